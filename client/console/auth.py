"""Who is at the keyboard, and from which page: the console's logins, sessions and origin checks.

**Origin and Host.** The console knows the addresses it is opened at (``--origin``, or
``http(s)://127.0.0.1:PORT`` and ``localhost`` when it serves this machine only). Every request
whose ``Host`` is not one of them is refused (403): a page on another site that rebinds its
DNS name to this machine's address (DNS rebinding) reaches the server with its own name as
Host. A POST or a WebSocket whose ``Origin`` is not one of them is refused too (403): another
site's page in an officer's browser. The request's own Host is never the reference.

**Logins.** With a roster (``--tls`` and the incident's ``roster.json``) every API call and the
live feed need a session. An operator or viewer logs in with the per-incident password
``firetrack certs issue`` printed, or, on HTTPS, with the client certificate the browser
presents (its common name and serial must be the roster's). The session is a random token in a
cookie that is ``HttpOnly`` (no script reads it), ``SameSite=Strict`` (no other site's request
carries it), ``Secure`` on HTTPS, and ends after :data:`SESSION_MAX_S` or at logout; revoking
the identity in the roster ends its sessions within a second. Viewers read; only operators
act (fix, checkpoint, acknowledge, PAR), and every action names the operator.

**Guessing.** A password login is limited per address (:data:`LOGIN_FAILURES` failures within
:data:`LOGIN_WINDOW_S`) and per account (:data:`ACCOUNT_FAILURES` within
:data:`ACCOUNT_WINDOW_S`, whatever the addresses): beyond either the answer is 429, "locked",
before any password is looked at. An attempt counts as a failure from the moment it starts (a
success takes it back), so concurrent guesses cannot slip past the count. A user name the
roster does not know is hashed against a dummy hash of the same cost, so known and unknown
names take the same time to answer (no user enumeration), and unknown names are counted like
known ones. scrypt (about 16 MiB and 50 ms) runs on :data:`HASH_THREADS` threads off the event
loop, so logins never stall the console's other requests. A locked account can still log in
with its client certificate.

**Without a roster** (the one-command demo) the console serves this machine only, and whoever
is at it acts as operator ``local``; the page says so.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import secrets
import ssl
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

log = logging.getLogger("firetrack.console")

SESSION_COOKIE = "firetrack_session"
SESSION_MAX_S = 12 * 3600.0  # s: one shift; then the operator logs in again
LOGIN_FAILURES = 5  # failed logins from one address within LOGIN_WINDOW_S ...
LOGIN_WINDOW_S = 60.0  # s: ... and that address waits this long (429)
ACCOUNT_FAILURES = 5  # failed logins for one user name, from any addresses, within ACCOUNT_WINDOW_S lock it
ACCOUNT_WINDOW_S = 900.0  # s
MAX_TRACKED = 10_000  # addresses and user names whose failures are kept (beyond, the oldest are forgotten)
HASH_THREADS = 1  # password hashes computed at once (16 MiB each; one core stays free for the console)
OPEN_USER = "local"  # who acts in the demo, without a roster


class SiteError(ValueError):
    """The console's addresses cannot be worked out (e.g. 0.0.0.0 without --origin)."""


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class SitePolicy:
    """The origins (``scheme://host:port``) the console is opened at, and the Host values that go with them."""

    def __init__(self, origins: list[str]):
        self.origins: set[str] = set()
        self.hosts: set[str] = set()
        self.primary = ""
        for o in origins:
            u = urlsplit(o)
            if u.scheme not in ("http", "https") or not u.hostname or u.path not in ("", "/"):
                raise SiteError(f"--origin {o!r}: give the address officers open, e.g. https://console.fire.local:8443")
            port = u.port or (443 if u.scheme == "https" else 80)
            host = f"[{u.hostname}]" if ":" in u.hostname else u.hostname
            self.origins.add(f"{u.scheme}://{host}:{port}")
            self.hosts.add(f"{host}:{port}")
            self.primary = self.primary or f"{u.scheme}://{host}:{port}"
            if port == (443 if u.scheme == "https" else 80):  # a default port may be left out
                self.origins.add(f"{u.scheme}://{host}")
                self.hosts.add(host)

    @classmethod
    def for_server(cls, host: str, port: int, https: bool, origins: list[str] | None) -> SitePolicy:
        scheme = "https" if https else "http"
        if origins:
            return cls(list(origins))
        if is_loopback(host):
            return cls([f"{scheme}://127.0.0.1:{port}", f"{scheme}://localhost:{port}", f"{scheme}://[::1]:{port}"])
        if host in ("0.0.0.0", "::", ""):
            raise SiteError(f"--host {host or '(every interface)'} listens on every interface: say the address "
                            f"officers open with --origin {scheme}://NAME-OR-IP:{port} (Host and Origin are checked "
                            "against it)")
        return cls([f"{scheme}://{host if ':' not in host else f'[{host}]'}:{port}"])

    def host_problem(self, host: str | None) -> str | None:
        if host is None or host.lower() not in self.hosts:
            return (f"Host {host!r} is not this console's address ({', '.join(sorted(self.hosts))}): "
                    "open the console at its own address")
        return None

    def origin_problem(self, origin: str | None) -> str | None:
        if origin is None:  # not a browser (curl, a script): the session decides
            return None
        if origin.lower().rstrip("/") not in self.origins:
            return f"requests from {origin} are refused: only the console's own page ({self.primary}) may act"
        return None


@dataclass
class Session:
    token: str
    user: str
    role: str  # operator | viewer
    via: str  # password | certificate | open
    created: float
    sockets: set = field(default_factory=set)

    @property
    def may_act(self) -> bool:
        return self.role == "operator"


class Logins:
    """Sessions against the roster (``roster`` None: the open demo, one implicit operator)."""

    def __init__(self, roster_path: Path | None, clock=time.time):
        self.roster_path = Path(roster_path) if roster_path is not None else None
        self.clock = clock
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}
        self._failures: dict[str, deque] = {}  # address -> times of failed (or ongoing) attempts
        self._account_failures: dict[str, deque] = {}  # user name -> the same
        self._hasher: ThreadPoolExecutor | None = None
        self._dummy_hash: str | None = None
        self.roster = None
        self._watcher = None
        self.on_revoked = None  # callable(list of sessions ended) from the roster watcher's thread
        if self.roster_path is not None:
            from service.protocol.access import RosterWatcher, load_roster

            self.roster = load_roster(self.roster_path)
            self._watcher = RosterWatcher(self.roster_path, self._roster_changed,
                                          on_error=lambda m: log.error("roster: %s; the previous one stays", m))

    @property
    def open(self) -> bool:
        return self.roster_path is None

    def close(self) -> None:
        if self._watcher is not None:
            self._watcher.close()
        if self._hasher is not None:
            self._hasher.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------ sessions
    def session(self, token: str | None) -> Session | None:
        if self.open:
            return Session("", OPEN_USER, "operator", "open", 0.0)
        if not token:
            return None
        with self._lock:
            s = self._sessions.get(token)
            if s is not None and self.clock() - s.created > SESSION_MAX_S:
                del self._sessions[token]
                return None
            return s

    def _start(self, user: str, role: str, via: str) -> Session:
        s = Session(secrets.token_urlsafe(32), user, role, via, self.clock())
        with self._lock:
            self._sessions[s.token] = s
        log.warning("console: %s (%s) logged in by %s", user, role, via)
        return s

    def logout(self, token: str | None) -> None:
        with self._lock:
            s = self._sessions.pop(token or "", None)
        if s is not None:
            log.warning("console: %s logged out", s.user)

    # ------------------------------------------------------------------ logins
    def throttled(self, address: str, user=None) -> str | None:
        """Why a login from ``address`` as ``user`` is refused before any password is looked at
        (``"address"`` or ``"account"``), or None."""
        now = self.clock()
        with self._lock:
            if _recent(self._failures.get(address), now, LOGIN_WINDOW_S) >= LOGIN_FAILURES:
                return "address"
            if _recent(self._account_failures.get(_account(user)), now, ACCOUNT_WINDOW_S) >= ACCOUNT_FAILURES:
                return "account"
        return None

    def _attempt(self, address: str, user) -> tuple[str, float] | None:
        """Start a password attempt: refused (None) when the address or the account is locked,
        else counted as a failure until :meth:`_succeeded` takes it back."""
        now = self.clock()
        with self._lock:
            if (_recent(self._failures.get(address), now, LOGIN_WINDOW_S) >= LOGIN_FAILURES or
                    _recent(self._account_failures.get(_account(user)), now, ACCOUNT_WINDOW_S) >= ACCOUNT_FAILURES):
                return None
            _note(self._failures, address, now, LOGIN_FAILURES)
            _note(self._account_failures, _account(user), now, ACCOUNT_FAILURES)
        return address, now

    def _succeeded(self, ticket: tuple[str, float], user) -> None:
        address, t = ticket
        with self._lock:
            for book, name in ((self._failures, address), (self._account_failures, _account(user))):
                q = book.get(name)
                if q is not None and t in q:
                    q.remove(t)

    def count_failure(self, address: str, user) -> None:
        """A failed login (or a wrong phone enrolment code) from ``address``: after
        LOGIN_FAILURES within LOGIN_WINDOW_S the address is :meth:`throttled`."""
        with self._lock:
            _note(self._failures, address, self.clock(), LOGIN_FAILURES)
        log.warning("console: failed login as %r from %s", user, address)

    def _login_identity(self, user: str):
        ident = self.roster.identities.get(user) if self.roster is not None and isinstance(user, str) else None
        from service.protocol.access import LOGIN_ROLES

        if ident is None or ident.revoked or ident.role not in LOGIN_ROLES:
            return None
        return ident

    def _stored_hash(self, ident) -> str:
        """The hash a password is checked against: the identity's, or for a name that cannot
        log in (unknown, revoked, a wearable, no password) a dummy of the same cost."""
        if ident is not None and ident.password:
            return ident.password
        if self._dummy_hash is None:
            from service.protocol.access import hash_password

            self._dummy_hash = hash_password(secrets.token_urlsafe(16))
        return self._dummy_hash

    def with_password(self, user, password, address: str) -> Session | None:
        """A password login, hashing in the calling thread (see :meth:`login_with_password`)."""
        ticket = self._attempt(address, user)
        if ticket is None:
            return None
        return self._judge(ticket, user, password, self._check(user, password))

    async def login_with_password(self, user, password, address: str) -> tuple[Session | None, str | None]:
        """``(session, None)``, ``(None, "wrong")`` or ``(None, "locked")``: the check of
        :meth:`with_password` with its hash on the hashing threads, off the event loop."""
        ticket = self._attempt(address, user)
        if ticket is None:
            return None, "locked"
        if self._hasher is None:
            self._hasher = ThreadPoolExecutor(HASH_THREADS, thread_name_prefix="firetrack-login")
        ok = await asyncio.get_running_loop().run_in_executor(self._hasher, self._check, user, password)
        s = self._judge(ticket, user, password, ok)
        return s, None if s is not None else "wrong"

    def _check(self, user, password) -> tuple[bool, object]:
        from service.protocol.access import check_password

        ident = self._login_identity(user)
        good = check_password(password if isinstance(password, str) else "", self._stored_hash(ident))
        return good and ident is not None and isinstance(password, str), ident

    def _judge(self, ticket, user, password, checked) -> Session | None:
        ok, ident = checked
        if not ok:
            log.warning("console: failed login as %r from %s", str(user)[:64], ticket[0])
            return None
        self._succeeded(ticket, user)
        return self._start(user, ident.role, "password")

    def with_certificate(self, der: bytes | None, address: str) -> Session | None:
        """A client certificate the TLS handshake already checked against the incident CA: its
        common name and serial must be a login identity of the roster."""
        if not der:
            return None
        from cryptography import x509
        from cryptography.x509.oid import NameOID

        try:
            cert = x509.load_der_x509_certificate(der)
            cn = str(cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value)
        except (ValueError, IndexError):
            return None
        ident = self._login_identity(cn)
        if ident is None or ident.serial != format(cert.serial_number, "x"):
            self.count_failure(address, cn)
            return None
        return self._start(cn, ident.role, "certificate")

    def _roster_changed(self, roster) -> None:
        self.roster = roster
        ended = []
        with self._lock:
            for tok, s in list(self._sessions.items()):
                ident = roster.identities.get(s.user)
                if ident is None or ident.revoked:
                    ended.append(self._sessions.pop(tok))
        for s in ended:
            log.warning("console: %s is revoked; its session ended", s.user)
        if ended and self.on_revoked is not None:
            self.on_revoked(ended)


def _account(user) -> str:
    """The name an account's failures are counted under (any value a body may carry)."""
    return user[:128] if isinstance(user, str) else "<not a name>"


def _recent(q: deque | None, now: float, window: float) -> int:
    """How many times in ``q`` lie within ``window`` s before ``now`` (the older ones go)."""
    while q and now - q[0] > window:
        q.popleft()
    return len(q) if q else 0


def _note(book: dict[str, deque], name: str, now: float, keep: int) -> None:
    """A failure of ``name`` at ``now``; at most :data:`MAX_TRACKED` names are kept."""
    q = book.pop(name, None)  # re-inserted: the dict's order is the last failure's
    if q is None:
        q = deque(maxlen=keep)
        while len(book) >= MAX_TRACKED:
            del book[next(iter(book))]
    q.append(now)
    book[name] = q


def server_ssl_context(tls, request_client_cert: bool = True) -> ssl.SSLContext:
    """HTTPS with the console's certificate; a client certificate from the incident CA is asked
    for but optional (an operator may log in with a password instead)."""
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(str(tls.cert), str(tls.key))
    if request_client_cert:
        ctx.load_verify_locations(cafile=str(tls.ca))
        ctx.verify_mode = ssl.CERT_OPTIONAL
    return ctx
