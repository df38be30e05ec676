"""The air guard (pdr.air_guard): pressure changes no motion explains stay out of the height."""
from __future__ import annotations

import numpy as np
import pytest

from pdr.air_guard import AIR_START, AirGuardSettings, guard_run

G = 9.81
M_PER_HPA = AirGuardSettings().m_per_hpa


def _imu(t: np.ndarray, walking: np.ndarray, lift_acc: np.ndarray | None = None) -> np.ndarray:
    """‖f‖ of a walker: a 2 Hz swing of 2 m/s² while walking, a hand's 0.05 m/s² otherwise, plus a
    lift's acceleration."""
    rng = np.random.default_rng(3)
    f = G + np.where(walking, 2.0 * np.sin(2 * np.pi * 2.0 * t), 0.0) + rng.normal(0.0, 0.05, t.size)
    return f + (0.0 if lift_acc is None else lift_acc)


def _heights_through(t_imu, f, tp, h, frame=None, settings=None, noise_hpa=0.0) -> np.ndarray:
    """Heights (m) ``h`` at ``tp`` as pressure (plus white noise of ``noise_hpa``), through a fresh
    guard (in frames of ``frame`` s), as heights again."""
    p = 1000.0 - h / M_PER_HPA + np.random.default_rng(5).normal(0.0, noise_hpa, tp.size) * (noise_hpa > 0)
    state = np.array(AIR_START, float)
    P = (settings or AirGuardSettings()).kernel_params
    if frame is None:
        out = guard_run(t_imu, f, tp, p, state, P)
    else:
        out = []
        for a in np.arange(0.0, tp[-1] + frame, frame):
            si, sp = (t_imu > a - 1e-9) & (t_imu < a + frame - 1e-9), (tp > a - 1e-9) & (tp < a + frame - 1e-9)
            out.append(guard_run(t_imu[si], f[si], tp[sp], p[sp], state, P))
        out = np.concatenate(out)
    return (1000.0 - out) * M_PER_HPA


def _ramp(t, start, height, ramp_s):
    x = np.clip((t - start) / ramp_s, 0.0, 1.0)
    return height * 0.5 * (1.0 - np.cos(np.pi * x))


T_IMU = np.arange(0.0, 60.0, 0.01)
TP = np.arange(0.0, 60.0, 0.1)


def test_a_fan_started_while_walking_is_mostly_kept_out():
    """A 45 Pa rise (3.8 m lower to the barometer) in 2 s while the walker walks on a level:
    at most 1.8 m of it reaches the height (0.6 m/s for the ramp and the low-pass) (the floor tracker switches at 70 % of a floor, 2.1 m
    at 3 m), and the rest of the walk stays there."""
    walking = np.ones(T_IMU.size, bool)
    h = -_ramp(TP, 20.0, 3.8, 2.0)
    out = _heights_through(T_IMU, _imu(T_IMU, walking), TP, h)
    assert np.all(out[TP < 20.0] == pytest.approx(0.0, abs=1e-9))
    assert -1.8 <= out[-1] <= -0.5 and np.allclose(out[TP > 30.0], out[-1])


def test_stairs_lifts_and_the_weather_pass_whole():
    """A flight walked at 0.35 m/s, lift rides standing at the museum's 0.7 m/s and at a tall
    building's 2.5 m/s, and a drift of 1 hPa/h reach the height whole."""
    walking = np.ones(T_IMU.size, bool)
    stairs = np.interp(TP, [10.0, 20.0], [0.0, 3.5]) + 0.02 * np.sin(2 * np.pi * 2.0 * TP)  # 0.35 m/s, a riser a step
    out = _heights_through(T_IMU, _imu(T_IMU, walking), TP, stairs)
    assert out[-1] == pytest.approx(3.5, abs=0.05)
    standing = np.zeros(T_IMU.size, bool)
    for speed in (0.7, 2.5):
        ride = -np.interp(TP, [20.0, 20.0 + 6.72 / speed], [0.0, 6.72])  # down two floors
        out = _heights_through(T_IMU, _imu(T_IMU, standing), TP, ride)
        np.testing.assert_allclose(out, ride, atol=1e-9)
    weather = -TP / 3600.0 * M_PER_HPA  # 1 hPa an hour
    out = _heights_through(T_IMU, _imu(T_IMU, standing), TP, weather)
    assert np.allclose(out, weather, atol=1e-9)


def test_a_noisy_barometer_widens_the_limit():
    """A 1 Hz barometer with 0.05 hPa of noise (the suite's ``baro_cheap``) on a 10-minute level
    walk: the guard takes its noise for air only rarely, and the offset stays within 0.3 m; with
    the limit held at the gait's (noise_sigmas near 0) the offset wanders past it."""
    t_imu, tp = np.arange(0.0, 600.0, 0.01), np.arange(0.0, 600.0, 1.0)
    f = _imu(t_imu, np.ones(t_imu.size, bool))
    level = np.zeros(tp.size)
    wander = lambda s: np.max(np.abs(_heights_through(t_imu, f, tp, level, settings=s, noise_hpa=0.05)
                                     - _heights_through(t_imu, f, tp, level, settings=AirGuardSettings(enabled=False,
                                                        noise_sigmas=1e6, step_climb_mps=1e6), noise_hpa=0.05)))
    assert wander(AirGuardSettings()) < 0.3
    assert wander(AirGuardSettings(noise_sigmas=1e-6)) > 0.5


def test_a_fast_change_standing_passes_and_frames_equal_one_batch():
    """Standing, a change of any speed passes (a lift or the air: the guard cannot tell them
    apart; a fan started then is not handled); any framing gives the same heights."""
    standing = np.zeros(T_IMU.size, bool)
    jump = -_ramp(TP, 20.0, 3.0, 1.0)
    out = _heights_through(T_IMU, _imu(T_IMU, standing), TP, jump)
    np.testing.assert_allclose(out, jump, atol=1e-9)
    walking = np.ones(T_IMU.size, bool)
    f = _imu(T_IMU, walking)
    out = _heights_through(T_IMU, f, TP, jump)
    assert out[-1] > -2.0
    for frame in (0.1, 0.73, 5.0):
        np.testing.assert_array_equal(_heights_through(T_IMU, f, TP, jump, frame), out)


def test_a_door_opened_walking_and_shut_standing_leaves_no_offset():
    """A door (−37 Pa: +3.1 m to the barometer, in 1.5 s) opened while the walker walks and shut
    20 s later while the walker stands: the opening is kept out, the shutting gives it back, and
    the height ends where it began (without the release it stayed off by what was kept out). A
    lift ridden standing long after (beyond ``release_s``) passes whole."""
    walking = (T_IMU < 25.0)
    door = _ramp(TP, 10.0, 3.1, 1.5) - _ramp(TP, 30.0, 3.1, 1.5)
    f = _imu(T_IMU, walking)
    out = _heights_through(T_IMU, f, TP, door)
    kept = _heights_through(T_IMU, f, TP, door, settings=AirGuardSettings(release_s=0.0))
    assert out[(TP > 12.0) & (TP < 25.0)].max() < 2.0  # kept out while open
    assert kept[-1] < -1.0  # without the release, the door's shutting stays in the height
    assert abs(out[-1]) < 0.2
    t_imu, tp = np.arange(0.0, 120.0, 0.01), np.arange(0.0, 120.0, 0.1)
    walking = (t_imu < 25.0)
    lift = np.interp(tp, [80.0, 80.0 + 3.0 / 0.7], [0.0, 3.0])  # one floor up at 0.7 m/s, 50 s after the door
    door = _ramp(tp, 10.0, 3.1, 1.5)  # a door opened walking and left open
    out = _heights_through(t_imu, _imu(t_imu, walking), tp, door + lift)
    assert out[-1] - out[tp < 79.0][-1] == pytest.approx(3.0, abs=0.05)


def test_a_noisy_barometer_standing_does_not_drain_the_offset():
    """After a fan kept out while walking, 5 minutes standing with a phone barometer's noise
    (0.01 hPa at 10 Hz): the noise's fast parts against the offset are no air coming back, and the
    offset stays. Releasing every change against it (the first form: limits near 0) drains it."""
    t_imu, tp = np.arange(0.0, 330.0, 0.01), np.arange(0.0, 330.0, 0.1)
    walking = (t_imu < 25.0)
    fan = -_ramp(tp, 20.0, 3.8, 2.0)
    f = _imu(t_imu, walking)

    def drift(settings):
        out = _heights_through(t_imu, f, tp, fan, settings=settings, noise_hpa=0.01)
        at_stop = np.mean(out[(tp > 25.0) & (tp < 27.0)])
        assert at_stop > -2.0  # the fan was mostly kept out
        return np.mean(out[-50:]) - at_stop

    assert abs(drift(AirGuardSettings())) < 0.2
    assert drift(AirGuardSettings(still_mps=1e-6, noise_sigmas=1e-6)) < -0.5
