"""One responder in the service: raw frames and fixes in, poses and motion changes out.

:class:`ResponderTracker` joins the pure dead reckoning (:class:`pdr.pipeline.PdrPipeline`)
with the track estimate — the gtsam fusion (:class:`service.fusion.TrackFusion`), or dead
reckoning alone (:class:`pdr.dead_reckoning.DeadReckoning`) as the baseline — and applies
fixes at their own time. The live service, replays, ``firetrack reprocess`` and
``firetrack eval ipin`` all drive this class the same way, so they give the same poses.

Placement. A responder has no position until the first checkpoint fix (an operator at the
door, a tag reader, the IPIN initial landmark) or, when the incident configures an entry
point, until the first step. Steps before placement are counted (Status) but make no pose.

Fix timing. A fix stamped later than the newest step waits until a step passes its time,
then attaches there (so an IPIN landmark reached after the last step before it attaches to
that step's pose, as it would live). A fix stamped in the past goes to the fusion at once,
which attaches it to the pose of its time and corrects the history after it.

Floors. Steps carry the barometer's floor; a floor change without a step (a lift) comes as a
:class:`pdr.events.FloorEvent` and republishes the latest pose on the new floor at its time.
A checkpoint's floor re-anchors the barometer as of the checkpoint's own time (a lift ridden
between the checkpoint and the next step is not undone). The dead-reckoning baseline
(``pdr_track``) is reset by checkpoints too, so it is the fair comparison at any fix rate.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pdr.dead_reckoning import DeadReckoning
from pdr.events import FloorEvent, MotionEvent, StepEvent
from pdr.floors import FloorElevations
from pdr.pipeline import ImuFrame, PdrPipeline, PipelineSettings
from service.fusion import TrackFusion
from service.fusion.fixes import CheckpointFix  # noqa: F401  (re-exported: the tracker's fix type)


@dataclass(frozen=True)
class PoseEstimate:
    """What the service publishes after a step (or a fix): the live estimate."""

    t: float
    x: float
    y: float
    heading: float  # rad, ENU yaw
    cov: np.ndarray  # (2, 2) m², ENU
    floor: int
    steps: int
    source: str  # "pdr" (dead reckoning only) or "fused" (a fix has been applied)


@dataclass
class TrackerSettings:
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)
    engine: str = "fusion"  # "fusion" (gtsam) or "dr" (dead reckoning alone)
    fusion: object | None = None  # service.fusion.FusionSettings, None = defaults


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
    def __init__(self, responder: str, floors: FloorElevations, start_floor: int = 0,
                 settings: TrackerSettings | None = None, entry: CheckpointFix | None = None):
        self.responder = responder
        self.settings = s = settings or TrackerSettings()
        self.pipeline = PdrPipeline(s.pipeline, floors, start_floor)
        self.floors = floors
        self._entry = entry
        self._placed_at: CheckpointFix | None = None
        self._pending_fixes: list[tuple[float, int, object]] = []  # (t, order, fix) waiting for a step
        self._order = 0
        if s.engine not in ("fusion", "dr"):
            raise ValueError(f"engine must be 'fusion' or 'dr', got {s.engine!r}")
        self.engine = None  # TrackFusion or DeadReckoning once placed
        self.dr = DeadReckoning()  # the dead-reckoning baseline, always kept (cheap)
        self.pdr_track: list[tuple[float, float, float, int]] = []  # (t, x, y, floor)
        self.live: PoseEstimate | None = None
        self.last_step: StepEvent | None = None
        self.fixes_applied = 0
        self.fixes_rejected = 0  # refused by the fusion's gates
        self.fixes_unused = 0  # nothing to apply them to (see _apply_fix)
        self._first_step_after_placement = True

    # ------------------------------------------------------------------ inputs
    def on_frame(self, frame: ImuFrame) -> list[PoseEstimate | MotionEvent]:
        return self._consume(self.pipeline.update(frame))

    def finish(self) -> list[PoseEstimate | MotionEvent]:
        out = self._consume(self.pipeline.finish())
        # fixes after the last step attach to it
        while self._pending_fixes:
            _, _, fix = self._pending_fixes.pop(0)
            p = self._apply_fix(fix)
            if p is not None:
                out.append(p)
        return out

    @property
    def fix_waiting(self) -> bool:
        """A checkpoint fix waits for the first step past its time. Applying it re-anchors the
        pipeline's floor (and may place the track) between two frames, so until then frames
        must come one at a time for the result not to depend on how they were batched. GNSS
        and UWB fixes only touch the factor graph, which sees the same sequence of steps and
        fixes however the frames were batched. Placement at an incident's entry point waits the
        same way for the first step (it anchors the floor too)."""
        if self._placed_at is None and self._entry is not None and self._entry.floor is not None:
            return True
        return any(isinstance(f, CheckpointFix) for _, _, f in self._pending_fixes)

    def on_fix(self, fix) -> PoseEstimate | None:
        """Apply a fix now if its time is covered by the steps so far, else when a step passes it."""
        last_t = self.last_step.t if self.last_step else -math.inf
        if fix.t <= last_t and (self.engine is not None or not isinstance(fix, CheckpointFix)):
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

    def _place(self, fix: CheckpointFix) -> None:
        self._placed_at = fix
        if fix.floor is not None:
            self.pipeline.anchor_floor(fix.floor, fix.t)
        self.dr.start(fix.t, fix.x, fix.y, fix.floor if fix.floor is not None else self.pipeline.floor, fix.sigma)
        self.pdr_track.append((fix.t, fix.x, fix.y, self.dr.point.floor))
        self._first_step_after_placement = True

    def _step(self, ev: StepEvent) -> PoseEstimate | None:
        self.last_step = ev
        if self._placed_at is None:
            if self._entry is None:
                return None
            self._place(dataclasses.replace(self._entry, t=ev.t - 1e-6))
        first = self._first_step_after_placement
        self._first_step_after_placement = False
        if first:  # the heading before the first placed step is the step's own
            ev = dataclasses.replace(ev, heading_change=0.0)
        pt = self.dr.add_step(ev)
        self.pdr_track.append((pt.t, pt.x, pt.y, pt.floor))
        if self.settings.engine == "dr":
            self.live = PoseEstimate(pt.t, pt.x, pt.y, pt.heading, pt.cov, pt.floor, ev.index,
                                     "fused" if self.fixes_applied > 1 else "pdr")
            return self.live
        if self.engine is None:
            p0 = self._placed_at
            self.engine = TrackFusion(self.settings.fusion)
            self.engine.start(p0.t, p0.x, p0.y, ev.heading, ev.heading_sigma, p0.sigma,
                              p0.floor if p0.floor is not None else ev.floor)
        fp = self.engine.add_step(ev)
        self.live = self._from_fused(fp, ev.index)
        return self.live

    def _floor_changed(self, ev: FloorEvent) -> PoseEstimate | None:
        """The barometer moved the responder to another floor without a step (a lift): the
        latest pose again, on the new floor, at the time of the change."""
        if self.live is None or self.dr.point is None:
            return None  # not placed, or no step yet: the next step carries the floor
        p = self.dr.point
        self.dr.point = dataclasses.replace(p, t=max(p.t, ev.t), floor=ev.floor)
        self.pdr_track.append((max(p.t, ev.t), p.x, p.y, ev.floor))
        if self.settings.engine == "fusion" and self.engine is not None:
            self.engine.set_floor(ev.t, ev.floor)
        self.live = dataclasses.replace(self.live, t=max(self.live.t, ev.t), floor=ev.floor)
        return self.live

    def _from_fused(self, fp, steps: int) -> PoseEstimate:
        return PoseEstimate(fp.t, fp.x, fp.y, fp.heading, np.asarray(fp.cov), fp.floor, steps,
                            "fused" if self.fixes_applied > 1 else "pdr")

    def _apply_fix(self, fix) -> PoseEstimate | None:
        if isinstance(fix, CheckpointFix) and (self._placed_at is None or self._first_step_after_placement):
            self._place(fix)  # not walked from the last placement yet: this one is where the track starts
            self.fixes_applied += 1
            return None
        if isinstance(fix, CheckpointFix) and fix.floor is not None:
            self.pipeline.anchor_floor(fix.floor, fix.t)
        if self.settings.engine == "dr" or self.engine is None:
            if isinstance(fix, CheckpointFix) and self.dr.point is not None:
                self.dr.move_to(fix.x, fix.y, fix.sigma)
                self.fixes_applied += 1
            else:  # GNSS/UWB with dead reckoning alone, or before the track has a first step: counted
                self.fixes_unused += 1
            return None
        if isinstance(fix, CheckpointFix) and self.dr.point is not None:
            self.dr.move_to(fix.x, fix.y, fix.sigma)  # the baseline is reset by checkpoints as well
        fp = self.engine.add_fix(self._fusion_fix(fix))
        if fp is None:
            self.fixes_rejected += 1
            return None
        self.fixes_applied += 1
        self.live = self._from_fused(fp, self.live.steps if self.live else 0)
        return self.live

    def _fusion_fix(self, fix):
        if isinstance(fix, CheckpointFix):
            # the floor is the pipeline's business (anchor_floor above): the graph gets x, y only,
            # or the floor would be corrected twice
            return dataclasses.replace(fix, floor=None)
        return fix  # GnssFix / UwbRange of service.fusion already

    def smoothed_track(self) -> dict[str, np.ndarray] | None:
        if self.engine is None or self.settings.engine == "dr":
            return None
        return self.engine.smoothed_track()
