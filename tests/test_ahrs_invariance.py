"""One set of defaults for any IMU: sample rate, magnetometer units, magnetic disturbance, frames.

Every filter runs with its shipped defaults on the same synthetic motion:

* sampled at 50, 100, 200 and 286 Hz and started 25° off (gains are in continuous time, so
  the estimates converge alike; gains per sample would not);
* with the magnetometer in µT, as unit vectors and in raw counts (only its direction, or
  ratios of its norm, may matter: the estimates agree to rounding);
* with a magnet attached to the sensor for a while (a body-fixed field three times the
  earth's): the inclination must not follow it.
"""
import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.ahrs import DEFAULT_FILTER, FILTERS, make_filter
from pdr.evaluation.orientation import earth_error_angles
from pdr.synthetic import FIELD_ENU, rotating_imu

ALL = sorted(FILTERS)
RATES = (50.0, 100.0, 200.0, 286.0)
COUNTS_PER_UT = 34.6  # a raw magnetometer: |B| ≈ 1670 counts
SECONDS = 90.0


def _imu(rate, seed=21):
    return rotating_imu(seconds=SECONDS, rate_hz=rate, seed=seed, max_rate=1.0)


def _at_whole_seconds(imu, q):
    """Samples at t = 0, 1, 2, ... s (every rate here has one there)."""
    k = np.flatnonzero(np.isclose(imu.t, np.round(imu.t), atol=1e-9))
    return imu.t[k], q[k], imu.q_true[k]


WRONG_START = quat.from_axis_angle([0.3, 1.0, 0.8], np.radians(25.0))  # tilt and heading off


def _runs_at_every_rate(make):
    """Estimates at t = 0, 1, 2, ... s from a start 25° off, one run per rate."""
    runs = {}
    for rate in RATES:
        imu = _imu(rate)
        f = make(rate, quat.multiply(WRONG_START, imu.q_true[0]))
        runs[rate] = _at_whole_seconds(imu, f.update(imu.t, imu.acc, imu.gyr, imu.mag))
    return runs


def _worst_rate_difference(runs) -> float:
    q50 = runs[RATES[0]][1]
    return max(np.degrees(quat.angle_between(q50, runs[r][1])).max() for r in RATES[1:])


@pytest.mark.parametrize("name", ALL)
def test_the_same_orientation_at_every_sample_rate(name):
    """Converging from a wrong start, estimates at 50-286 Hz stay within 1.5° of each other."""
    runs = _runs_at_every_rate(lambda rate, q0: make_filter(name, q0=q0))
    assert _worst_rate_difference(runs) < 1.5
    t, q, q_true = runs[RATES[-1]]
    assert np.degrees(quat.angle_between(q_true[-10:], q[-10:])).max() < 6.0


def test_the_rate_test_catches_gains_per_sample():
    """Control: the same filter with its time constants counted in samples of 100 Hz fails it."""
    d = FILTERS[DEFAULT_FILTER].Settings()
    runs = _runs_at_every_rate(lambda rate, q0: make_filter(
        DEFAULT_FILTER, {"tau_acc": d.tau_acc * 100 / rate, "tau_mag": d.tau_mag * 100 / rate}, q0=q0))
    assert _worst_rate_difference(runs) > 5.0


@pytest.mark.parametrize("name", ALL)
def test_magnetometer_units_do_not_matter(name):
    imu = _imu(100.0)
    norm = np.linalg.norm(imu.mag, axis=1, keepdims=True)
    outs = [make_filter(name).update(imu.t, imu.acc, imu.gyr, m)
            for m in (imu.mag, imu.mag / norm, imu.mag * COUNTS_PER_UT)]
    for other in outs[1:]:
        assert np.degrees(quat.angle_between(outs[0], other)).max() < 1e-6


def _attached_magnet(imu, start=30.0, stop=60.0, strength=3.0):
    """A magnet fixed to the sensor: a constant body-frame field added for ``start..stop`` s."""
    mag = imu.mag.copy()
    on = (imu.t >= start) & (imu.t < stop)
    offset = strength * np.linalg.norm(FIELD_ENU) * np.array([0.6, -0.48, 0.64])
    mag[on] += offset
    return mag, on


@pytest.mark.parametrize("name", ALL)
def test_a_magnet_does_not_drag_the_inclination(name):
    if name == "madgwick":
        pytest.skip("Madgwick's gradient step uses the whole field, so a magnet tilts it by design")
    imu = _imu(100.0)
    mag, _ = _attached_magnet(imu)
    q = make_filter(name, q0=imu.q_true[0]).update(imu.t, imu.acc, imu.gyr, mag)
    incl = np.degrees(earth_error_angles(q, imu.q_true)[:, 2])
    assert incl.max() < 2.0, f"{name}: inclination error {incl.max():.2f}° with a magnet attached"


def test_madgwick_is_tilted_by_a_magnet():
    """The reason Madgwick is exempt above: the field's direction enters its tilt."""
    imu = _imu(100.0)
    mag, on = _attached_magnet(imu)
    q = make_filter("madgwick", q0=imu.q_true[0]).update(imu.t, imu.acc, imu.gyr, mag)
    assert np.degrees(earth_error_angles(q, imu.q_true)[on, 2]).max() > 2.0


def test_the_default_filter_holds_its_heading_through_a_magnet():
    """The disturbance is detected (norm and dip): heading stays within 2°, unlike FSCF's."""
    imu = _imu(100.0)
    mag, on = _attached_magnet(imu)
    after = imu.t >= 20.0
    head = {}
    for name in (DEFAULT_FILTER, "fscf"):
        q = make_filter(name, q0=imu.q_true[0]).update(imu.t, imu.acc, imu.gyr, mag)
        head[name] = np.degrees(earth_error_angles(q, imu.q_true)[:, 1])
    assert head[DEFAULT_FILTER][after].max() < 2.0
    assert head["fscf"][on].max() > 3 * head[DEFAULT_FILTER][on].max()


@pytest.mark.parametrize("name", ALL)
def test_frame_is_stated_not_guessed(name):
    """The same data in ENU and NWU output differ by exactly the quarter turn about up."""
    imu = _imu(100.0)
    enu = make_filter(name).update(imu.t, imu.acc, imu.gyr, imu.mag)
    nwu = make_filter(name, frame="NWU").update(imu.t, imu.acc, imu.gyr, imu.mag)
    turned = quat.multiply(quat.from_yaw(np.pi / 2), nwu)
    assert np.degrees(quat.angle_between(enu, turned)).max() < 1e-9
    with pytest.raises(ValueError, match="unknown frame 'NED'"):
        make_filter(name, frame="NED")


@pytest.mark.parametrize("name", ALL)
def test_own_start_is_level_and_north_from_the_first_samples(name):
    """Started from its own estimate on a tilted, turned sensor: right from the first second.

    (The decoupled filter's inclination rate limit must not slow the start: the first
    ``tau_acc`` seconds are levelled in full.)
    """
    from pdr.synthetic import static_imu

    q_true = quat.multiply(quat.from_yaw(2.0), quat.from_axis_angle([1.0, 0.3, 0.0], np.radians(35.0)))
    imu = static_imu(seconds=10.0, rate_hz=100.0, q_true=q_true)
    q = make_filter(name).update(imu.t, imu.acc, imu.gyr, imu.mag)
    err = np.degrees(earth_error_angles(q, imu.q_true))
    assert err[:, 2].max() < 1.5, f"{name}: inclination {err[:, 2].max():.2f}° off"
    assert err[100:, 1].max() < 2.0, f"{name}: heading {err[100:, 1].max():.2f}° off after 1 s"
