"""The fusion's absolute heading where the PDR's own heading chain breaks (issue 27, robustness
suite: ``gaps`` and ``mag_steel``). Synthetic walks whose truth is known; real gtsam.

* A turn inside a gap in the samples: the step across the gap has an unknown turn (σ = ∞) and
  still carries the PDR's heading from before the gap; the compass and the PDR's heading after it
  are right. Neither the compass gate's window nor the PDR heading's offset may carry the old
  heading across the break.
* A PDR heading that the PDR itself does not know (σ = 180°: no compass epoch has passed its gates
  yet) is no absolute evidence: a first leg 140° off must not hold the graph's heading once the
  PDR's heading becomes absolute.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from service.fusion import FusionSettings, TrackFusion
from tests.test_fusion import DEG, track_err, walk


def _run(events, start_heading: float, start_sigma: float, settings: FusionSettings | None = None):
    f = TrackFusion(settings or FusionSettings())
    f.start(0.0, 0.0, 0.0, start_heading, heading_sigma=start_sigma)
    live = [f.add_step(ev) for ev in events]
    return f, np.array([[p.x, p.y] for p in live])


def test_a_turn_inside_a_gap_is_taken_from_the_absolute_heading_at_once():
    """East for 40 steps, a 90° left turn inside a gap, north for 60. The step across the gap has
    an unknown turn and the PDR's stale heading (east); after it the PDR's heading and the compass
    say north. The live track must turn with them, not keep walking east for seconds."""
    rng = np.random.default_rng(7)
    h = np.r_[np.zeros(40), np.full(60, math.pi / 2)]
    mag = h + rng.normal(0.0, 4 * DEG, h.size)
    events, truth = walk(h, mag=mag)
    gap = 40
    events[gap] = dataclasses.replace(events[gap], heading=0.0, heading_change=math.nan,
                                      heading_change_sigma=math.inf, t=events[gap].t + 1.4)
    for k in range(gap + 1, len(events)):
        events[k] = dataclasses.replace(events[k], t=events[k].t + 1.4)
    _, live = _run(events, 0.0, 5 * DEG)
    after = np.arange(gap + 1, len(h) + 1)
    errors = np.hypot(live[after - 1, 0] - truth[after, 0], live[after - 1, 1] - truth[after, 1])
    # the turn is 0.8 m of walk away from the gap step's pose: a track that keeps east for a few
    # steps ends metres off; one that turns at once stays within about a step of the truth
    assert errors.max() < 2.0, f"live track {errors.max():.1f} m off after a turn inside a gap"


def test_a_pdr_heading_it_does_not_know_is_no_absolute_evidence():
    """The first 14 steps: the PDR's heading is 140° off with σ = 180° (no compass epoch yet), no
    compass. Then its heading is right (σ 20°) and the compass comes in. The graph started from the
    wrong heading with σ = 180° must take the right one for the rest of the walk, and turn the
    first leg back (its length is the gyro's; only its direction was unknown)."""
    rng = np.random.default_rng(5)
    h = np.r_[np.full(14, math.pi), np.full(40, math.pi / 2), np.zeros(40)]
    mag = h + rng.normal(0.0, 4 * DEG, h.size)
    mag[:14] = np.nan
    events, truth = walk(h, mag=mag)
    wrong = math.remainder(math.pi + 140 * DEG, 2 * math.pi)
    events = [dataclasses.replace(ev, heading=wrong, heading_sigma=math.pi) if k < 14
              else dataclasses.replace(ev, heading_sigma=20 * DEG) for k, ev in enumerate(events)]
    f, live = _run(events, wrong, math.pi)
    rows = np.arange(len(h) + 1)
    # the smoothed track: the first leg is turned back once the heading is known
    assert track_err(f.smoothed_track(), truth, rows).max() < 2.0
    # live: once the heading is known the graph turns the first leg back, and the live pose follows
    assert math.hypot(*(live[-1] - truth[-1])) < 2.0, f"live track ends {math.hypot(*(live[-1] - truth[-1])):.1f} m off"
