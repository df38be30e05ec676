"""A gap in the samples hides the steps walked in it (robustness suite ``gaps``): the first step
after it stands for the steps of the interval (:meth:`pdr.step_events.StepAssembler._bridge`)."""
from __future__ import annotations

import math

import numpy as np

from pdr.events import StepDetection
from pdr.heading import StepHeadings
from pdr.pipeline_settings import PipelineSettings
from pdr.step_events import StepAssembler


def _walk(times, unknown_change_at=()):
    """Step events of steps at ``times`` (0.5 s apart: 0.25 + 0.22·2 = 0.69 m each), their heading
    change unknown at the indices ``unknown_change_at`` (a step across a gap in the samples)."""
    a = StepAssembler(PipelineSettings())
    t = np.asarray(times, float)
    found = [StepDetection(t=float(x), t_start=float(x) - 0.5, a_max=2.0, a_min=-2.0, a_mean=0.0, a_mean_abs=1.0)
             for x in t]
    n = t.size
    change_sigma = np.full(n, 0.05)
    change_sigma[list(unknown_change_at)] = math.inf
    hd = StepHeadings(t, np.zeros(n), np.full(n, 0.1), np.zeros(n), change_sigma, np.full(n, np.nan),
                      np.full(n, np.inf), np.zeros(n), np.zeros(n))
    a.detected(found)
    return a.assemble(hd, np.empty((0, 2)), lambda _t: 0)


def test_the_step_after_a_gap_in_the_samples_stands_for_the_steps_walked_in_it():
    before = [10.0 + 0.5 * k for k in range(10)]  # walking at 2 Hz up to 14.5 s
    after = [16.5 + 0.5 * k for k in range(6)]  # a 1.5 s gap: the steps at 15.0, 15.5 and 16.0 were not seen
    ev = _walk(before + after, unknown_change_at=[10])
    one = ev[9].length
    assert ev[10].length == np.float64(4 * one)  # 2.0 s since the previous step: four periods
    assert ev[10].length_sigma == np.float64(2 * ev[9].length_sigma)
    assert all(e.length == one for e in ev[11:])
    walked = sum(e.length for e in ev[1:])  # 10.0 to 19.0 s at 2 Hz: 18 steps walked
    assert abs(walked - 18 * one) < 1e-9  # without the rule 15: the gap's three steps lost


def test_a_pause_with_samples_and_a_gap_before_the_cadence_is_known_are_not_bridged():
    before = [10.0 + 0.5 * k for k in range(10)]
    after = [16.5 + 0.5 * k for k in range(4)]
    paused = _walk(before + after)  # the walker stood 2 s: the samples saw it, the heading change is known
    assert len({round(e.length, 12) for e in paused}) == 1
    early = _walk([10.0, 10.5, 11.0, 13.0, 13.5], unknown_change_at=[3])  # 2 intervals: no cadence yet
    assert len({round(e.length, 12) for e in early}) == 1
    long_gap = _walk(before + [19.0, 19.5], unknown_change_at=[10])  # 4.5 s: beyond bridge_max_s
    assert long_gap[10].length == long_gap[9].length
