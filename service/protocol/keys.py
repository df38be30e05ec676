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


PARSED_KEYS_KEPT = 8192  # keys whose parse is remembered (a service sees a few per responder, every frame)


def parse_key(k: str) -> tuple[str, str, str]:
    """``firetrack/{incident}/{responder}/{kind}`` -> ``(incident, responder, kind)`` (an anchor's
    ``fix-{anchor}`` is kind ``fix``); ValueError
    for anything else (wrong root, wrong number of chunks, bad id, unknown kind). Valid keys'
    parses are remembered (the service parses the same few keys for every frame); a bad key
    is checked again each time."""
    return _parse_key(str(k))


@lru_cache(maxsize=PARSED_KEYS_KEPT)
def _parse_key(k: str) -> tuple[str, str, str]:
    parts = k.split("/")
    if len(parts) != 4 or parts[0] != KEY_ROOT:
        raise ValueError(f"key {k!r} is not {KEY_ROOT}/{{incident}}/{{responder}}/{{kind}}")
    _, incident, responder, kind = parts
    if kind.startswith(ANCHOR_FIX):
        check_id("anchor", kind[len(ANCHOR_FIX):])
        kind = "fix"
    return check_id("incident", incident), check_id("responder", responder), check_kind(kind)


def is_valid_id(value: str) -> bool:
    return isinstance(value, str) and _ID_RE.match(value) is not None
