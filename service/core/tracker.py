"""One responder in the service: raw frames and fixes in, poses and motion changes out.

:class:`ResponderTracker` joins a motion model (:mod:`service.core.motion`: the handheld PDR
pipeline, or the model registered for the wearable's carry position) with a track estimator
(:mod:`service.fusion.estimators`: the gtsam fusion, or dead reckoning alone) and applies
fixes at their own time. A dead-reckoning baseline with the same checkpoint resets is always
kept beside the estimator (``pdr_track``), so every run can be compared with it. The live
service, replays, ``firetrack reprocess`` and ``firetrack eval ipin`` all reach this class
through the incident core, so they give the same poses.

Floors. The motion model owns the floor (its floor tracker); a checkpoint with a floor
anchors it there as of the checkpoint's own time (a lift ridden between the checkpoint and the
next step is not undone), and the estimators receive checkpoints without a floor, so a floor
is never corrected twice. A floor change without a step (a lift) comes as a
:class:`pdr.events.FloorEvent` and republishes the latest pose on the new floor at its time.

Placement. A responder has no position until the first checkpoint fix (an operator at the
door, a tag reader, the IPIN initial landmark) or, when the incident configures an entry
point, until the first step (placed there with a wide sigma; the first checkpoint then
corrects the whole track). Steps before placement are counted (Status) but make no pose.

Fix timing. A fix stamped later than the newest step waits until a step passes its time,
then attaches there (so an IPIN landmark reached after the last step before it attaches to
that step's pose, as it would live). A fix stamped in the past goes to the estimator at once,
which attaches it to the pose of its time and corrects the history after it.
"""
from __future__ import annotations

import bisect
import dataclasses
import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from pdr.events import FloorEvent, MotionEvent, MotionState, PoseEstimate, StepEvent
from pdr.floors import FloorElevations
from pdr.pipeline import ImuFrame, PipelineSettings
from service.core.motion import DEFAULT_CARRY, MotionModel, motion_model_for
from service.fusion.estimators import (
    DeadReckoningEstimator,
    FixOutcome,
    TrackEstimator,
    joined_tracks,
    make_estimator,
)
from service.fusion.fixes import CheckpointFix  # noqa: F401  (re-exported: the tracker's fix type)

log = logging.getLogger("firetrack.service")

HELD_OUT_KEPT = 64  # fixes held out by the estimator kept for the core's audits (source, t, reason)

__all__ = ["CheckpointFix", "PoseEstimate", "ResponderTracker", "TrackerSettings", "tracker_settings_for"]


@dataclass
class TrackerSettings:
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)
    engine: str = "fusion"  # the track estimator (service.fusion.estimators): "fusion" (gtsam) or "dr"
    fusion: object | None = None  # service.fusion.FusionSettings, None = defaults
    motion: object | None = None  # a motion-model factory that overrides the registry (the evaluation's replay)


def tracker_settings_for(incident, engine: str = "fusion") -> TrackerSettings:
    """Tracker settings for an incident: its declination (and WMM dip, when configured) reach
    the compass; everything else is the default."""
    import math

    from pdr.heading import HeadingSettings

    inc = incident.field_inclination_deg
    heading = HeadingSettings(
        declination=math.radians(incident.declination_deg),
        field_inclination=math.radians(inc) if inc is not None else math.nan,
    )
    return TrackerSettings(pipeline=PipelineSettings(heading=heading), engine=engine)


class ResponderTracker:
    # restarts counted before the current estimator (class defaults: a tracker pickled before
    # these were kept reads as none)
    _degraded_before: int = 0
    _degraded_at_before: float = math.nan

    def __init__(self, responder: str, floors: FloorElevations, start_floor: int = 0,
                 settings: TrackerSettings | None = None, entry: CheckpointFix | None = None,
                 carry: str = DEFAULT_CARRY, fleet=None):
        self.responder = responder
        self.settings = settings or TrackerSettings()
        self._fleet = fleet  # a pdr.fleet.PdrFleet: the handheld pipeline runs in the core's columnar rounds
        self.floors = floors
        self._start_floor = start_floor
        self._carry = carry
        self.model: MotionModel = self._motion_factory(carry)(self.settings, floors, start_floor)
        self._anchored: tuple | None = None  # (floor, t) the latest checkpoint anchored
        self._frames = 0
        self._entry = entry
        self._placed_at: CheckpointFix | None = None
        self._pending_fixes: list[tuple[float, int, object]] = []  # (t, order, fix) waiting for a step
        self._order = 0
        make_estimator(self.settings.engine, self.settings.fusion)  # an unknown engine fails here, not mid-walk
        self.estimator: TrackEstimator | None = None  # once placed and walking
        self.baseline = DeadReckoningEstimator()  # dead reckoning with the same resets, always kept (cheap)
        self.pdr_track: list[tuple[float, float, float, int]] = []  # (t, x, y, floor) of the baseline
        self.live: PoseEstimate | None = None
        self.last_step: StepEvent | None = None
        self.fixes_applied = 0
        self.fixes_rejected = 0  # refused by the estimator's gates ...
        self.fix_rejects: dict[str, int] = {}  # ... by the estimator's reason (gnss_gate, too_old, ...)
        self.fixes_unused = 0  # nothing to apply them to (see _apply_fix)
        self.last_fix: dict | None = None  # the last fix applied: source and device time
        self._first_step_after_placement = True
        self._gap: tuple[float, float] | None = None  # (t_from, sigma_m) of a gap the next step crosses
        self._degraded_before = 0  # graph restarts of the estimators replaced by a new placement
        self._degraded_at_before = math.nan
        self.held_out: deque = deque(maxlen=HELD_OUT_KEPT)  # (source, t, reason) refused: the core audits them
        self.readmitted: deque = deque(maxlen=HELD_OUT_KEPT)  # (source, t) held out, then taken: audited again
        self._past: dict[str, np.ndarray] | None = None  # smoothed track of estimators replaced after an error

    def __setstate__(self, state: dict) -> None:
        """A tracker from a snapshot; one pickled before ``held_out`` or ``readmitted`` was kept
        gets an empty one."""
        self.__dict__.update(state)
        for name in ("held_out", "readmitted"):
            if name not in state:
                setattr(self, name, deque(maxlen=HELD_OUT_KEPT))
        self.__dict__.setdefault("_past", None)

    @property
    def degraded(self) -> int:
        """How often the estimator could not go on and restarted the track from dead reckoning
        (:class:`service.fusion.estimators.FusionEstimator`); 0 for estimators that cannot fail."""
        return self._degraded_before + int(getattr(self.estimator, "degraded", 0))

    @property
    def degraded_at(self) -> float:
        """Device time (s) of the latest restart, NaN if none."""
        t = getattr(self.estimator, "degraded_at", math.nan)
        return t if math.isfinite(t) else self._degraded_at_before

    def _motion_factory(self, carry: str):
        if self.settings.motion is not None:
            return self.settings.motion
        factory = motion_model_for(carry)
        if self._fleet is not None and factory is motion_model_for(DEFAULT_CARRY):
            fleet = self._fleet
            return lambda settings, floors, start_floor: fleet.member(start_floor)  # the same pipeline, in rounds
        return factory

    # ------------------------------------------------------------------ what Status reads
    @property
    def steps(self) -> int:
        return self.model.steps

    @property
    def floor(self) -> int:
        return self.model.floor

    @property
    def motion(self) -> tuple[MotionState, float]:
        """The motion state and the device time it began."""
        m = self.model
        since = m.state_since if math.isfinite(m.state_since) else self.device_time
        return m.state, since

    @property
    def motionless_since(self) -> float:
        """s, device time the motion model last saw motion (NaN for a model that does not say)."""
        return getattr(self.model, "motionless_since", math.nan)

    @property
    def device_time(self) -> float:
        """Device time of the newest sample taken (0 before the first)."""
        t = self.model.last_time
        return t if math.isfinite(t) else 0.0

    # ------------------------------------------------------------------ inputs
    def on_frame(self, frame: ImuFrame, carry: str | None = None) -> list[PoseEstimate | MotionEvent]:
        """Consecutive samples; ``carry`` (the wire frame's) picks the motion model at the first frame."""
        self.choose_model(carry)
        events = self.model.update(frame)
        return self.on_events(events)

    def choose_model(self, carry: str | None) -> MotionModel:
        """The motion model for frames of ``carry`` (chosen at the first frame)."""
        if self._frames == 0 and carry is not None and carry != self._carry and self.settings.motion is None:
            self._carry = carry
            self.release_model()  # the default model made at construction gives way (a fleet slot back)
            self.model = self._motion_factory(carry)(self.settings, self.floors, self._start_floor)
            if self._anchored is not None:
                self.model.anchor_floor(*self._anchored)
        return self.model

    def release_model(self) -> None:
        """Hand back what the motion model holds outside this tracker (a columnar fleet's
        slot), when the responder leaves or the model is replaced; models without any ignore it."""
        release = getattr(self.model, "release", None)
        if release is not None:
            release()

    def on_events(self, events) -> list[PoseEstimate | MotionEvent]:
        """What the motion model made of one frame (``model.update(frame)``, or the core's
        columnar round of many responders) -> poses and motion changes."""
        self._frames += 1
        return self._consume(events)

    def finish(self) -> list[PoseEstimate | MotionEvent]:
        out = self._consume(self.model.finish())
        # fixes after the last step attach to it
        while self._pending_fixes:
            _, _, fix = self._pending_fixes.pop(0)
            p = self._apply_fix(fix)
            if p is not None:
                out.append(p)
        flush = getattr(self.estimator, "flush", None)  # steps batched for the graph's next update go in now
        p = flush() if flush is not None else None
        if p is not None:
            self.live = self._published(p, self.live.steps if self.live else p.steps)
            out.append(self.live)
        return out

    @property
    def fixes_queued(self) -> int:
        """Fixes waiting for a step to pass their time."""
        return len(self._pending_fixes)

    @property
    def max_fix_age_s(self) -> float:
        """How far behind the newest sample a fix may be and still be used (the estimator's window)."""
        if self.settings.engine != "fusion":
            return math.inf
        from service.fusion.settings import FusionSettings

        return (self.settings.fusion or FusionSettings()).lag_s

    @property
    def fix_waiting(self) -> bool:
        """A checkpoint fix waits for the first step past its time. Applying it re-anchors the
        motion model's floor (and may place the track) between two frames, so until then frames
        must come one at a time for the result not to depend on how they were batched. GNSS
        and UWB fixes only touch the estimator, which sees the same sequence of steps and
        fixes however the frames were batched. Placement at an incident's entry point waits the
        same way for the first step (it anchors the floor too)."""
        if self._placed_at is None and self._entry is not None and self._entry.floor is not None:
            return True
        return any(isinstance(f, CheckpointFix) for _, _, f in self._pending_fixes)

    def note_gap(self, t_from: float, t_to: float, sigma_m: float) -> None:
        """No samples between ``t_from`` and ``t_to``: the first step after ``t_from`` gets a
        position sigma of ``sigma_m`` more (the walk the gap may hide), so the next fix
        re-anchors the track (:meth:`service.fusion.estimators.TrackEstimator.add_gap`)."""
        if self._gap is not None:
            t_from, sigma_m = min(t_from, self._gap[0]), math.hypot(sigma_m, self._gap[1])
        self._gap = (t_from, sigma_m)

    def on_fix(self, fix) -> PoseEstimate | None:
        """Apply a fix now if its time is covered by the steps so far, else when a step passes it."""
        last_t = self.last_step.t if self.last_step else -math.inf
        if fix.t <= last_t and (self.estimator is not None or not isinstance(fix, CheckpointFix)):
            return self._apply_fix(fix)
        self._order += 1
        bisect.insort(self._pending_fixes, (fix.t, self._order, fix), key=lambda r: (r[0], r[1]))
        return None

    # ------------------------------------------------------------------ internals
    def _consume(self, events) -> list[PoseEstimate | MotionEvent]:
        out: list[PoseEstimate | MotionEvent] = []
        for ev in events:
            if isinstance(ev, MotionEvent):
                out.append(ev)
                continue
            if isinstance(ev, FloorEvent):
                p = self._floor_changed(ev)
                if p is not None:
                    out.append(p)
                continue
            while self._pending_fixes and self._pending_fixes[0][0] < ev.t:
                _, _, fix = self._pending_fixes.pop(0)
                p = self._apply_fix(fix)
                if p is not None:
                    out.append(p)
            p = self._step(ev)
            if p is not None:
                out.append(p)
        return out

    def _anchor_floor(self, floor: int, t: float | None = None) -> None:
        self._anchored = (floor, t)
        self.model.anchor_floor(floor, t)

    def _place(self, fix: CheckpointFix) -> None:
        self._placed_at = fix
        if fix.floor is not None:
            self._anchor_floor(fix.floor, fix.t)
        floor = fix.floor if fix.floor is not None else self.model.floor
        self.baseline.start(fix.t, fix.x, fix.y, math.nan, math.nan, fix.sigma, floor)
        self.pdr_track.append((fix.t, fix.x, fix.y, floor))
        if self.estimator is not None:  # its restarts stay counted
            self._degraded_before, self._degraded_at_before = self.degraded, self.degraded_at
        self.estimator = None  # a new track: the estimator starts at the first step from here
        self._first_step_after_placement = True

    def _step(self, ev: StepEvent) -> PoseEstimate | None:
        self.last_step = ev
        if self._placed_at is None:
            if self._entry is None:
                return None
            self._place(dataclasses.replace(self._entry, t=ev.t - 1e-6))
        if self._first_step_after_placement:  # the heading before the first placed step is the step's own
            self._first_step_after_placement = False
            ev = dataclasses.replace(ev, heading_change=0.0)
        pt = self.baseline.add_step(ev)
        self.pdr_track.append((pt.t, pt.x, pt.y, pt.floor))
        if self.estimator is None and not math.isfinite(ev.heading):
            return None  # no heading yet (frames lost before it): the estimator starts at the next step that has one
        if self.estimator is None:
            p0 = self._placed_at
            self.estimator = make_estimator(self.settings.engine, self.settings.fusion)
            self.estimator.start(p0.t, p0.x, p0.y, ev.heading, ev.heading_sigma, p0.sigma,
                                 p0.floor if p0.floor is not None else ev.floor)
        if self._gap is not None and ev.t > self._gap[0]:
            add_gap = getattr(self.estimator, "add_gap", None)  # an estimator of one's own may not have it
            if add_gap is not None:
                add_gap(self._gap[1])
            self._gap = None
        p = self._guarded(lambda: self.estimator.add_step(ev), ev.t)
        if p is None:
            return None
        self.live = self._published(p, ev.index)
        return self.live

    def _floor_changed(self, ev: FloorEvent) -> PoseEstimate | None:
        """The motion model moved the responder to another floor without a step (a lift): the
        latest pose again, on the new floor, at the time of the change."""
        if self.live is None or self.estimator is None:
            return None  # not placed, or no step yet: the next step carries the floor
        t = max(self.live.t, ev.t)
        p = self.baseline.set_floor(ev.t, ev.floor)
        self.pdr_track.append((max(p.t, ev.t), p.x, p.y, ev.floor))
        self._guarded(lambda: self.estimator.set_floor(ev.t, ev.floor), ev.t)
        self.live = dataclasses.replace(self.live, t=t, floor=ev.floor)
        return self.live

    def _published(self, p: PoseEstimate, steps: int) -> PoseEstimate:
        """The estimator's pose with the responder's step count (the estimator's restarts at each
        placement). ``source`` is the estimator's own: ``fused`` once it took an absolute fix."""
        return dataclasses.replace(p, steps=steps)

    def _apply_fix(self, fix) -> PoseEstimate | None:
        if isinstance(fix, CheckpointFix) and (self._placed_at is None or self._first_step_after_placement):
            self._place(fix)  # not walked from the last placement yet: this one is where the track starts
            self.fixes_applied += 1
            self.last_fix = {"source": fix.source, "t": float(fix.t)}
            return None
        if isinstance(fix, CheckpointFix):
            if fix.floor is not None:
                self._anchor_floor(fix.floor, fix.t)
            # the floor is the motion model's (anchored above): estimators get x, y only
            fix = dataclasses.replace(fix, floor=None)
        if self.estimator is None:  # before the track has a first step: counted
            if isinstance(fix, CheckpointFix):
                self.baseline.add_fix(fix)
            self.fixes_unused += 1
            return None
        outcome = self._guarded(lambda: self.estimator.add_fix(fix), float(fix.t))
        if outcome is None:
            outcome = FixOutcome("rejected", reason="estimator_error")
        if isinstance(fix, CheckpointFix) and outcome.verdict != "rejected":  # a refused fix moves no track
            self.baseline.add_fix(fix)
        if outcome.verdict == "unused":
            self.fixes_unused += 1
            return None
        if outcome.verdict == "rejected":
            self.fixes_rejected += 1
            reason = outcome.reason or "gated"
            self.fix_rejects[reason] = self.fix_rejects.get(reason, 0) + 1
            self.held_out.append((getattr(fix, "source", type(fix).__name__), float(fix.t), reason))
            return None
        if outcome.earlier is not None:  # a fix held out before, taken now: its refusal withdrawn
            self._withdraw_refusal(outcome.earlier)
        self.fixes_applied += 1
        self.last_fix = {"source": getattr(fix, "source", type(fix).__name__), "t": float(fix.t)}
        self.live = self._published(outcome.pose, self.live.steps if self.live else 0)
        return self.live

    def _withdraw_refusal(self, fix) -> None:
        """``fix`` was held out by the walk gate and counted refused; a later fix showed it right
        and the graph took it (a turn). Counted applied instead, and queued for its audit."""
        self.fixes_rejected = max(self.fixes_rejected - 1, 0)
        left = self.fix_rejects.get("walk_gate", 0) - 1
        if left > 0:
            self.fix_rejects["walk_gate"] = left
        else:
            self.fix_rejects.pop("walk_gate", None)
        self.fixes_applied += 1
        self.readmitted.append((getattr(fix, "source", type(fix).__name__), float(fix.t)))

    def _guarded(self, call, t: float):
        """``call()`` on the estimator. Should it raise (a bug: inputs are checked before they get
        here; CI once met a ValueError in the walk gate that then recurred at every round and cost a
        responder 20 s of track), the estimator is replaced by a new one started at the last
        published pose, the old one's smoothed track kept, the restart counted as a degradation
        (the ``track_degraded`` alarm) and logged: one error costs one step or fix, not the track.
        Returns None then."""
        try:
            return call()
        except Exception as e:
            log.exception("%s: the track estimator failed at device time %.2f s; restarted from the last pose",
                          self.responder, t)
            self._restart_estimator(t, f"{type(e).__name__}: {str(e)[:200]}")
            return None

    def _restart_estimator(self, t: float, why: str) -> None:
        old = self.estimator
        try:
            past = old.smoothed_track()
        except Exception:
            past = None
        if past is not None and len(past["t"]):
            self._past = past if self._past is None else joined_tracks(self._past, past)
        self._degraded_before, self._degraded_at_before = self.degraded + 1, t
        self.estimator = make_estimator(self.settings.engine, self.settings.fusion)
        p = self.live
        if p is None:  # no pose yet: the track starts again at the next step, from the placement
            self.estimator = None
            return
        from service.fusion.settings import FusionSettings

        fs = self.settings.fusion or FusionSettings()
        sigma = math.sqrt(max(float(np.linalg.eigvalsh(np.asarray(p.cov, float))[-1]), 0.0))
        self.estimator.start(p.t, p.x, p.y, p.heading, fs.restart_heading_sigma_rad,
                             max(sigma, fs.checkpoint_sigma_floor_m), p.floor)
        log.warning("%s: track restarted at (%.1f, %.1f) after %s", self.responder, p.x, p.y, why)

    def smoothed_track(self) -> dict[str, np.ndarray] | None:
        now = None if self.estimator is None else self.estimator.smoothed_track()
        if self._past is None or now is None:
            return self._past if now is None else now
        return joined_tracks(self._past, now)
