"""Heading estimator on synthetic walks whose truth is known."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.heading import HeadingEstimator, HeadingSettings, StepHeadings, wrap
from pdr.synthetic import FIELD_ENU, GRAVITY
from pdr.walking_direction import WalkingDirection

RATE = 100.0
TILT = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(35.0))  # texting: top raised 35°


def walk(yaw_rate, seconds, bias=(0.0, 0.0, 0.0), field=None, seed=0, yaw0=0.0, bounce=True):
    """A phone held in front (y forward, tilted 35°) by a walker turning at ``yaw_rate(t)`` rad/s.

    Returns t, acc, gyr, mag, the true heading of travel (ENU yaw of the device's y axis) and
    step times at 2 Hz. ``field(t)`` (N, 3) µT in ENU replaces the clean field when given.
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = np.arange(n) / RATE
    w = yaw_rate(t)
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) / RATE)])
    q = quat.multiply(quat.from_yaw(yaw), TILT)
    f = np.tile([0.0, 0.0, GRAVITY], (n, 1))
    walking = bounce(t) if callable(bounce) else np.full(n, bool(bounce))
    f[:, 2] += np.where(walking, 1.5 * np.sin(2 * np.pi * 2.0 * t), 0.0)
    acc = quat.rotate_inverse(q, f) + rng.normal(0, 0.05, (n, 3))
    gyr = quat.rotate_inverse(q, np.c_[np.zeros(n), np.zeros(n), w]) + np.asarray(bias) + rng.normal(0, 0.003, (n, 3))
    B = np.tile(FIELD_ENU, (n, 1)) if field is None else field(t)
    mag = quat.rotate_inverse(q, B) + rng.normal(0, 0.3, (n, 3))
    heading = wrap(yaw + np.pi / 2)
    steps = np.arange(0.5, seconds, 0.5)
    return t, acc, gyr, mag, heading, steps


def square_rate(t, side=10.0, turn=1.0):
    """Walk ``side`` seconds, turn +90° in ``turn`` seconds, repeat."""
    phase = np.mod(t, side + turn)
    return np.where(phase >= side, (np.pi / 2) / turn, 0.0)


def deg(a):
    return np.degrees(np.asarray(a))


def test_square_walk_recovers_90_degree_turns_and_absolute_heading():
    t, acc, gyr, mag, truth, steps = walk(square_rate, 4 * 11.0 + 4.0)
    est = HeadingEstimator()
    r = est.update(t, acc, gyr, mag, steps)
    assert len(r) == len(steps)
    # the summed per-step heading changes over each turn are +90°
    side_end = np.array([10.0, 21.0, 32.0])
    for a in side_end:
        sel = (r.t > a - 1.0) & (r.t <= a + 2.0)
        assert deg(r.heading_change[sel].sum()) == pytest.approx(90.0, abs=2.0)
    # absolute heading: the true heading of travel averaged over each step
    true_step = np.array([np.angle(np.exp(1j * truth[(t > tk - 0.5) & (t <= tk)]).mean()) for tk in r.t])
    err = deg(wrap(r.heading - true_step))
    assert np.percentile(np.abs(err[4:]), 95) < 3.0
    assert np.all(np.isfinite(r.mag_heading[4:]))
    assert np.abs(deg(wrap(r.mag_heading[4:] - true_step[4:]))).max() < 5.0
    assert np.all(r.heading_sigma > 0) and np.all(r.heading_change_sigma[1:] > 0)


def test_gyro_bias_is_removed_after_a_still_period():
    bias = (0.004, -0.003, 0.01)  # rad/s
    rate = lambda t: np.where(t < 20.0, 0.0, square_rate(t - 20.0))  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(rate, 80.0, bias=bias, bounce=lambda t: t >= 20.0)  # still, then walks
    steps = steps[steps > 20.0]
    for estimate, tol in ((True, 2.0), (False, None)):
        est = HeadingEstimator(HeadingSettings(estimate_bias=estimate, use_mag=False))
        r = est.update(t, acc, gyr, None, steps)
        drift = deg(wrap(r.heading[-1] - r.heading[0])) - deg(wrap(truth[t <= r.t[-1]][-1] - truth[t <= r.t[0]][-1]))
        drift = (drift + 180) % 360 - 180
        if estimate:
            assert abs(drift) < tol
            assert np.allclose(est.bias, bias, atol=2e-3)
        else:
            assert abs(drift) > 20.0  # 0.01 rad/s about the vertical for ~60 s


def test_disturbed_field_is_down_weighted():
    rng = np.random.default_rng(3)
    # 30-50 s: a steel structure adds a field that changes quickly as the walker passes
    def field(t):
        B = np.tile(FIELD_ENU, (len(t), 1)).astype(float)
        inside = (t > 30.0) & (t < 50.0)
        k = np.flatnonzero(inside)
        B[k, 0] += 25.0 * np.sin(2 * np.pi * 0.7 * t[k]) + rng.normal(0, 1.0, len(k))
        B[k, 1] += 15.0 * np.cos(2 * np.pi * 0.4 * t[k])
        return B

    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 70.0, field=field)
    clean = HeadingEstimator().update(t, acc, gyr, mag, steps)
    in_dist = (clean.t > 31.0) & (clean.t < 50.0)
    assert np.mean(np.isinf(clean.mag_heading_sigma[in_dist])) > 0.8
    assert np.mean(np.isnan(clean.mag_heading[in_dist])) > 0.8
    assert np.all(np.isfinite(clean.mag_heading_sigma[(clean.t > 5) & (clean.t < 29)]))
    err = deg(wrap(clean.heading - truth[0]))
    assert np.abs(err[clean.t > 5]).max() < 3.0
    # without the gates, the same filter would follow the disturbance
    open_gate = HeadingEstimator(HeadingSettings(spread_gate=math.inf, sigma_mag=math.radians(5.0)))
    r = open_gate.update(t, acc, gyr, mag, steps)
    assert np.abs(deg(wrap(r.heading - truth[0]))[in_dist]).max() > 2 * np.abs(err[in_dist]).max()


def test_declination_turns_magnetic_into_true_heading():
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 20.0)
    d = math.radians(3.6)  # magnetic north lies 3.6° east of true north: true yaw = magnetic yaw − D
    r0 = HeadingEstimator().update(t, acc, gyr, mag, steps)
    r1 = HeadingEstimator(HeadingSettings(declination=d)).update(t, acc, gyr, mag, steps)
    assert deg(wrap(r1.heading[-1] - r0.heading[-1])) == pytest.approx(-3.6, abs=0.05)


@pytest.mark.bitexact
def test_batches_equal_one_batch():
    t, acc, gyr, mag, truth, steps = walk(square_rate, 30.0, bias=(0, 0, 0.002))
    one = HeadingEstimator().update(t, acc, gyr, mag, steps)
    est = HeadingEstimator()
    rng = np.random.default_rng(1)
    parts, i = [], 0
    while i < len(t):
        j = min(len(t), i + int(rng.integers(1, 120)))
        s = steps[(steps > (t[i - 1] if i else -1)) & (steps <= t[j - 1] + 0.3)]  # some arrive early
        steps = steps[~np.isin(steps, s)]
        parts.append(est.update(t[i:j], acc[i:j], gyr[i:j], mag[i:j], s))
        i = j
    many = StepHeadings.concatenate(parts)
    assert len(many) == len(one)
    for name in ("t", "heading", "heading_sigma", "heading_change", "heading_change_sigma", "mag_heading", "mag_heading_sigma"):
        np.testing.assert_allclose(getattr(many, name), getattr(one, name), atol=1e-9, equal_nan=True, err_msg=name)


def test_walking_direction_detects_a_reversed_phone():
    # fore-aft acceleration leads the vertical bounce by a quarter step in the walking direction
    n = int(20 * RATE)
    t = np.arange(n) / RATE
    az = 1.5 * np.sin(2 * np.pi * 2.0 * t)
    afwd = 1.0 * np.sin(2 * np.pi * 2.0 * t + np.pi / 2)
    walk_yaw = 0.3
    a = np.c_[afwd * np.cos(walk_yaw), afwd * np.sin(walk_yaw), GRAVITY + az]
    steps = np.arange(5.0, 20.0, 0.5)
    for dev_yaw, expected in ((walk_yaw, 0.0), (walk_yaw + np.pi, np.pi)):
        _, off = WalkingDirection().update(t, a, np.full(n, dev_yaw), steps)
        assert np.allclose(off, expected)


def _rotated_field(angle_deg, dip_extra_deg=0.0):
    """FIELD_ENU turned ``angle_deg`` about the vertical and dipped ``dip_extra_deg`` more."""
    a, e = math.radians(angle_deg), math.radians(dip_extra_deg)
    h, z = math.hypot(*FIELD_ENU[:2]), FIELD_ENU[2]
    norm, dip = math.hypot(h, z), math.atan2(-z, h) + e
    az = math.atan2(FIELD_ENU[1], FIELD_ENU[0]) + a
    return np.array([norm * math.cos(dip) * math.cos(az), norm * math.cos(dip) * math.sin(az), -norm * math.sin(dip)])


def test_waved_phone_does_not_set_the_heading():
    # 0-10 s: the phone is waved (yaw ±3 rad/s) where the field points 60° off; then a calm walk
    # in the clean field. Epochs of fast rotation are not compass measurements.
    wave = lambda t: np.where(t < 10.0, 3.0 * np.sin(2 * np.pi * 1.0 * t), 0.0)  # noqa: E731
    bad = _rotated_field(60.0)
    field = lambda t: np.where((t < 10.0)[:, None], bad, FIELD_ENU)  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(wave, 25.0, field=field)
    after = (steps > 11.0) & (steps < 14.0)
    gated = HeadingEstimator().update(t, acc, gyr, mag, steps)
    err = np.abs(deg(wrap(gated.heading - np.interp(gated.t, t, truth))))
    assert err[after].max() < 5.0
    open_gate = HeadingEstimator(HeadingSettings(max_rate=math.inf))
    r = open_gate.update(t, acc, gyr, mag, steps)
    err_open = np.abs(deg(wrap(r.heading - np.interp(r.t, t, truth))))
    assert err_open[after].min() > 15.0  # the waved epochs would have set a wrong start


def test_inclination_gate_needs_a_configured_reference():
    # 20-40 s: a field turned 40° and dipping 25° less (steel nearby); the dip is known (WMM)
    bad = _rotated_field(40.0, -25.0)
    field = lambda t: np.where(((t > 20.0) & (t < 40.0))[:, None], bad, FIELD_ENU)  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 50.0, field=field)
    dip = math.atan2(-FIELD_ENU[2], math.hypot(*FIELD_ENU[:2]))
    inside = (steps > 21.0) & (steps < 40.0)
    known = HeadingEstimator(HeadingSettings(field_inclination=dip)).update(t, acc, gyr, mag, steps)
    assert np.all(np.isinf(known.mag_heading_sigma[inside]))
    assert np.abs(deg(wrap(known.heading - truth[0]))[steps > 5.0]).max() < 3.0
    # a reference learned where the walk began is not trusted to gate: the epochs only weigh less
    learned = HeadingEstimator(HeadingSettings(reference_seconds=10.0)).update(t, acc, gyr, mag, steps)
    assert np.all(np.isfinite(learned.mag_heading_sigma[inside]))
    assert np.abs(deg(wrap(learned.heading - truth[0]))[inside]).max() > 5.0


def test_wrap_of_a_float_is_the_bits_of_the_array_path():
    """``wrap`` takes Python's ``%`` for a float and ``np.mod`` for an array: the same bits
    (streaming code wraps per step, batch code per array), around ±π, at zeros and far out."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(0.0, 10.0, 20_000), rng.uniform(-1e6, 1e6, 5_000),
                        [0.0, -0.0, math.pi, -math.pi, 2 * math.pi, -3 * math.pi, np.nextafter(math.pi, 4.0),
                         np.nextafter(-math.pi, -4.0), 1e300, -1e-300, 5e-324]])
    by_array = wrap(x)
    by_float = np.array([wrap(float(v)) for v in x])
    assert by_array.view(np.int64).tolist() == by_float.view(np.int64).tolist()
    assert type(wrap(np.float64(1.0))) is float and math.isnan(wrap(math.nan))
