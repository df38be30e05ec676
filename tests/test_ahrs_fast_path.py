"""The decoupled filter's fast accelerometer path and its trust weight (pdr/ahrs/decoupled.py, step 2).

Synthetic motion with known truth:

* a gyroscope whose axes are turned 3.5° against the accelerometer's (Justa's IMU is off by
  about that much): the gravity held in the almost-inertial frame drifts by up to ε·|ω|,
  faster than the low-pass and the rate limit follow; the fast path removes it;
* walking-like accelerations (±3 m/s² at the step frequency): the trust weight keeps the
  fast path out, and the same path without the weight is the control that fails;
* a sustained one-sided acceleration, the case the fast path costs (docs/ahrs.md):
  a regression guard on the measured figure, with the rate-limited filter as the reference.
"""
import dataclasses
import math

import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.ahrs import make_filter
from pdr.evaluation.orientation import earth_error_angles
from pdr.synthetic import rotating_imu

NO_FAST = {"acc_rate_fast": 0.0}
UNGATED = {"acc_trust_sigma": math.inf, "acc_trust_norm": math.inf}


def _inclination_rms(imu, params) -> float:
    q = make_filter("decoupled", params, q0=imu.q_true[0]).update(imu.t, imu.acc, imu.gyr, imu.mag)
    e = np.degrees(earth_error_angles(q, imu.q_true)[:, 2])
    return float(np.sqrt(np.mean(e * e)))


def _with_linear_acceleration(imu, a_enu):
    """The same motion with an extra linear acceleration (ENU, m/s²) in the specific force."""
    return dataclasses.replace(imu, acc=imu.acc + quat.rotate_inverse(imu.q_true, a_enu))


@pytest.mark.parametrize("rate", [50.0, 286.0])
def test_fast_path_follows_a_gyroscope_misaligned_with_its_accelerometer(rate):
    imu = rotating_imu(seconds=60.0, rate_hz=rate, seed=3, max_rate=2.0)
    imu = dataclasses.replace(imu, gyr=quat.rotate(quat.from_axis_angle([1.0, 0.2, -0.3], np.radians(3.5)), imu.gyr))
    with_fast, without = _inclination_rms(imu, {}), _inclination_rms(imu, NO_FAST)
    # measured: 0.25° / 0.16° with the fast path, 1.64° without
    assert with_fast < 0.5
    assert with_fast < 0.3 * without


def test_trust_keeps_walking_accelerations_out_of_the_fast_path():
    imu = rotating_imu(seconds=60.0, rate_hz=100.0, seed=3, max_rate=0.5)
    t = imu.t
    walking = np.stack([3.0 * np.sin(2 * np.pi * 1.8 * t),
                        1.5 * np.sin(2 * np.pi * 0.9 * t + 1.0),
                        2.0 * np.sin(2 * np.pi * 1.8 * t + 0.5)], axis=1)
    imu = _with_linear_acceleration(imu, walking)
    default, without, ungated = (_inclination_rms(imu, p) for p in ({}, NO_FAST, UNGATED))
    assert default < without + 0.1  # the weighted fast path costs nothing here
    assert ungated > 3.0 * default  # control: the same path without the weight follows the steps


def test_sustained_one_sided_acceleration_regression_guard():
    """2 m/s² east for 3 s in every 10 s: the known cost of the fast path, guarded.

    Measured (inclination RMSE): default 5.8°, without the fast path 3.6° (its rate limit
    slews at most 1.7°/s), VQF 4.5°. After ``tau_acc`` the low-pass has followed the
    acceleration, the estimate is dragged towards it and the innovation shrinks, so the
    trust returns: the accelerometer alone cannot tell a lasting acceleration from gravity.
    """
    imu = rotating_imu(seconds=60.0, rate_hz=100.0, seed=3, max_rate=0.5)
    on = ((imu.t % 10.0) < 3.0).astype(float)
    imu = _with_linear_acceleration(imu, np.stack([2.0 * on, 0.0 * on, 0.0 * on], axis=1))
    default, without = _inclination_rms(imu, {}), _inclination_rms(imu, NO_FAST)
    assert without < default < 7.0
    assert default < np.degrees(np.arctan2(2.0, 9.81))  # never the whole tilt of the specific force


def test_fast_path_settings_are_checked():
    with pytest.raises(ValueError, match="acc_rate_fast must be >= 0"):
        make_filter("decoupled", {"acc_rate_fast": -0.1})
    with pytest.raises(ValueError, match="acc_trust_sigma must be > 0"):
        make_filter("decoupled", {"acc_trust_sigma": 0.0})
    with pytest.raises(ValueError, match="acc_trust_norm must be > 0"):
        make_filter("decoupled", {"acc_trust_norm": -1.0})
