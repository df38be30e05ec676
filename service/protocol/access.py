"""Who may do what at an incident: the roster, the router's access control generated from it,
and the policy the service enforces at run time.

Two layers, each doing what it can:

**The router** (zenoh's ``access_control``, default deny, subjects by certificate common name)
decides, for every message on every link, whether that identity may send or receive it on that
key. Rules are generated here from the incident's roster (``firetrack certs router-config``;
``firetrack serve --tls`` builds its in-process router with them):

==============  ===========================================================================
role            may (``{i}`` = the incident, ``{me}`` = the certificate's common name)
==============  ===========================================================================
service         everything under ``firetrack/{i}/**`` (publishes pose, status, audit; answers
                ``track``; subscribes to frames, fixes, actions, presence)
wearable        put ``firetrack/{i}/{me}/imu``, ``.../{me}/fix`` and ``.../{me}/ack``; liveliness
                token ``.../{me}/presence``; subscribe to its own ``.../{me}/command`` (roll
                call, evacuation) and its own ``.../{me}/status`` (the acknowledgements and
                resend requests of :mod:`client.wearable`); query its own ``.../{me}/track``;
                keep its frames and fixes for zenoh's history and recovery (queryable,
                liveliness token, heartbeat and replies on ``.../{me}/imu/@adv/**`` and
                ``.../{me}/fix/@adv/**``, and it hears the service's history queries there).
                Nothing else: no other responder's keys, no pose, no other Status
anchor          put ``firetrack/{i}/*/fix-{me}`` (its own ranges to any responder; the key names
                the anchor, and the service takes only UWB ranges whose ``anchor`` is ``{me}``)
console,        subscribe to ``*/pose``, ``*/status``, ``*/audit``; query ``*/track``; put
operator        ``firetrack/{i}/{me}/op`` (its own actions only) and orders ``*/command``
viewer          subscribe to ``*/pose``, ``*/status``, ``*/audit``; query ``*/track``
simulator       like a wearable for every responder id ``{me}-...`` (exercises, the load bench)
gateway         like a wearable for every wearable of the roster, and reads statuses (the
                console's phone gateway, ``firetrack console --gateway-tls``: phones publish
                through it; which phone may speak for which responder is the console's
                enrolment, :mod:`client.console.enrolment`)
router          nothing as a client (a standalone zenohd's own certificate)
everyone        receive subscriber and queryable *declarations* (not data): a publisher's
                matching status and a client's routing need them

``**`` matches no chunk that starts with ``@``, so zenoh-ext's ``@adv`` keys are named
explicitly wherever they are allowed (:func:`kept_keys`). Without them a wearable under TLS
never heard its acknowledgements and a restarted service never got the frames it missed
(issue 32: 251 frames lost to a SIGKILL of ``serve --tls``; 0 now, ``tests/test_faults_tls.py``).
==============  ===========================================================================

Zenoh cannot template the certificate's name into a key, so a wearable's rules are written
once per wearable of the roster. That is also the limit of the router layer: its rules are
read when it starts and cannot change while it runs.

**The service** (:class:`service.protocol.actions.Access`, fed to the incident core) decides
what the router cannot: an operator action is taken only from an identity whose role may act
(console, operator, service), the operator's name is the one the console logged in, and a
**revoked** identity is refused from the moment the roster says so, without a restart (the
core drops its frames, fixes, presence and actions). The service re-reads the roster while it
runs.

Roster changes during an incident:

* **A responder joining.** Reserve names up front (``firetrack certs reserve --role wearable
  --name ff21 ...``): the router's rules cover every name of the roster, issued or not, so a
  certificate issued mid-incident for a reserved name works at once. A name added after the
  router started needs the router restarted with regenerated rules (clients reconnect by
  themselves; a standalone zenohd restarts in about a second, the service keeps its tracks).
* **A revoked certificate** (a lost phone). ``firetrack certs revoke --name ff3``: the service
  refuses ff3 at once; the router drops ff3's rules at its next restart; certificates are
  short-lived (one incident, 24 h by default) and every link closes when its certificate
  expires. Zenoh 1.10 checks no revocation list and its rules match common names, not serial
  numbers, so a revoked name is never issued again (``certs issue`` refuses it): the
  replacement device gets a new responder id.
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import json
import os
import secrets
import threading
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from service.protocol.keys import ANCHOR_FIX, KEY_ROOT, check_id
from service.protocol.tls import ROLES

ACTING_ROLES = ("service", "console", "operator")  # may publish operator actions
READING_ROLES = ("console", "operator", "viewer")  # may read poses, statuses, audits and tracks
LOGIN_ROLES = ("operator", "viewer")  # may log in to a console page
ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]

# scrypt cost of a console password: 2^14 x 8 x 1 is about 16 MiB and 50 ms per login
SCRYPT_N, SCRYPT_R, SCRYPT_P = 1 << 14, 8, 1
ROSTER_POLL_S = 1.0  # s between looks at the roster file while a service or console runs


class RosterError(ValueError):
    """A roster file that cannot be used, or a change to it that is not allowed."""


class Identity(BaseModel):
    """One name of the incident: its role, its certificate (if issued yet), its state."""

    model_config = ConfigDict(extra="forbid")
    role: str
    serial: str | None = Field(None, description="hex serial of the certificate issued; None while only reserved")
    not_after: str | None = Field(None, description="ISO UTC end of the certificate's validity")
    revoked: bool = False
    revoked_at: str | None = None
    password: str | None = Field(None, description="scrypt hash of the console password (operators, viewers)")


class Roster(BaseModel):
    """Every identity of one incident (``roster.json`` beside the CA)."""

    model_config = ConfigDict(extra="forbid")
    incident: str
    ca_serial: str | None = None
    identities: dict[str, Identity] = Field(default_factory=dict)

    def add(self, name: str, role: str) -> Identity:
        check_id("identity", name)
        if role not in ROLES:
            raise RosterError(f"role {role!r} is not one of {', '.join(ROLES)}")
        old = self.identities.get(name)
        if old is not None and old.revoked:
            raise RosterError(f"{name!r} was revoked; a revoked name is never issued again (the router's rules match "
                              f"names, not certificates): give the replacement another name")
        if old is not None and old.role != role:
            raise RosterError(f"{name!r} is a {old.role} already; one name has one role")
        for other, ident in self.identities.items():
            if ident.role == "simulator" and name.startswith(other + "-") and role != "simulator":
                raise RosterError(f"{name!r} starts with simulator {other!r}'s prefix {other}-: choose another name")
            if role == "simulator" and other.startswith(name + "-"):
                raise RosterError(f"simulator {name!r} would cover {other!r} ({name}-...): choose another name")
        ident = old or Identity(role=role)
        self.identities[name] = ident
        return ident

    def names(self, *roles: str, include_revoked: bool = False) -> list[str]:
        return sorted(n for n, i in self.identities.items()
                      if i.role in roles and (include_revoked or not i.revoked))

    def revoked(self) -> list[str]:
        return sorted(n for n, i in self.identities.items() if i.revoked)


def load_roster(path: str | Path) -> Roster:
    p = Path(path)
    try:
        return Roster.model_validate_json(p.read_text())
    except FileNotFoundError:
        raise RosterError(f"{p}: no roster here (run `firetrack certs init` first)") from None
    except (ValidationError, ValueError) as e:
        raise RosterError(f"{p}: not a roster: {' '.join(str(e).split())}") from None


def save_roster(path: str | Path, roster: Roster) -> None:
    """Written atomically (a reader never sees half a file), readable by the owner only
    (it holds password hashes)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(roster.model_dump_json(indent=2) + "\n")
    os.replace(tmp, p)


# ------------------------------------------------------------------------------------------
# console passwords
# ------------------------------------------------------------------------------------------
def new_password() -> str:
    """A random per-incident console password: 16 characters, about 96 bits."""
    return secrets.token_urlsafe(12)


def hash_password(password: str) -> str:
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, dklen=32)
    return "scrypt${}${}${}${}${}".format(SCRYPT_N, SCRYPT_R, SCRYPT_P, base64.b64encode(salt).decode(),
                                          base64.b64encode(digest).decode())


def check_password(password: str, stored: str | None) -> bool:
    """Constant-time comparison; False for a malformed or absent hash."""
    if not stored or not isinstance(password, str):
        return False
    try:
        scheme, n, r, p, salt, digest = stored.split("$")
        if scheme != "scrypt":
            return False
        want = base64.b64decode(digest)
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p),
                             dklen=len(want))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, want)


# ------------------------------------------------------------------------------------------
# the router's rules
# ------------------------------------------------------------------------------------------
def _rule(rid: str, messages: list[str], flows: list[str], keys: list[str]) -> dict:
    return {"id": rid, "messages": messages, "flows": flows, "permission": "allow", "key_exprs": keys}


KEPT_KINDS = ("imu", "fix")  # kinds a wearable publishes through zenoh's advanced publisher (its keep)
WEARABLE_RULES = ("put", "presence", "keep", "replies", "query", "reply", "listen", "hear")


def kept_keys(root: str, who: str) -> list[str]:
    """The keys of zenoh-ext's machinery for ``who``'s kept kinds: an advanced publisher on
    ``K`` declares its keep's queryable, its liveliness token and its heartbeat on
    ``K/@adv/pub/{zid}/{eid}/...``, and the service's advanced subscriber queries, watches and
    hears them there (``@adv`` is a verbatim chunk: no ``*`` or ``**`` matches it)."""
    return [f"{root}/{who}/{k}/@adv/**" for k in KEPT_KINDS]


def wearable_rules(prefix: str, me: str, truth: bool = False) -> list[dict]:
    """The rules of one wearable (``me``: its keys' prefix, ``firetrack/{i}/{id}``), named
    ``{prefix}-{what}`` for each of :data:`WEARABLE_RULES`: it puts its frames, fixes and
    acknowledgements (and a simulator its ground truth); holds its presence token; keeps its
    frames and fixes for zenoh's history and recovery (queryable, token, heartbeat, replies);
    queries its own track; and hears its own Status (acknowledgements, resend requests) and
    orders."""
    adv = [f"{me}/{k}/@adv/**" for k in KEPT_KINDS]
    kinds = ["imu", "fix", "ack"] + (["truth"] if truth else [])
    spec = {
        "put": (["put"], ["ingress"], [f"{me}/{k}" for k in kinds] + adv),
        "presence": (["liveliness_token"], ["ingress"], [f"{me}/presence", *adv]),
        "keep": (["declare_queryable"], ["ingress"], adv),
        "replies": (["reply"], ["ingress"], [f"{me}/{k}" for k in KEPT_KINDS] + adv),
        "query": (["query"], ["ingress"], [f"{me}/track"]),
        "reply": (["reply"], ["egress"], [f"{me}/track"]),
        "listen": (["declare_subscriber"], ["ingress"], [f"{me}/command", f"{me}/status"]),
        "hear": (["put"], ["egress"], [f"{me}/command", f"{me}/status"]),
    }
    return [_rule(f"{prefix}-{what}", *spec[what]) for what in WEARABLE_RULES]


def access_control(roster: Roster, incident: str | None = None) -> dict:
    """The ``access_control`` section of a zenoh router for ``roster`` (see the module
    docstring): default deny, one subject per identity (its certificate's common name),
    revoked identities left out."""
    inc = check_id("incident", incident or roster.incident)
    root = f"{KEY_ROOT}/{inc}"
    everything = [f"{root}/**", *kept_keys(root, "*")]  # ``**`` does not reach zenoh's ``@adv`` chunks
    rules = [
        _rule("declarations-out", ["declare_subscriber", "declare_queryable"], ["egress"], everything),
        _rule("service-all", ALL_MESSAGES, ["ingress", "egress"], everything),
        _rule("read-in", ["declare_subscriber"], ["ingress"], [f"{root}/*/pose", f"{root}/*/status", f"{root}/*/audit"]),
        _rule("read-out", ["put"], ["egress"], [f"{root}/*/pose", f"{root}/*/status", f"{root}/*/audit"]),
        _rule("tracks-query", ["query"], ["ingress"], [f"{root}/*/track"]),
        _rule("tracks-reply", ["reply"], ["egress"], [f"{root}/*/track"]),
        _rule("orders", ["put"], ["ingress"], [f"{root}/*/command"]),
        # the service's history and recovery queries reach every keeper of frames (they carry
        # no data; each wearable's keep answers for its own key only, which its reply rule binds)
        _rule("history-queries", ["query"], ["egress"], kept_keys(root, "*")),
    ]
    subjects = [{"id": "everyone"}]
    policies = [{"id": "everyone", "rules": ["declarations-out"], "subjects": ["everyone"]}]

    def subject(sid: str, names: list[str]) -> bool:
        if names:
            subjects.append({"id": sid, "cert_common_names": names})
        return bool(names)

    if subject("services", roster.names("service")):
        policies.append({"id": "services", "rules": ["service-all"], "subjects": ["services"]})
    gateways = roster.names("gateway")
    if subject("readers", roster.names(*READING_ROLES, "gateway")):
        policies.append({"id": "readers", "rules": ["read-in", "read-out", "tracks-query", "tracks-reply"],
                         "subjects": ["readers"]})
    for name in roster.names("anchor"):  # an anchor puts on keys that name it: the service knows who sent a fix
        rules.append(_rule(f"anchor-{name}", ["put"], ["ingress"], [f"{root}/*/{ANCHOR_FIX}{name}"]))
        subject(f"anchor-{name}", [name])
        policies.append({"id": f"anchor-{name}", "rules": [f"anchor-{name}"], "subjects": [f"anchor-{name}"]})
    if subject("actors", roster.names("console", "operator")):
        policies.append({"id": "actors", "rules": ["orders"], "subjects": ["actors"]})
    if subject("keepers", roster.names("wearable", "simulator", "gateway")):
        policies.append({"id": "keepers", "rules": ["history-queries"], "subjects": ["keepers"]})
    for name in roster.names("console", "operator"):
        rules.append(_rule(f"op-{name}", ["put"], ["ingress"], [f"{root}/{name}/op"]))
        subject(f"actor-{name}", [name])
        policies.append({"id": f"actor-{name}", "rules": [f"op-{name}"], "subjects": [f"actor-{name}"]})
    for role, chunk in (("wearable", "{}"), ("simulator", "{}-$*")):
        for name in roster.names(role):
            rules += wearable_rules(f"{role}-{name}", f"{root}/{chunk.format(name)}", truth=role == "simulator")
            subject(f"{role}-{name}", [name] + (gateways if role == "wearable" else []))
            policies.append({"id": f"{role}-{name}", "rules": [r["id"] for r in rules[-len(WEARABLE_RULES):]],
                             "subjects": [f"{role}-{name}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def router_config_json5(roster: Roster, tls_dir: str, listen: list[str], incident: str | None = None) -> str:
    """A complete zenohd configuration: TLS only with client certificates required, no
    multicast scouting, and the roster's access control."""
    d = Path(tls_dir)
    conf = {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {
            "protocols": ["tls"],
            "tls": {"root_ca_certificate": str(d / "ca.crt"), "listen_certificate": str(d / "cert.pem"),
                    "listen_private_key": str(d / "key.pem"), "enable_mtls": True,
                    "close_link_on_expiration": True}}},
        "access_control": access_control(roster, incident),
    }
    head = (f"// zenohd for incident {incident or roster.incident}: generated by `firetrack certs router-config` from "
            f"the incident roster.\n// Mutual TLS only (plain TCP refused), default-deny access control per identity. "
            f"Regenerate and restart\n// zenohd after adding names to the roster; see service/protocol/access.py.\n")
    return head + json.dumps(conf, indent=2) + "\n"


# ------------------------------------------------------------------------------------------
# what the service enforces
# ------------------------------------------------------------------------------------------
def access_message(roster: Roster | None, source: str | None = None):
    """The :class:`service.protocol.actions.Access` for ``roster`` (None: the insecure demo,
    nothing enforced)."""
    from service.protocol.actions import Access

    if roster is None:
        return Access(enforce=False, source=source)
    return Access(enforce=True, operators=roster.names(*ACTING_ROLES), revoked=roster.revoked(),
                  wearables=roster.names("wearable"), source=source)


class RosterWatcher:
    """Calls ``on_change(roster)`` whenever the roster file changes (polled every
    ``period_s``), until ``close()``. A roster that cannot be read is reported through
    ``on_error(message)`` and the last good one stays in force."""

    def __init__(self, path: str | Path, on_change, on_error=None, period_s: float = ROSTER_POLL_S):
        self.path = Path(path)
        self._on_change, self._on_error, self.period_s = on_change, on_error, period_s
        self._stamp = self._stat()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="firetrack-roster", daemon=True)
        self._thread.start()

    def _stat(self):
        try:
            st = os.stat(self.path)
            return (st.st_mtime_ns, st.st_size, st.st_ino)
        except OSError:
            return None

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            stamp = self._stat()
            if stamp == self._stamp:
                continue
            self._stamp = stamp
            try:
                roster = load_roster(self.path)
            except RosterError as e:
                if self._on_error is not None:
                    self._on_error(str(e))
                continue
            self._on_change(roster)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2 * self.period_s + 1)
