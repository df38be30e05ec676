"""Frames into tracks: streams, gaps and clock leaps, and the rounds that run the motion
models (columnar for handhelds, one responder at a time otherwise).

A collaborator of :class:`service.core.incident_core.IncidentCore`: the core hands it each
responder's released frames (:meth:`FrameRounds.process`) and runs the round's end
(:meth:`FrameRounds.run_dirty`); poses go to the core's :class:`service.core.pose_output.Outbox`.
"""
from __future__ import annotations

import logging
import math

from pdr.events import MotionEvent
from pdr.fleet import FleetMember, PdrFleet
from service.core.core_types import CoreClock, CoreCounters, CoreSettings
from service.core.fix_audit import FixAudit
from service.core.pose_output import Outbox
from service.core.rejects import RejectBook
from service.core.responder import Responder, continues, frame_of
from service.core.tracker import (
    PoseEstimate,
)
from service.protocol import wire

log = logging.getLogger("firetrack.service")


class FrameRounds:
    """Frames into tracks: streams, gaps, clock leaps, and the rounds that run the motion models (columnar or one responder at a time)."""

    def __init__(self, settings: CoreSettings, fleet: PdrFleet | None, clock: CoreClock, counters: CoreCounters,
                 rejects: RejectBook, outbox: Outbox, fix_audit: FixAudit):
        self.settings, self.fleet, self.clock, self.counters = settings, fleet, clock, counters
        self.rejects, self.outbox, self.fix_audit = rejects, outbox, fix_audit
        self.dirty: dict[str, Responder] = {}  # responders with frames waiting for the round's end

    def offer(self, r: Responder, batch: wire.ImuBatch, now: float) -> bool:
        """A decoded frame of ``r`` through its gate, the frames it releases on to the tracker
        (at the round's end); True when a gap in front of held frames should be asked for now
        (the wearable's Status names it)."""
        if batch.utc_offset is not None:
            r.utc_offset = batch.utc_offset
        rejected_before = r.gate.rejected
        released = r.gate.offer(batch, now, r.taken_late_s() if r.gate.waiting else 0.0)
        if r.gate.rejected > rejected_before:  # the gate records why in its newest event
            _, reason, detail = r.gate.events[-1]
            self.rejects.noted(r, reason, f"frame {batch.seq}: {detail}", now)
        for b in released:
            self.process(r, b)
        return r.gate.ask() is not None

    def process(self, r: Responder, b: wire.ImuBatch) -> None:
        """A frame the gate released, for the round's end (frame by frame while a fix waits)."""
        if b is r.gate.first_of_stream and b is not r.stream_start:
            self._new_stream(r, b)
            r.lag.reset()  # another device clock (service.core.lag)
        r.lag.note(self.clock.now, float(b.t[-1]), base=b is not r.gate.first_of_stream)
        t0 = float(b.t[0]) + r.t_offset
        if math.isfinite(r.last_t) and t0 - r.last_t > self.settings.gap_reanchor_s:
            self.run_backlog(r)  # the frames before the gap go first
            t0 = self._bound_leap(r, b, t0)
            self._gap(r, r.last_t, t0)
        if r.backlog and (not continues(r.backlog[-1], b) or len(r.backlog) >= self.settings.max_coalesce):
            self.run_backlog(r)
        r.backlog.append(b)
        r.last_t = float(b.t[-1]) + r.t_offset
        r.last_rt = self.clock.now
        self.dirty[r.id] = r  # run at the round's end (frame by frame while a fix waits: see run_backlog)

    def _new_stream(self, r: Responder, b: wire.ImuBatch) -> None:
        """The gate opened a stream with ``b``: the first of the responder, or a new one (a
        restarted wearable, another device, a counter reset) that continues the same track.
        Its device clock is the track's if its first sample follows the last one within the
        receive-time gap; otherwise it is put on the track's clock after that gap."""
        self.run_backlog(r)  # the old stream's last frames end at the old clock
        r.stream_start = b
        if not math.isfinite(r.last_t):
            return
        s = self.settings
        gap = max(self.clock.now - r.last_rt, 0.0) if r.last_rt is not None else 0.0
        t0 = float(b.t[0])
        ahead = t0 - (r.last_t - r.t_offset)
        if not 0.0 < ahead <= gap + s.same_clock_tolerance_s:
            r.t_offset = r.last_t + max(gap, s.min_stream_gap_s) - t0
        log.warning("%s: new stream (device %s, boot %s) after %.1f s; the track continues%s", r.id, b.device,
                    b.boot, gap, "" if r.t_offset == 0.0 else f" (its clock is {r.t_offset:+.3f} s from the track's)")

    def _bound_leap(self, r: Responder, b: wire.ImuBatch, t0: float) -> float:
        """A device clock that leaps further ahead than the service's clock went (by more than
        ``max_clock_lead_s``) is put back on the track's clock after the receive-time gap:
        a broken or hostile clock must not make the motion model walk through hours of
        nothing (its state grid would grow with them). Returns the frame's new track time."""
        s = self.settings
        rgap = max(self.clock.now - r.last_rt, 0.0) if r.last_rt is not None else 0.0
        if t0 - r.last_t <= rgap + s.max_clock_lead_s:
            return t0
        leap = t0 - r.last_t
        r.t_offset -= leap - max(rgap, s.min_stream_gap_s)
        self.rejects.log.note(r.id, "clock_leap", f"frame {b.seq}: device time leapt {leap:.1f} s in {rgap:.1f} s; "
                                                 "the track goes on after the receive-time gap", self.clock.now)
        return float(b.t[0]) + r.t_offset

    def _gap(self, r: Responder, t_from: float, t_to: float) -> None:
        """No frames between ``t_from`` and ``t_to`` (track clock): the tracker widens the step
        across it, and the motionlessness before it no longer counts towards man-down."""
        r.gap_end = t_to
        r.tracker.note_gap(t_from, t_to, self.settings.gap_speed_mps * (t_to - t_from))

    def run_dirty(self) -> None:
        """The round's end: every responder's waiting frames through its tracker; those on the
        handheld pipeline together, a stage at a time (:meth:`_run_columnar`)."""
        dirty, self.dirty = self.dirty, {}
        columns: list[Responder] = []
        for r in dirty.values():
            if r.backlog and isinstance(r.tracker.choose_model(r.backlog[0].carry), FleetMember):
                columns.append(r)
                continue
            try:
                self.run_backlog(r)
            except Exception:
                self.counters.errors += 1
                log.exception("error while running the frames of %s", r.id)
        if columns:
            self._run_columnar(columns)

    def _run_columnar(self, responders: list[Responder]) -> None:
        """Responders on the fleet's pipeline: their frames in one columnar round, then each
        one's events through its tracker. The events are those of one responder at a time, bit
        for bit (:mod:`pdr.fleet`). While a fix waits for its step a responder gives one frame
        per round (:meth:`_next_batches`), so its frames run one at a time as alone. A frame the
        pipeline refuses takes the one-at-a-time path, which finds the culprit."""
        while responders:
            items = [(r, self._next_batches(r)) for r in responders]
            try:
                results = self.fleet.run([(r.tracker.model, frame_of(batches)) for r, batches in items])
            except Exception:  # a bug in the round: each responder alone, so that one cannot stop the others
                self.counters.errors += 1
                log.exception("error in a columnar round of %d responders", len(items))
                results = [None] * len(items)
            for (r, batches), events in zip(items, results):
                try:
                    if events is None or isinstance(events, Exception):
                        r.backlog = batches + r.backlog
                        self.run_backlog(r)
                        continue
                    self._after_batches(r, batches, r.tracker.on_events(events))
                except Exception:
                    self.counters.errors += 1
                    log.exception("error while running the frames of %s", r.id)
            responders = [r for r, _ in items if r.backlog]

    @staticmethod
    def _next_batches(r: Responder) -> list:
        """The frames a responder's tracker takes next as one batch: all it has, or one while a
        checkpoint fix waits for its step (``ResponderTracker.fix_waiting``)."""
        if len(r.backlog) > 1 and r.tracker.fix_waiting:  # the cheap test first: most rounds give one frame
            batches, r.backlog = r.backlog[:1], r.backlog[1:]
        else:
            batches, r.backlog = r.backlog, []
        return batches

    def run_backlog(self, r: Responder) -> None:
        """The responder's waiting frames through its tracker, as one batch (one at a time while
        a fix waits); poses out."""
        while r.backlog:
            self._run_batches(r, self._next_batches(r))

    def _run_batches(self, r: Responder, batches: list) -> None:
        try:
            outputs = r.tracker.on_frame(frame_of(batches, r.t_offset), batches[0].carry)
        except ValueError as e:  # e.g. a frame the gate let through that the pipeline cannot take
            if len(batches) > 1:  # the check comes before any state changes: find the culprit alone
                for b in batches:
                    self._run_batches(r, [b])
                return
            self.rejects.frame(r, "pipeline", f"frame {batches[0].seq}: {e}", self.clock.now)
            return
        self._after_batches(r, batches, outputs)

    def _after_batches(self, r: Responder, batches: list, outputs: list) -> None:
        r.seq, r.seq_oldest = batches[-1].seq, batches[0].seq
        self.counters.frames_processed += len(batches)
        self.counters.tracker_batches += 1
        for o in outputs:
            if isinstance(o, PoseEstimate):
                self.outbox.pose(r, o, self.clock.now)
            elif isinstance(o, MotionEvent):
                log.info("%s is %s since device time %.1f", r.id, o.state.value, o.since)
        if r.tracker.held_out or r.tracker.readmitted:  # a queued fix judged at its step: audited with its sender
            self.fix_audit.tracker_verdicts(r)
