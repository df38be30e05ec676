"""The PDR heading gets back what it lost (issue 27's robustness suite): a tilt error no walker
could cause is levelled at once, a gap in the samples lets the compass decide again, and a
compass gate that shut on a wrong start reopens on the evidence of 20 s."""
from __future__ import annotations

import math

import numpy as np

from pdr import quaternion as quat
from pdr.ahrs import make_filter
from pdr.heading import HeadingEstimator, HeadingSettings, wrap
from pdr.synthetic import FIELD_ENU, GRAVITY
from tests.test_heading import _rotated_field, deg, walk


def _tilt_deg(q: np.ndarray, acc_body: np.ndarray) -> float:
    up = quat.rotate(q, acc_body)
    return float(np.degrees(np.arccos(np.clip(up[2] / np.linalg.norm(up), -1.0, 1.0))))


def test_a_lost_attitude_is_levelled_at_once_beyond_the_relevel_angle():
    # started 80° off level (as after a fast wave with a gyro scale 2 % off), then held still
    rate = 50.0
    t = np.arange(0.0, 6.0, 1 / rate)
    acc = np.tile([0.0, 0.0, GRAVITY], (t.size, 1))
    q0 = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(80.0))
    tilts = {}
    for relevel in (math.radians(30.0), math.inf):
        f = make_filter("decoupled", {"rest_time": math.inf, "acc_relevel_angle": relevel}, q0=q0)
        q = f.update(t, acc, np.zeros((t.size, 3)))
        tilts[relevel] = _tilt_deg(q[int(3.0 * rate)], acc[0])
    assert tilts[math.radians(30.0)] < 2.0
    # slewed at acc_rate_max (0.03 rad/s) the same error would still be tens of degrees
    assert tilts[math.inf] > 40.0


def test_the_walkers_turn_inside_a_gap_is_taken_from_the_compass_at_once():
    # a straight walk north, a 90° left turn made in 0.5 s inside a 1.5 s gap, then west
    turn = lambda t: np.where((t >= 30.0) & (t < 30.5), (np.pi / 2) / 0.5, 0.0)  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(turn, 60.0)
    keep = (t < 29.5) | (t >= 31.0)
    after = (steps > 31.5) & (steps < 34.0)
    errs = {}
    for rate in (1.0, 0.0):
        r = HeadingEstimator(HeadingSettings(gap_turn_rate=rate)).update(t[keep], acc[keep], gyr[keep], mag[keep], steps)
        errs[rate] = np.abs(deg(wrap(r.heading - np.interp(r.t, t, truth))))[after]
        # the step across the gap reports its turn as unknown (the fusion takes it from the heading)
        assert np.isinf(r.heading_change_sigma[1:]).sum() == 1 and np.isinf(r.heading_change_sigma[r.t == 31.0]).all()
    assert errs[1.0].max() < 10.0
    # weighted as usual, the compass brings the unseen turn back only over about ten seconds
    assert errs[0.0].min() > 30.0


def test_a_compass_gate_shut_by_a_wrong_start_reopens_on_consistent_evidence():
    # the walk starts next to steel: the field is turned 150° for its first 6 s (straight ahead,
    # longer than start_confirm_s: the start takes it), then clean; no turn proves the clean run
    bad = _rotated_field(150.0)
    field = lambda t: np.where((t < 6.0)[:, None], bad, FIELD_ENU)  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 60.0, field=field)
    r = HeadingEstimator().update(t, acc, gyr, mag, steps)
    err = np.abs(deg(wrap(r.heading - truth[0])))
    assert err[(r.t > 7.0) & (r.t < 18.0)].min() > 90.0  # the start's error is beyond the gate
    assert err[r.t > 30.0].max() < 5.0  # 20 s of a consistent, rejected compass restart δ


def _travel_error_deg(q: np.ndarray) -> float:
    """Heading of travel from the device's heading vector (``level_and_compass``) for a walker
    going north (ENU yaw 90°), with the phone's y axis pointing north before it was turned."""
    from pdr.heading_kernels import level_and_compass

    raw = level_and_compass(np.ascontiguousarray(q[None, :]), HeadingEstimator()._fwd, np.zeros((1, 3)),
                            np.empty((0, 3)), False, 0.0)[0][0]
    return float(deg(wrap(raw - math.pi / 2)))


def test_a_phone_tipped_past_vertical_keeps_the_heading_of_travel():
    # issue 27's grip_x on a phone held at 55°: turned about x up to 145°, screen facing the floor
    # behind; the heading of travel must not flip when the long axis goes over the vertical
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    for pitch in (0.0, 55.0, 90.0, 100.0, 108.0, 115.0, 130.0, 145.0, 160.0):
        for sway in (-5.0, 0.0, 5.0):  # the hand's roll about the long axis
            q = quat.multiply(quat.from_axis_angle(x, math.radians(pitch)), quat.from_axis_angle(y, math.radians(sway)))
            assert abs(_travel_error_deg(q)) < 6.0, (pitch, sway)
    # a phone rolled on its side (landscape, issue 27's grip_y) keeps its long axis as forward
    for roll in (60.0, 90.0, 120.0, 135.0):
        q = quat.multiply(quat.from_axis_angle(x, math.radians(55.0)), quat.from_axis_angle(y, math.radians(roll)))
        assert abs(_travel_error_deg(q)) < 1.0, roll
