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


def _heights_through(t_imu, f, tp, h, frame=None) -> np.ndarray:
    """Heights (m) ``h`` at ``tp`` as pressure, through a fresh guard (in frames of ``frame`` s), as heights again."""
    p = 1000.0 - h / M_PER_HPA
    state = np.array(AIR_START, float)
    P = AirGuardSettings().kernel_params
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
    at most 1.6 m of it reaches the height (0.5 m/s for the ramp and the low-pass) (the floor tracker switches at 70 % of a floor, 2.1 m
    at 3 m), and the rest of the walk stays there."""
    walking = np.ones(T_IMU.size, bool)
    h = -_ramp(TP, 20.0, 3.8, 2.0)
    out = _heights_through(T_IMU, _imu(T_IMU, walking), TP, h)
    assert np.all(out[TP < 20.0] == pytest.approx(0.0, abs=1e-9))
    assert -1.6 <= out[-1] <= -0.5 and np.allclose(out[TP > 30.0], out[-1])


def test_stairs_a_lift_and_the_weather_pass_whole():
    """A flight walked at 0.35 m/s, a lift ride standing at 0.7 m/s (0.5 m/s² for 1.4 s at its
    start and stop) and a drift of 1 hPa/h reach the height whole."""
    walking = np.ones(T_IMU.size, bool)
    stairs = np.interp(TP, [10.0, 20.0], [0.0, 3.5]) + 0.02 * np.sin(2 * np.pi * 2.0 * TP)  # 0.35 m/s, a riser a step
    out = _heights_through(T_IMU, _imu(T_IMU, walking), TP, stairs)
    assert out[-1] == pytest.approx(3.5, abs=0.05)
    standing = np.zeros(T_IMU.size, bool)
    acc = np.where((T_IMU >= 20.0) & (T_IMU < 21.4), -0.5, 0.0) + np.where((T_IMU >= 29.6) & (T_IMU < 31.0), 0.5, 0.0)
    ride = -np.interp(TP, [20.0, 21.4, 29.6, 31.0], [0.0, 0.49, 6.23, 6.72])  # down two floors: 0.7 m/s cruise
    out = _heights_through(T_IMU, _imu(T_IMU, standing, acc), TP, ride)
    assert out[-1] == pytest.approx(-6.72, abs=0.1)
    weather = -TP / 3600.0 * M_PER_HPA  # 1 hPa an hour
    out = _heights_through(T_IMU, _imu(T_IMU, standing), TP, weather)
    assert np.allclose(out, weather, atol=1e-9)


def test_without_a_lift_seen_a_fast_change_standing_is_kept_out_and_frames_equal_one_batch():
    """The same ride without the car's accelerations (what a fan or a door does to a standing
    walker) passes only at 0.8 m/s; any framing gives the same heights."""
    standing = np.zeros(T_IMU.size, bool)
    jump = -_ramp(TP, 20.0, 3.0, 1.0)
    f = _imu(T_IMU, standing)
    out = _heights_through(T_IMU, f, TP, jump)
    assert -2.0 <= out[-1] <= -0.5
    for frame in (0.1, 0.73, 5.0):
        np.testing.assert_array_equal(_heights_through(T_IMU, f, TP, jump, frame), out)
