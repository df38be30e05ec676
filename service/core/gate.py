"""The frame gate at the service edge: one per responder, pure (no zenoh, no clock of its own).

Frames (:class:`service.protocol.wire.ImuBatch`) can arrive twice, out of order, late or not at all;
the PDR pipeline behind the gate needs each frame once, in order, with strictly increasing
device time. :class:`FrameGate` turns the first stream into the second and counts what it
turns away, so nothing is dropped silently.

Reorder policy
--------------
``next`` is the seq the gate releases next. A frame with ``seq == next`` is released at once,
followed by any held frames that are now consecutive. A frame with ``seq > next`` is held. When
more than ``reorder_window`` frames are held, the frames between ``next`` and the lowest held
seq are declared lost (one gap, ``lost`` += their number) and release resumes from the lowest
held frame. So a frame is released when no more than ``reorder_window`` frames with a higher
seq arrived before it, and lost otherwise. Held frames also leave, with the same rule, once the
oldest has waited ``max_hold_s`` of receive time (:meth:`FrameGate.expire`, also run by every
:meth:`FrameGate.offer`), so one lost frame never stalls a responder for long.
The first frame of a stream is released at once and sets ``next``, unless its seq is above 0
and within ``ask_from_start``: a wearable counts from 0, so frames ``[0, seq - 1]`` were sent
and not received. That frame is then held and the run asked for, as for any gap (below).
This is what catches the first frames of a route that zenoh's advanced subscriber dropped:
a subscriber declared just after the wearable began (a shard's route, a standby taking over)
delivers a live frame that beats its history reply and then drops the older history frames
(seen under load: 212 of 240 frames taken, all acknowledged, the rest never counted).

Resend. A gap in front of held frames is also *asked for*: :meth:`FrameGate.ask` names the
missing run ``[next, lowest held - 1]`` once per gap, the core puts it in the responder's
``Status.missing`` and the wearable resends those frames from its own keep
(:mod:`client.wearable`). Meanwhile the gate holds up to ``max_held`` frames (and
``max_held_samples``; a stream's asked-for beginning by samples only) for ``resend_wait_s``
plus the responder's lag (a worker behind takes the resend as late as what queued before it),
counted from the newest resent frame once the resend comes; what does not come is declared
lost as before. This fills a gap zenoh's own recovery cannot: after a service restart the
advanced subscriber delivers a wearable's first live frame when it beats the history reply,
then drops the older history frames (zenoh-ext ``advanced_subscriber.rs``).

Rejects (counted by reason in :attr:`FrameGate.counts`, logged in :attr:`FrameGate.events`):

* ``duplicate``: the seq is held, or was released already;
* ``late``: the seq is below ``next`` and was never released (declared lost, or older than the
  first frame);
* ``time_order``: the frame's first sample is not after the last released sample (judged when
  its turn comes, so the frame still uses up its seq and nobody waits for it).

Device time between consecutive released frames that jumps by more than ``max_gap_s`` counts
as a gap (the frame is released; the pipeline decides what a gap means to it).

Streams. A stream is one run of seq numbers from one start of one wearable, named by
``(device, boot)`` (:attr:`service.protocol.wire.ImuBatch.boot`, a random id per start). A new
stream begins (``epoch`` grows, held frames are released, ``next`` and the time check are
forgotten) when

* a frame names another ``(device, boot)`` than the current stream: a restarted wearable, or
  another device for the same responder. The stream it replaces is *retired*: its frames
  still in flight are turned away (``old_stream``) instead of switching back;
* a frame's seq goes back while its time goes on (``seq < next`` and its first sample after the
  last released one): the wearable's counter restarted, whatever its ``boot`` says;
* a frame's seq jumps ahead by more than ``max_seq_jump``: a counter that restarted elsewhere,
  not a loss (which would otherwise count that many frames lost);
* without a ``boot`` (an older wearable), a frame that would be rejected as above after
  ``restart_after_s`` of silence (a rebooted wearable whose clock also went back).

**A stream cannot be taken over.** A new ``(device, boot)`` must prove itself: it replaces the
current stream only once the current one has been silent (no frame naming it heard) for
``takeover_after_s`` (6 s), or when it *continues* the current one (its seq is the next one and
its first sample follows the last released one within ``max_gap_s``) after ``restart_quiet_s`` of
quiet. Silence is weak proof of a restart (a phone's Wi-Fi stalls, a service starves: 2.4 s seen
in CI, where a forged boot took a track over with the old 2 s); 6 s covers such stalls and stays
below ``lost_contact_s`` (10 s). A restarted wearable waits at most 6 s once; its frames keep
their own times, so the track and man-down come out the same. Until then its frames are a **candidate**: held (one
candidate at a time, at most ``max_candidate`` frames and ``max_held_samples`` samples, each for
at most ``2 * takeover_after_s``), so a restart that comes sooner than the old stream's silence
is proven loses nothing; they are released in order when it takes over, and whatever of it did
not fit is asked for again like any gap (``Status.missing`` names the new boot; the wearable
resends from its keep). The current stream speaking ``restart_quiet_s`` or more after a
candidate's first frame (no restart does that) sets ``last_contested`` at once.
Frames of any other stream, and candidate frames that age out or do not fit, are turned away
(``other_stream``) and counted in :attr:`FrameGate.contested` (``last_contested``: the core's
``stream_contested`` alarm); the real stream keeps being tracked. The counter restarts and jumps
within one ``(device, boot)`` need ``restart_quiet_s`` of quiet; before that they are turned
away (``seq_jump``, or as duplicates).

Every new stream is a gap (``gaps``, ``gap_s``); the core continues the track across epochs.
Counts. ``lost`` frames (seq never released), ``gaps`` (runs of lost frames, device-time jumps
over ``max_gap_s``, new streams) and ``gap_s`` (the seconds they span: across lost frames or a
jump, the receive-time gap before a new stream) are what ``Status`` reports: no silent loss.
"""
from __future__ import annotations

import logging
import math
from collections import Counter, deque

from service.protocol.wire import ImuBatch

log = logging.getLogger("firetrack.service")

GATE_REASONS = ("duplicate", "late", "time_order", "old_stream", "other_stream", "seq_jump")
RESEND_WAIT_S = 2.0  # s an asked-for gap is waited for (beyond the responder's lag: see FrameGate.expire)
MAX_RESEND_SLACK_S = 10.0  # s the lag may add to that wait at most
# frames held while an asked-for gap is waited for. A takeover's history reply comes as one burst
# beyond the gap the snapshot left (a standby: the snapshot's age plus the takeover, 50-70 frames at
# 10 frames/s; a simulated wearable's whole zenoh keep, 100): 64 declared the gap lost before the
# resend could come. The wait stays bounded by time (resend_wait_s + lag) and by MAX_HELD_SAMPLES.
MAX_HELD = 256
MAX_HELD_SAMPLES = 8192  # and samples in them (a frame holds up to MAX_SAMPLES)
TAKEOVER_AFTER_S = 6.0  # s of silence of the current stream before another (device, boot) may replace it
MAX_CANDIDATE = 128  # frames of a candidate stream held meanwhile (10 frames/s for 2 * TAKEOVER_AFTER_S, and more)
RESTART_QUIET_S = 0.5  # s of quiet before a counter restart, or a stream that continues the current one


class FrameGate:
    """Per-responder reorder buffer and reject counter: ``released = gate.offer(batch, now)``."""

    # class defaults: gates restored from a snapshot taken before resends (and candidates) existed
    _asked: tuple[int, int] | None = None  # the run last asked for
    resend_wait_s, max_held, max_held_samples = RESEND_WAIT_S, MAX_HELD, MAX_HELD_SAMPLES
    restart_quiet_s, max_candidate = RESTART_QUIET_S, MAX_CANDIDATE
    _stream_heard: float | None = None  # receive time of the newest frame naming the current stream
    _resend_heard = -math.inf  # receive time of the newest frame of the asked-for run
    _candidate: tuple[str, str | None] | None = None  # the stream that waits to take over ...
    _candidate_held: dict | None = None  # ... its frames: seq -> (frame, receive time)
    ask_from_start = 0  # a stream's first seq up to which its frames [0, seq - 1] are asked for (0: never)
    contested = 0  # frames of other streams turned away (or of a candidate that did not take over)
    last_contested = -math.inf  # receive time of the newest one
    who = "?"  # the responder's id, for the log (set by the core)

    def __init__(self, reorder_window: int = 4, max_gap_s: float = 0.5, *, max_hold_s: float = 1.0,
                 restart_after_s: float = 30.0, max_events: int = 256, max_seq_jump: int = 100_000,
                 max_retired: int = 16, takeover_after_s: float = TAKEOVER_AFTER_S, resend_wait_s: float = RESEND_WAIT_S,
                 max_held: int = MAX_HELD, max_held_samples: int = MAX_HELD_SAMPLES,
                 restart_quiet_s: float = RESTART_QUIET_S, ask_from_start: int = 0, max_candidate: int = MAX_CANDIDATE):
        if reorder_window < 0:
            raise ValueError(f"reorder_window must be >= 0, got {reorder_window}")
        if not max_gap_s > 0 or not max_hold_s > 0 or not restart_after_s > 0:
            raise ValueError("max_gap_s, max_hold_s and restart_after_s must be positive")
        if max_seq_jump < 1:
            raise ValueError(f"max_seq_jump must be >= 1 frames, got {max_seq_jump}")
        if not resend_wait_s >= max_hold_s or max_held < reorder_window or max_held_samples < 1:
            raise ValueError("resend_wait_s must be >= max_hold_s, max_held >= reorder_window, max_held_samples >= 1")
        self.reorder_window, self.max_held, self.max_held_samples = int(reorder_window), int(max_held), int(max_held_samples)
        self.resend_wait_s, self.max_gap_s, self.max_hold_s = float(resend_wait_s), float(max_gap_s), float(max_hold_s)
        self.restart_after_s, self.takeover_after_s = float(restart_after_s), float(takeover_after_s)
        self.max_seq_jump = int(max_seq_jump)
        if not takeover_after_s > 0 or max_candidate < 1:
            raise ValueError(f"takeover_after_s must be positive and max_candidate >= 1, got {takeover_after_s}, "
                             f"{max_candidate}")
        self.max_candidate = int(max_candidate)
        self.restart_quiet_s = float(restart_quiet_s)
        if ask_from_start < 0:
            raise ValueError(f"ask_from_start must be >= 0 frames, got {ask_from_start}")
        self.ask_from_start = int(ask_from_start)
        self.events: deque[tuple[float, str, str]] = deque(maxlen=max_events)
        self._counts: Counter[str] = Counter()
        self.offered = 0  # frames passed to offer()
        self.accepted = 0  # frames released
        self.rejected = 0  # offered frames the gate turned away (decode rejects counted via count() excluded)
        self.gaps = 0  # discontinuities: runs of lost frames, device-time jumps > max_gap_s
        self.lost = 0  # frames declared lost
        self.epoch = 0  # restarts
        self.gap_s = 0.0  # s spanned by the gaps (device time across a loss or jump, receive time before a new stream)
        self.last_heard: float | None = None  # receive time of the last frame (or counted reject)
        self._stream: tuple[str, str | None] | None = None  # (device, boot) of the current stream
        self._retired: deque[tuple[str, str]] = deque(maxlen=max_retired)  # streams replaced by a newer one
        self._released_at: float | None = None  # receive time of the newest released frame
        self.first_of_stream: ImuBatch | None = None  # the first frame released of the current stream
        self._held: dict[int, tuple[ImuBatch, float]] = {}
        self._reset_stream()

    def _reset_stream(self) -> None:
        self._asked = None
        self._next: int | None = None
        self._first: int | None = None
        self._last_t: float | None = None
        self._last_seq: int | None = None
        self._lost_runs: deque[tuple[int, int]] = deque(maxlen=256)  # [lo, hi) seq runs declared lost

    # -- what the service reads ---------------------------------------------------------
    @property
    def counts(self) -> dict[str, int]:
        """Rejects by reason: the gate's (duplicate, late, time_order) and any added by count()."""
        return dict(self._counts)

    @property
    def held(self) -> int:
        return len(self._held)

    @property
    def waiting(self) -> bool:
        """Anything held that a later :meth:`expire` may settle (frames, or a candidate stream's)."""
        return bool(self._held or self._candidate_held)

    @property
    def next_seq(self) -> int | None:
        return self._next

    @property
    def last_t(self) -> float | None:
        """Device time of the last released sample."""
        return self._last_t

    @property
    def last_seq(self) -> int | None:
        """Seq of the newest released frame of the current stream (what the wearable may count as taken)."""
        return self._last_seq

    @property
    def device(self) -> str | None:
        return None if self._stream is None else self._stream[0]

    @property
    def boot(self) -> str | None:
        return None if self._stream is None else self._stream[1]

    @property
    def streams(self) -> int:
        """Streams seen: 0 before the first frame, then 1 + the restarts."""
        return 0 if self._stream is None else self.epoch + 1

    def count(self, reason: str, detail: str, receive_time: float | None = None) -> None:
        """Count a reject found elsewhere (a decode error: :data:`service.protocol.wire.REJECT_REASONS`)."""
        if receive_time is not None:
            self.last_heard = receive_time
        self._counts[reason] += 1
        when = receive_time if receive_time is not None else (self.last_heard if self.last_heard is not None else math.nan)
        self.events.append((when, reason, detail))

    def add_counts(self, counts: dict[str, int]) -> None:
        """Rejects counted before the gate existed (a newcomer's: :class:`service.core.responder.Newcomer`)."""
        for reason, n in counts.items():
            self._counts[reason] += n

    # -- the gate -----------------------------------------------------------------------
    def offer(self, batch: ImuBatch, receive_time: float, slack: float = 0.0) -> list[ImuBatch]:
        """Take one frame; return the frames released by it, in order (possibly none).
        ``slack``: s an asked-for gap waits beyond ``resend_wait_s`` (:meth:`expire`)."""
        self.offered += 1
        stream = (batch.device, batch.boot)
        # the frame a gap waits for is taken before the wait is judged: after a stall of the
        # worker (the frames and the resend waited in the channel meanwhile) it fills the gap
        # instead of arriving just after the gap was declared lost
        fills = bool(self._held) and stream == self._stream and batch.seq == self._next
        if stream == self._stream and self._waiting() and self._next <= batch.seq <= self._asked[1]:
            self._resend_heard = receive_time  # a missing frame came (the resend, late, in pieces): wait again
        out = [] if fills else self.expire(receive_time, slack)
        if self._stream is not None and stream != self._stream:
            if batch.boot is not None and stream in self._retired:
                self._reject(receive_time, "old_stream", f"seq {batch.seq} of device {batch.device!r} boot "
                                                         f"{batch.boot!r}, which a newer stream replaced")
                return out
            if not self._proves_itself(batch, receive_time):
                self._hold_candidate(batch, receive_time)
                return out
            out += self._take_over(stream, receive_time)
        elif self._candidate_held and receive_time - min(rt for _, rt in self._candidate_held.values()) \
                >= self.restart_quiet_s:  # the live stream speaks while another waits: contested at once
            self.last_contested = receive_time
        return out + self._offer_in_stream(batch, receive_time)

    def _proves_itself(self, batch: ImuBatch, now: float) -> bool:
        """May the frame of another stream replace the current one? After ``takeover_after_s``
        of the current stream's silence, or continuing it (next seq, next sample) after
        ``restart_quiet_s`` of quiet."""
        heard = self._stream_heard if self._stream_heard is not None else self._released_at
        silent = math.inf if heard is None else now - heard
        if silent >= self.takeover_after_s:
            return True
        return (silent >= self.restart_quiet_s and self._last_seq is not None and batch.seq == self._last_seq + 1
                and self._last_t is not None and 0.0 < float(batch.t[0]) - self._last_t <= self.max_gap_s)

    def _hold_candidate(self, batch: ImuBatch, now: float) -> None:
        """A frame of a stream that has not proven itself: held as the candidate's (the first
        such stream, within ``max_candidate`` frames and ``max_held_samples`` samples), else
        turned away."""
        stream = (batch.device, batch.boot)
        if self._candidate is None or not self._candidate_held:
            self._candidate, self._candidate_held = stream, {}
        held = self._candidate_held
        fits = (len(held) < self.max_candidate
                and sum(len(b.t) for b, _ in held.values()) + len(batch.t) <= self.max_held_samples)
        if stream == self._candidate and fits and batch.seq not in held:
            held[batch.seq] = (batch, now)
            return
        self._contest(now, f"seq {batch.seq} of device {batch.device!r} boot {batch.boot!r} while {self._stream} "
                           "is live")

    def _contest(self, now: float, detail: str) -> None:
        self.contested += 1
        self.last_contested = now
        self._reject(now, "other_stream", detail)

    def _take_over(self, stream: tuple[str, str | None], now: float) -> list[ImuBatch]:
        """``stream`` replaces the current one: the current is retired, the candidate's held
        frames (if ``stream`` is the candidate) are offered first, in seq order."""
        old_device, old_boot = self._stream
        why = (f"device changed from {old_device!r} to {stream[0]!r}" if stream[0] != old_device
               else f"device {stream[0]!r} restarted (boot {old_boot!r} -> {stream[1]!r})")
        if old_boot is not None:
            self._retired.append(self._stream)
        held = (self._candidate_held or {}) if self._candidate == stream else {}
        self._candidate, self._candidate_held = None, None
        out = self._restart(min([now, *(rt for _, rt in held.values())]), why)  # the gap ends at its first frame
        self._stream, self._stream_heard = stream, None
        for seq in sorted(held):
            out += self._offer_in_stream(held[seq][0], held[seq][1])
        return out

    def _offer_in_stream(self, batch: ImuBatch, receive_time: float) -> list[ImuBatch]:
        """A frame of the current stream (or the first of the gate, or of a stream taking over)."""
        out: list[ImuBatch] = []
        silence = receive_time - self.last_heard if self.last_heard is not None else 0.0
        quiet = self._released_at is None or receive_time - self._released_at >= self.restart_quiet_s
        self.last_heard = receive_time
        self._stream_heard = max(receive_time, self._stream_heard or -math.inf)
        self._stream = (batch.device, batch.boot)
        verdict = self._seq_verdict(batch)
        if verdict is not None and quiet and self._counter_restarted(batch):
            out += self._restart(receive_time, f"seq {batch.seq} after seq {self._last_seq} while time went on "
                                               f"(t[0] = {float(batch.t[0])!r} s): the counter restarted")
            verdict = None
        elif self._next is not None and batch.seq - self._next > self.max_seq_jump:
            if not quiet:
                self._reject(receive_time, "seq_jump", f"seq {batch.seq} is {batch.seq - self._next} frames ahead "
                                                       f"of the next expected ({self._next}) in a live stream")
                return out
            out += self._restart(receive_time, f"seq {batch.seq} is {batch.seq - self._next} frames ahead of the next "
                                               f"expected ({self._next}): the counter restarted")
        elif batch.boot is None and silence >= self.restart_after_s and (verdict or self._time_verdict(batch)):
            why = (verdict or self._time_verdict(batch))[0]
            out += self._restart(receive_time, f"seq {batch.seq} after {silence:.1f} s of silence ({why} "
                                               "otherwise): new stream")
            verdict = None
        if verdict is not None:
            self._reject(receive_time, *verdict)
            return out
        if self._next is None and 0 < batch.seq <= self.ask_from_start:
            self._next = 0  # the stream began at 0: what came before this frame is asked for
        if self._next is None or batch.seq == self._next:
            self._release(batch, receive_time, out)
            self._drain(receive_time, out)
        else:
            self._held[batch.seq] = (batch, receive_time)
            while self._held and self._over_hold():
                self._skip_to_held(receive_time, out, f"more than {self.max_held} frames (or {self.max_held_samples} "
                                   "samples) arrived after it while its resend was awaited" if self._waiting() else
                                   f"more than {self.reorder_window} frames arrived after it")
        return out

    def ask(self) -> tuple[int, int] | None:
        """The run of seqs missing in front of the held frames, ``(first, last)``, the first time
        it is asked for (None when nothing is missing, or it is part of the run asked already
        while the resend fills it from below); from now on the gate waits for it by
        :attr:`resend_wait_s` and :attr:`max_held`."""
        if not self._held or self._next is None or self._waiting():
            return None
        self._asked = (self._next, min(self._held) - 1)
        return self._asked

    @property
    def missing(self) -> tuple[int, int] | None:
        """The asked-for run still missing, ``(first, last)`` seq of the current stream, or None."""
        return (self._next, min(self._held) - 1) if self._waiting() else None

    def _waiting(self) -> bool:
        """Frames are held in front of a gap that was asked for (the resend may fill it from below)."""
        return (bool(self._held) and self._next is not None and self._asked is not None
                and self._asked[0] <= self._next <= self._asked[1])

    def _over_hold(self) -> bool:
        if not self._waiting():
            return len(self._held) > self.reorder_window
        samples = sum(len(b.t) for b, _ in self._held.values())
        if self._first is None:  # a stream's beginning is awaited (a backlog may bring many frames): samples bound it
            return samples > self.max_held_samples
        return len(self._held) > self.max_held or samples > self.max_held_samples

    def expire(self, now: float, slack: float = 0.0) -> list[ImuBatch]:
        """Release held frames whose wait exceeded ``max_hold_s`` (for an asked-for gap
        ``resend_wait_s + slack``); the missing ones are declared lost.

        ``slack``: how late the responder's frames are taken (its lag, at most ``MAX_RESEND_SLACK_S``):
        the resend queues behind what waits for a worker that is behind, and is taken that much later.
        The wait counts from the newest resent frame taken, if that is later than the oldest held."""
        out: list[ImuBatch] = []
        if self._candidate_held:
            out += self._settle_candidate(now)
        while self._held:
            since, wait = min(rt for _, rt in self._held.values()), self.max_hold_s
            if self._waiting():  # from the newest resent frame, if later: the rest of the resend follows it
                since, wait = max(since, self._resend_heard), self.resend_wait_s + min(max(slack, 0.0), MAX_RESEND_SLACK_S)
            if not now - since > wait:
                break
            self._skip_to_held(now, out, f"not received within {wait:g} s")
        return out

    def _settle_candidate(self, now: float) -> list[ImuBatch]:
        """The candidate takes over once the current stream has been silent for
        ``takeover_after_s``; its frames held longer than ``2 * takeover_after_s`` are turned away."""
        held = self._candidate_held
        for seq in [s for s, (_, rt) in held.items() if now - rt > 2 * self.takeover_after_s]:
            b, _ = held.pop(seq)
            self._contest(now, f"seq {seq} of device {b.device!r} boot {b.boot!r}: the stream did not take over "
                               f"from the live {self._stream} within {2 * self.takeover_after_s:g} s")
        if held and self._proves_itself(held[min(held)][0], now):
            return self._take_over(self._candidate, now)
        return []

    def flush(self) -> list[ImuBatch]:
        """Release everything held, in order (missing frames are declared lost)."""
        out: list[ImuBatch] = []
        now = self.last_heard if self.last_heard is not None else math.nan
        while self._held:
            self._skip_to_held(now, out, "flushed")
        return out

    def reset(self) -> list[ImuBatch]:
        """Start a new stream on purpose (held frames are released first)."""
        return self._restart(self.last_heard if self.last_heard is not None else math.nan, "reset")

    # -- internals ----------------------------------------------------------------------
    def _seq_verdict(self, batch: ImuBatch) -> tuple[str, str] | None:
        """Duplicate or late by seq. (Time order is judged on release, against the frame
        released just before, so a rejected frame still uses up its seq.)"""
        s = batch.seq
        if s in self._held:
            return "duplicate", f"seq {s} is already waiting to be released"
        if self._next is not None and s < self._next:
            if s >= self._first and not any(lo <= s < hi for lo, hi in self._lost_runs):
                return "duplicate", f"seq {s} was already released (next expected {self._next})"
            why = "was declared lost" if s >= self._first else f"precedes the first frame (seq {self._first})"
            return "late", f"seq {s} arrived after release moved on: it {why}; next expected {self._next}"
        return None

    def _counter_restarted(self, batch: ImuBatch) -> bool:
        """A lower seq whose first sample comes after the newest released one: no copy or
        straggler of this stream can be that (theirs are older), so the counter restarted."""
        return (self._next is not None and batch.seq < self._next and self._last_t is not None
                and batch.seq not in self._held and float(batch.t[0]) > self._last_t)

    def _time_verdict(self, batch: ImuBatch) -> tuple[str, str] | None:
        t0 = float(batch.t[0])
        if self._last_t is not None and not t0 > self._last_t:
            return "time_order", (f"seq {batch.seq}: t[0] = {t0!r} s is not after the last released sample "
                                  f"t = {self._last_t!r} s (seq {self._last_seq})")
        return None

    def _reject(self, now: float, reason: str, detail: str) -> None:
        self.rejected += 1
        self._counts[reason] += 1
        self.events.append((now, reason, detail))

    def _release(self, batch: ImuBatch, now: float, out: list[ImuBatch], gap_counted: bool = False) -> None:
        """Release ``batch`` (seq == next, or the first of a stream) unless its time goes back."""
        if self._first is None:
            self._first = batch.seq
            self.first_of_stream = batch  # the core continues the track from here as a new stream
        self._next = batch.seq + 1
        verdict = self._time_verdict(batch)
        if verdict is not None:
            self._reject(now, *verdict)
            return
        if self._last_t is not None:
            jump = float(batch.t[0]) - self._last_t
            if jump > self.max_gap_s:
                self.gap_s += jump
                if not gap_counted:
                    self.gaps += 1
                self.events.append((now, "gap", f"seq {batch.seq}: {jump:.3f} s of device time since the last "
                                               f"released sample (seq {self._last_seq})"))
        self._last_t = float(batch.t[-1])
        self._last_seq = batch.seq
        self._released_at = now
        self.accepted += 1
        out.append(batch)

    def _drain(self, now: float, out: list[ImuBatch]) -> None:
        while self._next in self._held:
            batch, _ = self._held.pop(self._next)
            self._release(batch, now, out)

    def _skip_to_held(self, now: float, out: list[ImuBatch], why: str) -> None:
        """Declare the frames before the lowest held one lost and release from there."""
        first = min(self._held)
        missing = first - self._next
        self._lost_runs.append((self._next, first))
        self.lost += missing
        self.gaps += 1
        span = f"seq {self._next}" if missing == 1 else f"seq {self._next}..{first - 1} ({missing} frames)"
        self.events.append((now, "lost", f"{span} lost: {why}"))
        log.warning("%s: %s lost: %s", self.who, span, why)  # counted in its Status too; said here for the log
        batch, _ = self._held.pop(first)
        self._next = first
        self._release(batch, now, out, gap_counted=True)
        self._drain(now, out)

    def _restart(self, now: float, why: str) -> list[ImuBatch]:
        out: list[ImuBatch] = []
        while self._held:
            self._skip_to_held(now, out, "stream restarted")
        self._reset_stream()
        self.epoch += 1
        self.gaps += 1
        if self._released_at is not None and now > self._released_at:
            self.gap_s += now - self._released_at
        self.events.append((now, "restart", why))
        return out
