"""The intake: what may enter the incident at all, decided before a payload is copied, decoded or recorded.

Every message is charged to a **source**: the responder id its key names
(``firetrack/{incident}/{responder}/{kind}``), which the shell read once at its edge
(:class:`service.protocol.keys.KeyParts`); keys that are not keys (a bad id) are one source,
``<bad key>``, new ids refused by the admission budget another, ``<new ids>``, and operator
actions (``.../{actor}/op``: an actor is not a responder) share ``<operators>``. Each of these
checks is a few dictionary look-ups and a little arithmetic, so a flood costs microseconds per
message however hostile its payloads are:

* **Size.** A payload over :data:`service.protocol.wire.MAX_PAYLOAD_BYTES` is refused by its
  length (``oversize``), before zenoh copies it into Python.
* **Fixes make no responder.** A fix for an id the incident does not know is charged to
  ``<new ids>``'s budget, keeps no state here and is no admission: only a wearable's frames
  bring a responder (the core holds such a fix a few seconds for a wearable whose door fix
  came before its first frame).
* **Admission.** A responder id the incident does not know yet is admitted from a token bucket
  (``admit_burst`` at once, ``admit_per_s`` after that) while fewer than ``max_responders`` are
  known; ids on the roster always are, and with ``roster_only`` nobody else is. Refused ids are
  ``not_admitted``: no state is kept for them, so memory is bounded whatever ids arrive.
* **Per-source budget, one per lane.** Each source draws from its own token buckets, one per
  **lane**, the kind its key ends with (``imu``, ``fix``, ``ack``, ``command``, ``op``; the
  anchors' ``fix-{anchor}`` keys share the lane ``anchor``):
  ``source_rate`` messages/s with a burst of ``source_burst`` (enough for a wearable resending
  the frames it kept through an outage). A lane whose messages were rejected ``bad_after``
  times within ``bad_window_s`` (a sender of garbage; duplicates do not count: retransmission
  makes them) is held to ``bad_rate`` with a burst of ``bad_burst`` until it has behaved for
  ``bad_window_s``. Messages over the budget are ``throttled`` (``fix_throttled``, ... in the
  responder's counts for the other lanes), and the lane is ``flooding`` for ``flood_alarm_s``
  after the last one: the responder's ``flooding`` alarm is its frames' lane
  (:data:`ALARM_LANE`), the others are named ``{id}/{lane}`` by :meth:`Intake.flooding_sources`.

**Why lanes, not identities.** The budget should be the sender's, but a zenoh subscriber cannot
tell who sent a sample: ``Sample.source_info`` is empty unless the publisher fills it, and an
attachment says what the publisher wants. What the shell can trust is the key, because the
router's access control (certificate names, :mod:`service.protocol.access`) decides who may put
on it: ``{id}/imu``, ``{id}/ack`` and ``{id}/fix`` only ``{id}``'s own wearable, ``{id}/fix-{a}``
only anchor ``a``. So the lanes separate the identities the router separates: an anchor flooding
``ff2/fix-a1`` with garbage spends the ``anchor`` lane of ff2, never the frames or the own
fixes of ff2's wearable.

Pure: time comes in with every call (the shell's receive clock), nothing here touches the
network. The shell records and feeds only what the intake took, so ``reprocess`` of a
recording sees exactly the messages the core saw live.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Container
from dataclasses import dataclass, field

from service.protocol.keys import KeyParts
from service.protocol.schema import MAX_PAYLOAD_BYTES

BAD_KEY = "<bad key>"
NEW_IDS = "<new ids>"
OPERATORS = "<operators>"
INTAKE_REASONS = ("oversize", "not_admitted", "throttled", "bad_key")
LANES = ("imu", "fix", "anchor", "ack", "command", "op")  # the kinds with a budget of their own; any other shares "other"
_LANE_SET = frozenset(LANES)
_UNLANED = frozenset(("bad_key", "not_admitted"))  # reasons counted under their own name whatever the lane
ALARM_LANE = "imu"  # the lane whose flooding is the responder's own ``flooding`` alarm (its wearable's frames)


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


def lane_of(kind: str) -> str:
    """The budget lane of a message kind (the last part of its key)."""
    return kind if kind in LANES else "other"


@dataclass
class Lane:
    """One budget of a source (bounded: a few numbers and a short deque)."""

    bucket: TokenBucket
    rejects: deque = field(default_factory=deque)  # receive times of recent rejects (at most bad_after)
    bad: bool = False
    throttled: int = 0  # messages refused by the budget, ever
    last_throttled: float = -math.inf


@dataclass
class SourceState:
    """What the intake keeps per source: its lanes (at most ``len(LANES) + 1``) and its drops."""

    lanes: dict = field(default_factory=dict)  # lane name -> Lane
    dropped: dict = field(default_factory=dict)  # intake reason (``{lane}_{reason}`` but for imu) -> count

    @property
    def last_throttled(self) -> float:
        return max((ln.last_throttled for ln in self.lanes.values()), default=-math.inf)

    def __setstate__(self, state: dict) -> None:
        """A source pickled before lanes (one bucket per source) becomes one with that bucket as
        its frames' lane, so a snapshot of an older service still resumes."""
        if "bucket" in state:
            old = {k: state.pop(k) for k in ("bucket", "rejects", "bad", "throttled", "last_throttled") if k in state}
            state["lanes"] = {ALARM_LANE: Lane(**old)}
        self.__dict__.update(state)


class Intake:
    """Per-source budgets and admission (see the module docstring); ``reason = intake.admit(...)``."""

    in_hand = ALARM_LANE  # (class default: an intake pickled before lanes)

    def __init__(self, settings: IntakeSettings | None = None):
        self.settings = settings or IntakeSettings()
        s = self.settings
        self.sources: dict[str, SourceState] = {}
        self._admit: TokenBucket | None = None
        self.pseudo = (BAD_KEY, NEW_IDS, OPERATORS)  # sources of messages no responder can be charged with
        self.admitted = 0  # new responder ids admitted, ever
        self.counts: dict[str, int] = {}  # intake reason -> messages refused, over all sources
        self._roster = s.roster or frozenset()
        self.in_hand = ALARM_LANE  # the lane of the message the core is processing (its rejects go there)

    # ------------------------------------------------------------------ the check
    def admit(self, parts: KeyParts | ValueError, size: int, now: float,
              known: Container[str] = ()) -> tuple[str | None, str]:
        """``(None, source)`` when the message may go on, else ``(reason, source)``. ``parts``:
        its key as the shell read it (:func:`service.protocol.keys.read_key`; a ValueError, a
        key that is not one, is ``bad_key``). ``known`` holds the responders the core has
        (restored from a snapshot, or fed without the intake); an id neither there nor admitted
        before is new."""
        if isinstance(parts, ValueError):  # (a pseudo-source's name is no id: never a key's)
            return self._refuse(BAD_KEY, "bad_key", now), BAD_KEY
        rid = parts.responder
        src = self.sources.get(rid)
        if src is None:
            if rid in known:
                src = self._source(rid)
            elif parts.kind == "fix":  # a fix for an id nobody has made yet: it makes nobody
                pseudo = self.sources.get(NEW_IDS) or self._source(NEW_IDS)
                return self._charge(pseudo, "fix", size, now), NEW_IDS
            else:
                if not self._may_admit(rid, now):
                    return self._refuse(NEW_IDS, "not_admitted", now), NEW_IDS
                src = self._source(rid)
                self.admitted += 1
        lane = "anchor" if parts.sender is not None else (parts.kind if parts.kind in _LANE_SET else "other")
        if size > self.settings.max_payload_bytes:
            return self._drop(src, "oversize", lane), rid
        ln = src.lanes.get(lane) or self._lane(src, lane, now)  # _charge, inlined: the flood's hot path
        if ln.bad:
            self._maybe_rehabilitate(ln, now)
        if not ln.bucket.take(now):
            ln.throttled += 1
            ln.last_throttled = now
            return self._drop(src, "throttled", lane), rid
        return None, rid

    def admit_shared(self, source: str, size: int, now: float, lane: str = "op") -> str | None:
        """A message charged to a pseudo-source (``<operators>``): its size and that source's
        budget; no admission, no responder. None when it may go on, else the reason."""
        src = self.sources.get(source)
        if src is None:
            src = self._source(source)
        return self._charge(src, lane_of(lane), size, now)

    def _charge(self, src: SourceState, lane: str, size: int, now: float) -> str | None:
        """The size check, then one token of the lane's bucket."""
        if size > self.settings.max_payload_bytes:
            return self._drop(src, "oversize", lane)
        ln = src.lanes.get(lane) or self._lane(src, lane, now)
        if ln.bad:
            self._maybe_rehabilitate(ln, now)
        if not ln.bucket.take(now):
            ln.throttled += 1
            ln.last_throttled = now
            return self._drop(src, "throttled", lane)
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

    def _maybe_rehabilitate(self, ln: Lane, now: float) -> None:
        """A lane held to the bad-sender budget that has neither been rejected nor throttled
        for ``bad_window_s`` gets the ordinary budget back."""
        s = self.settings
        if (not ln.rejects or now - ln.rejects[-1] > s.bad_window_s) and now - ln.last_throttled > s.bad_window_s:
            ln.bad = False
            ln.rejects.clear()
            ln.bucket.limit(s.source_rate, s.source_burst)

    # ------------------------------------------------------------------ feedback
    def note_reject(self, source: str, now: float, lane: str | None = None) -> None:
        """A message of ``source`` that passed the intake was rejected later (decode, schema):
        ``bad_after`` of them within ``bad_window_s`` hold that lane of the source (default:
        the lane of the message in hand, :attr:`in_hand`) to the bad-sender budget."""
        src = self.sources.get(source)
        if src is None:
            return
        s = self.settings
        ln = self._lane(src, lane_of(lane or self.in_hand), now)
        q = ln.rejects
        q.append(now)
        while q and (now - q[0] > s.bad_window_s or len(q) > s.bad_after):
            q.popleft()
        if not ln.bad and len(q) >= s.bad_after:
            ln.bad = True
            ln.bucket.limit(s.bad_rate, s.bad_burst)

    def flooding(self, source: str, now: float, lane: str | None = ALARM_LANE) -> bool:
        """Was ``source``'s ``lane`` (None: any of its lanes) throttled within ``flood_alarm_s``?"""
        src = self.sources.get(source)
        if src is None:
            return False
        last = src.last_throttled if lane is None else getattr(src.lanes.get(lane), "last_throttled", -math.inf)
        return now - last <= self.settings.flood_alarm_s

    def flooding_sources(self, now: float) -> list[str]:
        """Every source (responder ids and the pseudo-sources) throttled within ``flood_alarm_s``:
        its name for its frames' lane (or any lane of a pseudo-source), ``{name}/{lane}`` for the others."""
        out = []
        for name, src in self.sources.items():
            for lane, ln in src.lanes.items():
                if now - ln.last_throttled <= self.settings.flood_alarm_s:
                    out.append(name if lane == ALARM_LANE or name in self.pseudo else f"{name}/{lane}")
        return list(dict.fromkeys(out))

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
    def _source(self, name: str) -> SourceState:
        src = self.sources[name] = SourceState()
        return src

    def _lane(self, src: SourceState, lane: str, now: float) -> Lane:
        ln = src.lanes.get(lane)
        if ln is None:
            s = self.settings
            ln = src.lanes[lane] = Lane(TokenBucket(s.source_rate, s.source_burst, now))
        return ln

    def _refuse(self, pseudo: str, reason: str, now: float) -> str:
        src = self.sources.get(pseudo)
        if src is None:
            src = self._source(pseudo)
        ln = self._lane(src, ALARM_LANE, now)
        if not ln.bucket.take(now):  # the pseudo-source floods: the alarm names it
            ln.throttled += 1
            ln.last_throttled = now
        return self._drop(src, reason, ALARM_LANE)

    def _drop(self, src: SourceState, reason: str, lane: str) -> str:
        name = reason if lane == ALARM_LANE or reason in _UNLANED else f"{lane}_{reason}"
        src.dropped[name] = src.dropped.get(name, 0) + 1
        self.counts[reason] = self.counts.get(reason, 0) + 1
        return reason
