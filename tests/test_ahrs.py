"""The orientation filters: equations, streaming, convergence, settings."""
import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.ahrs import FILTERS, make_filter, settings_with
from pdr.ahrs.base import _NWU_TO_ENU
from pdr.ahrs.reference import scf_reference
from pdr.ahrs.scf import SCFSettings
from pdr.synthetic import rotating_imu, static_imu

ALL = sorted(FILTERS)


def test_closed_form_predictions_equal_sandwich_products():
    """Justa eqs. 23 and 25: the closed forms used in the kernel equal q⁻¹ v q."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = quat.normalize(rng.normal(size=4))
        w, x, y, z = q
        a_pred = np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
        assert np.allclose(a_pred, quat.multiply(quat.multiply(quat.conjugate(q), [0, 0, 0, 1]), q)[1:], atol=1e-12)
        mz = rng.uniform(-1, 1)
        mr = np.array([np.sqrt(1 - mz * mz), 0.0, mz])
        row0 = np.array([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)])
        m_pred = mr[0] * row0 + mr[2] * a_pred
        assert np.allclose(m_pred, quat.multiply(quat.multiply(quat.conjugate(q), np.r_[0, mr]), q)[1:], atol=1e-12)


@pytest.mark.parametrize("exact", [True, False])
def test_kernel_equals_readable_reference(exact):
    imu = rotating_imu(seconds=5, rate_hz=100, seed=2)
    s = SCFSettings(gain_acc=0.3, gain_mag=0.05)
    name = "scf" if exact else "fscf"
    q0 = quat.multiply(quat.conjugate(_NWU_TO_ENU), imu.q_true[0])  # start in the native frame
    f = make_filter(name, {"gain_acc": s.gain_acc, "gain_mag": s.gain_mag}, q0=q0, frame="NWU")
    got = f.update(imu.t, imu.acc, imu.gyr, imu.mag)
    want = scf_reference(q0, np.diff(imu.t), imu.acc[1:], imu.gyr[1:], imu.mag[1:], s.gain_acc, s.gain_mag, exact)
    assert np.abs(got[1:] - want).max() < 1e-12


@pytest.mark.bitexact
@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("with_mag", [True, False])
def test_streaming_in_batches_equals_one_batch(name, with_mag):
    imu = rotating_imu(seconds=6, rate_hz=100, seed=5)
    mag = imu.mag if with_mag else None
    whole = make_filter(name).update(imu.t, imu.acc, imu.gyr, mag)
    for size in (1, 7, 100):
        f = make_filter(name)
        parts = [f.update(imu.t[i:i + size], imu.acc[i:i + size], imu.gyr[i:i + size],
                          None if mag is None else mag[i:i + size]) for i in range(0, len(imu.t), size)]
        # bit for bit: the kernel runs sample by sample and the frame turn is elementwise
        assert np.array_equal(np.concatenate(parts), whole), f"batches of {size}"


@pytest.mark.parametrize("name", ALL)
def test_converges_from_a_wrong_start_on_static_data(name):
    """Started 40° off in tilt and heading, every filter finds the true orientation (slow mag gains: 4 min)."""
    q_true = quat.from_axis_angle([0.2, -0.4, 1.0], 0.9)
    imu = static_imu(seconds=240, rate_hz=100, q_true=q_true)
    wrong = quat.multiply(quat.from_axis_angle([1, 1, 1], np.radians(40)), q_true)
    q = make_filter(name, q0=wrong).update(imu.t, imu.acc, imu.gyr, imu.mag)
    err = np.degrees(quat.angle_between(imu.q_true, q))
    assert err[0] > 39
    assert err[-100:].max() < 1.5, f"{name} still {err[-1]:.2f}° off after 240 s"


@pytest.mark.parametrize("name", ALL)
def test_imu_only_path_recovers_tilt_but_not_heading(name):
    q_true = quat.from_axis_angle([1.0, 0.5, 0.0], 0.5)
    imu = static_imu(seconds=120, rate_hz=100, q_true=q_true)
    wrong = quat.multiply(quat.from_axis_angle([1, 0, 0], np.radians(20)), q_true)
    q = make_filter(name, q0=wrong).update(imu.t, imu.acc, imu.gyr)
    up_est = quat.rotate(q[-1], imu.acc[-1] / np.linalg.norm(imu.acc[-1]))
    assert np.degrees(np.arccos(np.clip(up_est[2], -1, 1))) < 1.5


@pytest.mark.parametrize("name", ALL)
def test_tracks_a_rotating_imu(name):
    imu = rotating_imu(seconds=60, rate_hz=100, seed=11)
    q = make_filter(name, q0=imu.q_true[0]).update(imu.t, imu.acc, imu.gyr, imu.mag)
    err = np.degrees(quat.angle_between(imu.q_true, q))
    assert err.mean() < 2.0


def test_frames_differ_by_a_quarter_turn_about_up():
    imu = rotating_imu(seconds=3, rate_hz=100, seed=4)
    enu = make_filter("fscf").update(imu.t, imu.acc, imu.gyr, imu.mag)
    nwu = make_filter("fscf", frame="NWU").update(imu.t, imu.acc, imu.gyr, imu.mag)
    assert np.allclose(quat.multiply(_NWU_TO_ENU, nwu), enu, atol=1e-12)


def test_first_sample_without_q0_levels_the_body_and_points_y_north():
    imu = static_imu(seconds=1, q_true=quat.from_yaw(0.7))
    q = make_filter("fscf").update(imu.t[:1], imu.acc[:1], imu.gyr[:1], imu.mag[:1])
    assert np.degrees(quat.angle_between(imu.q_true[0], q[0])) < 2.0


def test_gaps_and_repeated_timestamps_do_not_spin_the_state():
    imu = static_imu(seconds=2)
    t = imu.t.copy()
    t[100:] += 30.0  # a 30 s gap
    t[50] = t[49]  # a repeated stamp
    q = make_filter("fscf", q0=imu.q_true[0]).update(t, imu.acc, imu.gyr + 0.5, imu.mag)
    assert np.isfinite(q).all()


def test_settings_errors_are_clear():
    with pytest.raises(ValueError, match="unknown parameter 'gain' .*valid: max_dt, gain_acc, gain_mag"):
        settings_with(SCFSettings(), {"gain": "1"})
    with pytest.raises(ValueError, match="gain_acc='fast' is not a valid float"):
        settings_with(SCFSettings(), {"gain_acc": "fast"})
    with pytest.raises(ValueError, match="unknown filter 'kalman'"):
        make_filter("kalman")
    with pytest.raises(ValueError, match=r"acc must have shape \(3, 3\)"):
        make_filter("fscf").update(np.arange(3.0), np.zeros((3, 2)), np.zeros((3, 3)))
