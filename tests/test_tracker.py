"""ResponderTracker: placement by checkpoints, fixes that have nothing to act on are counted."""
from __future__ import annotations

import numpy as np

from pdr.floors import FloorElevations
from pdr.pipeline import frames_of
from pdr.synthetic import static_imu
from service.core.tracker import (
    CheckpointFix,
    PoseEstimate,
    ResponderTracker,
    TrackerSettings,
)
from service.fusion import GnssFix


def _walk_frames(seconds=20.0, rate=50.0):
    imu = static_imu(seconds=seconds, rate_hz=rate)
    acc = imu.acc.copy()
    acc[:, 2] += 2.5 * np.sin(2 * np.pi * 1.8 * imu.t)  # one bounce per step at 1.8 Hz
    return list(frames_of(imu.t, acc, imu.gyr, imu.mag, per_frame=5))


def _poses(tracker, frames):
    out = []
    for f in frames:
        out += [p for p in tracker.on_frame(f) if isinstance(p, PoseEstimate)]
    return out


def test_a_second_checkpoint_before_the_first_step_is_where_the_track_starts():
    for engine in ("fusion", "dr"):
        tr = ResponderTracker("r", FloorElevations.uniform(3.0, 0, 0), 0, TrackerSettings(engine=engine))
        tr.on_fix(CheckpointFix(0.0, 0.0, 0.0, sigma=0.3))
        tr.on_fix(CheckpointFix(0.3, 10.0, 0.0, sigma=0.3))  # moved on before the first step (0.48 s)
        poses = _poses(tr, _walk_frames())
        assert len(poses) > 10
        first = poses[0]
        assert np.hypot(first.x - 10.0, first.y) < 1.5, (engine, first)
        assert tr.fixes_applied == 2 and tr.fixes_unused == 0


def test_gnss_with_nothing_to_correct_is_counted_not_dropped():
    """With the fusion engine, which takes every GNSS fix it can place: a fix that comes while the
    responder has no track (walking, but not yet placed by a checkpoint) is counted as unused,
    neither applied nor rejected; the same kind of fix once the track exists is applied."""
    tr = ResponderTracker("r", FloorElevations.uniform(3.0, 0, 0), 0, TrackerSettings(engine="fusion"))
    frames = _walk_frames(20.0)
    first, second = frames[:len(frames) // 2], frames[len(frames) // 2:]
    assert _poses(tr, first) == [] and tr.last_step is not None  # steps taken, no track to put them on
    tr.on_fix(GnssFix(t=1.0, x=3.0, y=0.0, accuracy=5.0))  # covered by the steps: decided now
    assert (tr.fixes_unused, tr.fixes_applied, tr.fixes_rejected) == (1, 0, 0)

    tr.on_fix(CheckpointFix(float(second[0].t[0]), 0.0, 0.0, sigma=0.3))  # placed: the track starts here
    poses = _poses(tr, second)
    assert len(poses) > 5 and tr.fixes_applied == 1
    last = poses[-1]
    tr.on_fix(GnssFix(t=last.t, x=last.x + 1.0, y=last.y, accuracy=5.0))
    assert (tr.fixes_unused, tr.fixes_applied, tr.fixes_rejected) == (1, 2, 0)


def test_a_first_step_without_a_heading_waits_for_one_instead_of_failing_every_step():
    """Frames lost before a responder's first placed step can leave it without a heading (NaN):
    the estimator then starts at the next step that has one, it does not raise at each step."""
    from pdr.events import StepEvent

    def step(i, heading):
        return StepEvent(t=1.0 + 0.5 * i, index=i, length=0.7, length_sigma=0.1, heading=heading, heading_sigma=0.1,
                         heading_change=0.0, heading_change_sigma=0.05, dz=0.0, dz_sigma=0.1, floor=0, on_stairs=False,
                         mag_heading=float("nan"), mag_heading_sigma=float("inf"))

    tr = ResponderTracker("ff", FloorElevations({0: 0.0}))
    tr.on_fix(CheckpointFix(0.5, 0.0, 0.0, sigma=0.3))
    assert tr.on_events([step(1, float("nan"))]) == []
    poses = tr.on_events([step(2, 0.0), step(3, 0.0)])
    assert len(poses) == 2 and tr.estimator is not None and poses[-1].x > 0.5


def test_an_estimator_that_raises_costs_one_step_and_one_fix_not_the_track():
    """A bug in the estimator (CI once met a ValueError in the walk gate that then recurred every
    round) must not cost the responder its track: the tracker replaces the estimator with a new
    one at the last published pose, counts a degradation with its time, refuses the fix it was
    taking with the reason ``estimator_error``, and the walk goes on from there."""
    import math

    from pdr.events import StepEvent
    from service.fusion.estimators import FusionEstimator, register_estimator

    class BreaksOnce(FusionEstimator):
        """The fusion that raises at step 6 and at the first fix, as a bug would (an estimator
        of our own through the registry, the extension point a new estimator uses)."""
        broken = {"step": True, "fix": True}

        def add_step(self, ev):
            if ev.index == 6 and BreaksOnce.broken.pop("step", False):
                raise ValueError("math domain error")
            return super().add_step(ev)

        def add_fix(self, fix):
            if BreaksOnce.broken.pop("fix", False):
                raise ValueError("math domain error")
            return super().add_fix(fix)

    register_estimator("breaks-once", BreaksOnce)

    def step(i):
        return StepEvent(t=1.0 + 0.5 * i, index=i, length=0.7, length_sigma=0.1, heading=0.0, heading_sigma=0.1,
                         heading_change=0.0, heading_change_sigma=0.05, dz=0.0, dz_sigma=0.1, floor=0, on_stairs=False,
                         mag_heading=float("nan"), mag_heading_sigma=float("inf"))

    tr = ResponderTracker("ff", FloorElevations({0: 0.0}), 0, TrackerSettings(engine="breaks-once"))
    tr.on_fix(CheckpointFix(0.5, 0.0, 0.0, sigma=0.3))
    poses = tr.on_events([step(i) for i in range(1, 11)])
    assert [p.steps for p in poses] == [1, 2, 3, 4, 5, 7, 8, 9, 10]  # step 6 lost, none after it
    assert tr.degraded == 1 and tr.degraded_at == step(6).t
    assert abs(poses[5].x - poses[4].x - 0.7) < 0.05 and abs(poses[-1].x - poses[4].x - 4 * 0.7) < 0.2
    first = tr.estimator
    tr.on_fix(GnssFix(t=step(10).t, x=poses[-1].x + 1.0, y=0.0, accuracy=5.0))
    assert tr.fix_rejects == {"estimator_error": 1} and tr.degraded == 2 and tr.estimator is not first
    more = tr.on_events([step(i) for i in range(11, 14)])
    assert [p.steps for p in more] == [11, 12, 13] and abs(more[-1].x - poses[-1].x - 3 * 0.7) < 0.2
    smoothed = tr.smoothed_track()  # the replaced estimators' tracks are kept before the new one's
    assert smoothed["t"][0] < step(5).t and smoothed["t"][-1] == step(13).t
    assert np.all(np.diff(smoothed["t"]) > 0)
