"""Phones enrolled as wearables: a token per phone, scoped to one responder of one incident.

An operator enrols a phone for a roster entry from the console (``POST /api/phones``): the
console makes a random **token** (what the phone presents on every WebSocket it opens to the
gateway, :mod:`client.console.phone_gateway`) and a short **code** (six characters an officer
can read out or type, valid for :data:`CODE_TTL_S` and for one claim) that the phone trades
for the token at ``/wear``; the QR code the console shows is the page's address with the
code in it. A token names the responder it may publish as and nothing else: a frame that
names another responder is refused and counted against the token (``refused``). Revoking a
responder's phone ends its tokens at once: the gateway checks the token on every message,
and closes the phone's socket when it is revoked.

Tokens live in the console's memory: a restarted console enrols its phones again (a phone
keeps its token in its own storage, and is told the token is unknown).
"""
from __future__ import annotations

import secrets
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

CODE_TTL_S = 600.0  # s a short code can be claimed (a QR shown on the console, read by a phone)
CODE_ALPHABET = "ABCDEFGHJKMNPQRSTUVWXYZ23456789"  # no 0/O, 1/I/L: read aloud over a radio
CODE_LEN = 6


@dataclass
class PhoneGrant:
    """One enrolled phone: the responder it may publish as, and what it was refused."""

    token: str
    responder: str
    incident: str
    issued_at: float
    issued_by: str
    code: str | None = None  # until claimed or expired
    code_expires: float = 0.0
    claimed_at: float | None = None
    revoked_at: float | None = None
    refused: Counter = field(default_factory=Counter)  # reason -> count (another responder, revoked, ...)

    def public(self) -> dict:
        """What the console shows of it (never the token)."""
        return {"responder": self.responder, "issued_at": self.issued_at, "issued_by": self.issued_by,
                "claimed": self.claimed_at is not None, "revoked": self.revoked_at is not None,
                "refused": dict(self.refused)}


class PhoneEnrolments:
    """The grants of one incident; thread-safe (the console's loop and tests read it)."""

    def __init__(self, incident: str, clock=time.time):
        self.incident = incident
        self._clock = clock
        self._lock = threading.Lock()
        self._by_token: dict[str, PhoneGrant] = {}
        self._by_code: dict[str, PhoneGrant] = {}
        self.on_revoked = None  # callback(list of tokens): the gateway closes their sockets

    def enrol(self, responder: str, issued_by: str) -> PhoneGrant:
        """A new token and code for ``responder``; earlier phones of the responder stay enrolled
        (a second phone, a spare) until revoked."""
        now = self._clock()
        with self._lock:
            code = self._new_code()
            g = PhoneGrant(token=secrets.token_urlsafe(24), responder=responder, incident=self.incident,
                           issued_at=now, issued_by=issued_by, code=code, code_expires=now + CODE_TTL_S)
            self._by_token[g.token] = g
            self._by_code[code] = g
            return g

    def _new_code(self) -> str:
        while True:
            code = "".join(secrets.choice(CODE_ALPHABET) for _ in range(CODE_LEN))
            if code not in self._by_code:
                return code

    def claim(self, code: str) -> PhoneGrant | None:
        """The grant of a short code (once; case and spaces forgiven), or None: unknown,
        expired, already claimed or revoked."""
        code = "".join(str(code).upper().split())
        now = self._clock()
        with self._lock:
            g = self._by_code.pop(code, None)
            if g is None or now > g.code_expires or g.revoked_at is not None:
                return None
            g.code, g.claimed_at = None, now
            return g

    def grant(self, token: str | None) -> PhoneGrant | None:
        """The live grant of ``token`` (None: unknown or revoked)."""
        with self._lock:
            g = self._by_token.get(token) if isinstance(token, str) else None
            return g if g is not None and g.revoked_at is None else None

    def refuse(self, token: str, reason: str) -> None:
        """Count a refused message against the token's grant (revoked ones count too)."""
        with self._lock:
            g = self._by_token.get(token)
            if g is not None:
                g.refused[reason] += 1

    def revoke(self, responder: str) -> int:
        """Revoke every phone of ``responder``; returns how many tokens ended."""
        now = self._clock()
        with self._lock:
            ended = [g for g in self._by_token.values() if g.responder == responder and g.revoked_at is None]
            for g in ended:
                g.revoked_at = now
                if g.code is not None:
                    self._by_code.pop(g.code, None)
                    g.code = None
        if ended and self.on_revoked is not None:
            self.on_revoked([g.token for g in ended])
        return len(ended)

    def listing(self) -> list[dict]:
        with self._lock:
            return [g.public() for g in self._by_token.values()]

    def refused_total(self, responder: str | None = None) -> Counter:
        """Refused messages by reason, of one responder's phones or of all."""
        total: Counter = Counter()
        with self._lock:
            for g in self._by_token.values():
                if responder is None or g.responder == responder:
                    total.update(g.refused)
        return total
