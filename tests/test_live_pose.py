"""The live pose after a checkpoint (issue 27, part 5): it starts from the fix, and the heading
error the fix reveals is corrected in the live track at once, between graph updates too.

Through :class:`service.fusion.estimators.FusionEstimator` (updates batched per second, dead
reckoning from the graph's newest pose in between), real gtsam.
"""
from __future__ import annotations

import math

from pdr.angles import wrap
from service.fusion.estimators import FusionEstimator
from service.fusion.fixes import CheckpointFix
from tests.test_fusion import DEG, no_mag, square, walk


def test_after_a_checkpoint_the_live_pose_starts_from_it_and_walks_the_corrected_heading():
    """A square walked with the start heading 8° off; a checkpoint at the second corner."""
    events, truth = walk(square())
    est = FusionEstimator(no_mag())
    est.start(0.0, 0.0, 0.0, 8 * DEG, 15 * DEG, 0.3, 0)
    for ev in events[:50]:
        before = est.add_step(ev)
    assert math.hypot(before.x - truth[50, 0], before.y - truth[50, 1]) > 3.0  # the error is real
    outcome = est.add_fix(CheckpointFix(t=events[49].t, x=truth[50, 0], y=truth[50, 1], sigma=0.3))
    assert outcome.verdict == "applied"
    assert math.hypot(outcome.pose.x - truth[50, 0], outcome.pose.y - truth[50, 1]) < 0.3
    worst = 0.0
    for k, ev in enumerate(events[50:75], start=51):  # the third side, live: propagated and updated
        p = est.add_step(ev)
        worst = max(worst, math.hypot(p.x - truth[k, 0], p.y - truth[k, 1]))
    assert worst < 0.6  # the heading left as it was would put the side's end ≈2.8 m off (8° over 20 m)
    assert abs(wrap(p.heading - math.pi)) < 3 * DEG
