"""The intake: what may enter the incident at all, decided before a payload is copied, decoded or recorded.

Every message is charged to a **source**: the responder id its key names
(``firetrack/{incident}/{responder}/{kind}``); keys whose id is not a valid id are one source,
``<bad key>``, new ids refused by the admission budget another, ``<new ids>``, and operator
actions (``.../{actor}/op``: an actor is not a responder) share ``<operators>``. Each of these
checks is a few dictionary look-ups and a little arithmetic, so a flood costs microseconds per
message however hostile its payloads are:

* **Size.** A payload over :data:`service.protocol.wire.MAX_PAYLOAD_BYTES` is refused by its
  length (``oversize``), before zenoh copies it into Python.
* **Admission.** A responder id the incident does not know yet is admitted from a token bucket
  (``admit_burst`` at once, ``admit_per_s`` after that) while fewer than ``max_responders`` are
  known; ids on the roster always are, and with ``roster_only`` nobody else is. Refused ids are
  ``not_admitted``: no state is kept for them, so memory is bounded whatever ids arrive.
* **Per-source budget.** Each source draws from its own token bucket: ``source_rate``
  messages/s with a burst of ``source_burst`` (enough for a wearable resending the frames it
  kept through an outage). A source whose messages were rejected ``bad_after`` times within
  ``bad_window_s`` (a sender of garbage; duplicates do not count: retransmission makes them) is
  held to ``bad_rate`` with a burst of ``bad_burst`` until it has behaved for ``bad_window_s``.
  Messages over the budget are ``throttled``, and the source carries a ``flooding`` alarm for
  ``flood_alarm_s`` after the last one.

Pure: time comes in with every call (the shell's receive clock), nothing here touches the
network. The shell records and feeds only what the intake took, so ``reprocess`` of a
recording sees exactly the messages the core saw live.
"""
from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Container
from dataclasses import dataclass, field

from service.protocol.keys import ID_PATTERN
from service.protocol.schema import MAX_PAYLOAD_BYTES

BAD_KEY = "<bad key>"
NEW_IDS = "<new ids>"
OPERATORS = "<operators>"
INTAKE_REASONS = ("oversize", "not_admitted", "throttled", "bad_key")
_ID_RE = re.compile(ID_PATTERN)


@dataclass(frozen=True)
class IntakeSettings:
    max_responders: int = 1024  # responders the incident keeps at once; new ids beyond are refused
    admit_burst: float = 256.0  # new responder ids admitted at once (a large crew arriving) ...
    admit_per_s: float = 2.0  # ... and per second after that (ids/s)
    roster: frozenset[str] | None = None  # ids always admitted (the incident's roster), None: no roster
    roster_only: bool = False  # admit the roster's ids only
    source_rate: float = 100.0  # messages/s a source may send (a wearable sends about 11)
    source_burst: float = 4000.0  # messages a source may send at once (a wearable's kept frames after an outage)
    bad_after: int = 20  # rejects within bad_window_s that make a source a sender of garbage ...
    bad_window_s: float = 10.0  # s
    bad_rate: float = 5.0  # ... held to this many messages/s ...
    bad_burst: float = 20.0  # ... with this burst
    flood_alarm_s: float = 30.0  # s a throttled source keeps its flooding alarm
    max_payload_bytes: int = MAX_PAYLOAD_BYTES

    def __post_init__(self):
        for name in ("admit_per_s", "source_rate", "bad_rate", "bad_window_s", "flood_alarm_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"IntakeSettings.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("admit_burst", "source_burst", "bad_burst"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"IntakeSettings.{name} must be at least 1 message, got {getattr(self, name)!r}")
        if self.max_responders < 1 or self.bad_after < 1:
            raise ValueError("IntakeSettings.max_responders and bad_after must be at least 1")


class TokenBucket:
    """``rate`` tokens per second up to ``burst``; :meth:`take` spends one if there is one."""

    __slots__ = ("rate", "burst", "tokens", "t")

    def __init__(self, rate: float, burst: float, now: float):
        self.rate, self.burst, self.tokens, self.t = rate, burst, burst, now

    def take(self, now: float) -> bool:
        if now > self.t:
            self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
            self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False

    def limit(self, rate: float, burst: float) -> None:
        self.rate, self.burst = rate, burst
        self.tokens = min(self.tokens, burst)


@dataclass
class SourceState:
    """What the intake keeps per source (bounded: a few numbers and a short deque)."""

    bucket: TokenBucket
    rejects: deque = field(default_factory=deque)  # receive times of recent rejects (at most bad_after)
    bad: bool = False
    throttled: int = 0  # messages refused by the budget, ever
    last_throttled: float = -math.inf
    dropped: dict = field(default_factory=dict)  # intake reason -> count


class Intake:
    """Per-source budgets and admission (see the module docstring); ``reason = intake.admit(...)``."""

    def __init__(self, settings: IntakeSettings | None = None):
        self.settings = settings or IntakeSettings()
        s = self.settings
        self.sources: dict[str, SourceState] = {}
        self._admit: TokenBucket | None = None
        self.pseudo = (BAD_KEY, NEW_IDS, OPERATORS)  # sources of messages no responder can be charged with
        self.admitted = 0  # new responder ids admitted, ever
        self.counts: dict[str, int] = {}  # intake reason -> messages refused, over all sources
        self._roster = s.roster or frozenset()

    # ------------------------------------------------------------------ the check
    def admit(self, key: str, size: int, now: float, known: Container[str] = ()) -> tuple[str | None, str]:
        """``(None, source)`` when the message may go on, else ``(reason, source)``. ``known``
        holds the responders the core has (restored from a snapshot, or fed without the
        intake); an id neither there nor admitted before is new."""
        parts = key.split("/")
        rid = parts[2] if len(parts) == 4 else ""
        src = self.sources.get(rid)
        if src is None:
            if rid in known:
                src = self._source(rid, now)
            elif not _ID_RE.match(rid) or rid in self.pseudo:
                return self._refuse(BAD_KEY, "bad_key", now), BAD_KEY
            else:
                if not self._may_admit(rid, now):
                    return self._refuse(NEW_IDS, "not_admitted", now), NEW_IDS
                src = self._source(rid, now)
                self.admitted += 1
        if size > self.settings.max_payload_bytes:
            return self._drop(src, "oversize"), rid
        if src.bad:
            self._maybe_rehabilitate(src, now)
        if not src.bucket.take(now):
            src.throttled += 1
            src.last_throttled = now
            return self._drop(src, "throttled"), rid
        return None, rid

    def admit_shared(self, source: str, size: int, now: float) -> str | None:
        """A message charged to a pseudo-source (``<operators>``): its size and that source's
        budget; no admission, no responder. None when it may go on, else the reason."""
        src = self.sources.get(source)
        if src is None:
            src = self._source(source, now)
        if size > self.settings.max_payload_bytes:
            return self._drop(src, "oversize")
        if not src.bucket.take(now):
            src.throttled += 1
            src.last_throttled = now
            return self._drop(src, "throttled")
        return None

    @property
    def responders(self) -> int:
        """Responder ids admitted and not forgotten."""
        return len(self.sources) - sum(1 for p in self.pseudo if p in self.sources)

    def _may_admit(self, rid: str, now: float) -> bool:
        s = self.settings
        if rid in self._roster:
            return True
        if s.roster_only or self.responders >= s.max_responders:
            return False
        if self._admit is None:
            self._admit = TokenBucket(s.admit_per_s, s.admit_burst, now)
        return self._admit.take(now)

    def _maybe_rehabilitate(self, src: SourceState, now: float) -> None:
        """A source held to the bad-sender budget that has neither been rejected nor throttled
        for ``bad_window_s`` gets the ordinary budget back."""
        s = self.settings
        if (not src.rejects or now - src.rejects[-1] > s.bad_window_s) and now - src.last_throttled > s.bad_window_s:
            src.bad = False
            src.rejects.clear()
            src.bucket.limit(s.source_rate, s.source_burst)

    # ------------------------------------------------------------------ feedback
    def note_reject(self, source: str, now: float) -> None:
        """A message of ``source`` that passed the intake was rejected later (decode, schema):
        ``bad_after`` of them within ``bad_window_s`` hold the source to the bad-sender budget."""
        src = self.sources.get(source)
        if src is None:
            return
        s = self.settings
        q = src.rejects
        q.append(now)
        while q and (now - q[0] > s.bad_window_s or len(q) > s.bad_after):
            q.popleft()
        if not src.bad and len(q) >= s.bad_after:
            src.bad = True
            src.bucket.limit(s.bad_rate, s.bad_burst)

    def flooding(self, source: str, now: float) -> bool:
        """Was ``source`` throttled within ``flood_alarm_s``?"""
        src = self.sources.get(source)
        return src is not None and now - src.last_throttled <= self.settings.flood_alarm_s

    def flooding_sources(self, now: float) -> list[str]:
        """Every source (responder ids and the pseudo-sources) throttled within ``flood_alarm_s``."""
        return [name for name, src in self.sources.items() if now - src.last_throttled <= self.settings.flood_alarm_s]

    def set_roster(self, extra: frozenset[str]) -> None:
        """The ids always admitted: the settings' roster and ``extra`` (the access policy's
        wearables, which a roster changed mid-incident brings)."""
        self._roster = (self.settings.roster or frozenset()) | frozenset(extra)

    def forget(self, source: str) -> None:
        """The core let a responder go (expired): its budget goes with it."""
        self.sources.pop(source, None)

    def dropped_of(self, source: str) -> dict[str, int]:
        src = self.sources.get(source)
        return dict(src.dropped) if src is not None else {}

    # ------------------------------------------------------------------ internals
    def _source(self, name: str, now: float) -> SourceState:
        s = self.settings
        src = self.sources[name] = SourceState(TokenBucket(s.source_rate, s.source_burst, now))
        return src

    def _refuse(self, pseudo: str, reason: str, now: float) -> str:
        src = self.sources.get(pseudo)
        if src is None:
            src = self._source(pseudo, now)
        if not src.bucket.take(now):  # the pseudo-source floods: the alarm names it
            src.throttled += 1
            src.last_throttled = now
        return self._drop(src, reason)

    def _drop(self, src: SourceState, reason: str) -> str:
        src.dropped[reason] = src.dropped.get(reason, 0) + 1
        self.counts[reason] = self.counts.get(reason, 0) + 1
        return reason
