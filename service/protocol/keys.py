"""Key expressions: ``firetrack/{incident}/{responder}/{kind}``, the one place their rules live.

The id chunk names a responder for ``imu``, ``fix``, ``pose``, ``status``, ``track``,
``presence`` and ``truth``. For ``op`` (an operator action), ``audit`` (the service's verdict
on one) and ``access`` (the access policy the service works under) it names the *actor*: the
console, operator or service identity that published, which with TLS on is the common name
of its certificate, bound to the key by the router's access control
(:mod:`service.protocol.access`).

A fix has two keys. ``{responder}/fix`` is the responder's own wearable's (and, through the
phone gateway, its phone's). ``{responder}/fix-{anchor}`` is an anchor's: the router lets the
anchor certificate named ``{anchor}`` put there and nowhere else
(:mod:`service.protocol.access`), so the key names who sent the fix, and the service takes only
ranges from that anchor id from it (:mod:`service.core.fix_intake`). Both parse as kind ``fix``;
:func:`fix_sender` says which.

Incident and responder ids match ``[A-Za-z0-9_.-]{1,64}``, so they never contain a
key-expression separator or wildcard (``/``, ``*``, ``$``, ``#``, ``?``). The service, the
recorder, the console and the wearables all build and parse keys here.
"""
from __future__ import annotations

import re
from functools import lru_cache
from typing import NamedTuple

KEY_KINDS = ("imu", "fix", "pose", "status", "track", "presence", "truth", "command", "ack", "op", "audit",
             "access")
ACTOR_KINDS = ("op", "audit", "access")  # kinds whose id chunk is the publishing identity, not a responder
KEY_ROOT = "firetrack"
ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
_ID_RE = re.compile(ID_PATTERN)


def check_id(what: str, value: str) -> str:
    if not isinstance(value, str) or not _ID_RE.match(value):
        raise ValueError(f"{what} id {value!r} must match [A-Za-z0-9_.-]{{1,64}} "
                         "(no '/', '*', '$', '#', '?', spaces or empty)")
    return value


def check_kind(kind: str) -> str:
    if kind not in KEY_KINDS:
        raise ValueError(f"unknown key kind {kind!r}; known: {', '.join(KEY_KINDS)}")
    return kind


def key(incident: str, responder: str, kind: str) -> str:
    """``firetrack/{incident}/{responder}/{kind}``: where one responder's messages of a kind go."""
    return f"{KEY_ROOT}/{check_id('incident', incident)}/{check_id('responder', responder)}/{check_kind(kind)}"


def key_all(incident: str, kind: str) -> str:
    """``firetrack/{incident}/*/{kind}``: subscribe to a kind for every responder of an incident."""
    return f"{KEY_ROOT}/{check_id('incident', incident)}/*/{check_kind(kind)}"


ANCHOR_FIX = "fix-"  # the kind chunk of an anchor's fix: fix-{anchor}


def anchor_fix_key(incident: str, responder: str, anchor: str) -> str:
    """``firetrack/{incident}/{responder}/fix-{anchor}``: where anchor ``anchor`` puts its fixes
    (ranges) for a responder."""
    return f"{key(incident, responder, 'fix')}-{check_id('anchor', anchor)}"


def anchor_fix_all(incident: str) -> str:
    """``firetrack/{incident}/*/fix-$*``: every anchor's fixes for every responder."""
    return f"{KEY_ROOT}/{check_id('incident', incident)}/*/{ANCHOR_FIX}$*"


def fix_sender(k: str) -> str | None:
    """The anchor that sent a fix on ``k`` (``.../fix-{anchor}``), None for any other key."""
    kind = str(k).rsplit("/", 1)[-1]
    return kind[len(ANCHOR_FIX):] if kind.startswith(ANCHOR_FIX) else None


PARSED_KEYS_KEPT = 4096  # keys whose parse is remembered: the hot ones, a frame key and a fix key for each of
# the 1024 responders an intake keeps at most, twice over; bounded whatever keys a flood of new ids brings
# (the shell reads every key it hears, refused or not: about 0.4 kB an entry)


class KeyParts(NamedTuple):
    """A key read once, at the shell's edge, and carried with its message to the core
    (:class:`service.core.core_types.Inbound`): nothing after the edge splits the key again."""

    incident: str
    responder: str  # the id chunk: a responder, or the actor for op, audit and access (ACTOR_KINDS)
    kind: str  # an anchor's fix-{anchor} is kind "fix"
    sender: str | None  # the anchor of a fix-{anchor} key; None for every other key


def parse_key(k: str) -> tuple[str, str, str]:
    """``firetrack/{incident}/{responder}/{kind}`` -> ``(incident, responder, kind)`` (an anchor's
    ``fix-{anchor}`` is kind ``fix``); ValueError
    for anything else (wrong root, wrong number of chunks, bad id, unknown kind). Valid keys'
    parses are remembered (the service parses the same few keys for every frame); a bad key
    is checked again each time."""
    return tuple(_parse_key(str(k))[:3])


def read_key(k: str) -> KeyParts | ValueError:
    """The key's :class:`KeyParts`, or the ValueError that says why it is not a key (returned,
    not raised: the shell reads every message's key once and carries the verdict, good or bad,
    to the intake and the core)."""
    try:
        return _parse_key(str(k))
    except ValueError as e:
        return e


@lru_cache(maxsize=PARSED_KEYS_KEPT)
def _parse_key(k: str) -> KeyParts:
    parts = k.split("/")
    if len(parts) != 4 or parts[0] != KEY_ROOT:
        raise ValueError(f"key {k!r} is not {KEY_ROOT}/{{incident}}/{{responder}}/{{kind}}")
    _, incident, responder, kind = parts
    sender = None
    if kind.startswith(ANCHOR_FIX):
        sender = check_id("anchor", kind[len(ANCHOR_FIX):])
        kind = "fix"
    return KeyParts(check_id("incident", incident), check_id("responder", responder), check_kind(kind), sender)


def is_valid_id(value: str) -> bool:
    return isinstance(value, str) and _ID_RE.match(value) is not None
