"""The compass weighed by its field's strength (issue 27: route 03's bent corridors, ``mag_steel``).

Synthetic walks whose truth is known: a field bent where its strength is off is weighed down
from the first ``reference_min_s`` of the walk on, and the steps taken before any compass epoch
passed the gates take the offset of the least disturbed epochs, not the raw compass of their own.
"""
from __future__ import annotations

import math

import numpy as np

from pdr.heading import HeadingEstimator, HeadingSettings, wrap
from tests.test_heading import FIELD_ENU, _rotated_field, deg, walk

DIP = math.atan2(-FIELD_ENU[2], math.hypot(*FIELD_ENU[:2]))  # rad, the clean field's dip (as if from the WMM)


def _field(stretches):
    """ENU field per time: FIELD_ENU except inside each ``(start, end, field)`` stretch."""
    def field(t):
        B = np.tile(FIELD_ENU, (len(t), 1)).astype(float)
        for a, b, f in stretches:
            B[(t >= a) & (t < b)] = f
        return B
    return field


def test_a_bent_weak_field_is_weighed_down_before_the_reference_window_ends():
    # 0-20 s clean; 20-35 s a corridor whose field is turned 50° and 25 % weaker, dip unchanged
    # (route 03's corridors: 24-28 µT against 31-35 µT at the start): it agrees with itself, so
    # only its strength can tell. The reference window (60 s) is not over when the corridor begins.
    # The weight slows the pull (a corridor long enough bends the heading all the same).
    bent = 0.75 * _rotated_field(50.0)
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 36.0, field=_field([(20.0, 35.0, bent)]))
    inside = steps > 20.0

    def worst(settings):
        r = HeadingEstimator(settings).update(t, acc, gyr, mag, steps)
        return np.abs(deg(wrap(r.heading - truth[0])))[inside].max()

    now = worst(HeadingSettings())
    before = worst(HeadingSettings(norm_weight=math.radians(1.0), reference_min_s=60.0))  # c065ffd's weighing
    assert now < 0.8 * before, (now, before)  # 31° against 42°


def test_steps_before_any_epoch_passes_take_the_least_disturbed_offset():
    # The dip is known (WMM). 0-20 s the walker stands where the dip is 20° off (the gate rejects,
    # though the field points the right way); 20-30 s a steel door adds a field that turns it
    # by 120° and makes it 25 µT stronger (rejected by the dip gate too); then a clean field.
    # The steps of 21-29 s used to take their own raw compass: 120° off.
    wrong_dip = _rotated_field(0.0, 20.0)
    steel = 1.5 * _rotated_field(120.0, 20.0)
    field = _field([(0.0, 20.0, wrong_dip), (20.0, 30.0, steel)])
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 40.0, field=field)
    r = HeadingEstimator(HeadingSettings(field_inclination=DIP)).update(t, acc, gyr, mag, steps)
    in_steel = (r.t > 21.0) & (r.t < 29.0)
    assert np.all(np.isnan(r.mag_heading[in_steel]))  # the compass of those steps is rejected ...
    err = np.abs(deg(wrap(r.heading - truth[0])))
    assert err[in_steel].max() < 20.0, err[in_steel]  # ... and their heading is not the steel's
    assert np.all(r.heading_sigma[in_steel] < math.pi)  # with a finite sigma (the provisional one)
    assert err[r.t > 32.0].max() < 5.0
