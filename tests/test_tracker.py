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
    tr = ResponderTracker("r", FloorElevations.uniform(3.0, 0, 0), 0, TrackerSettings(engine="dr"))
    tr.on_fix(CheckpointFix(0.0, 0.0, 0.0))
    _poses(tr, _walk_frames(10.0))
    tr.on_fix(GnssFix(t=1.0, x=3.0, y=0.0, accuracy=5.0))
    assert tr.fixes_unused == 1
