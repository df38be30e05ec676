"""A synthetic boot-mounted IMU with known truth: still windows, strides, turns and stairs.

For tests and benchmarks (never for tuning). The foot rests for ``stance_s`` between
swings of ``swing_s``; during swing ``i`` it travels the stride vector
``D_i = (L_i cos ψ_i, L_i sin ψ_i, dz_i)`` with a minimum-jerk profile (Flash and Hogan,
J. Neurosci. 5(7), 1985) ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵``, lifted by ``clearance·sin²(πτ)``,
while its yaw turns by the stride's turn along the same profile and its pitch goes from
the previous rest's to this rest's (0, flat, unless a stride says otherwise: a boot resting
on its toe) plus ``pitch·sin(2πτ)·sin²(πτ)`` (toe-off and heel strike). Position,
velocity and attitude are smooth, and so are the IMU signals:

* attitude of the foot ``q_f = q_z(ψ) ⊗ q_y(θ)`` (ZYX Euler, no roll), of the IMU
  ``q = q_f ⊗ q_mount`` (scalar first, Hamilton, body → ENU);
* angular rate in the foot frame ``ω_f = (−ψ̇ sin θ, θ̇, ψ̇ cos θ)`` (ZYX Euler rates),
  in the IMU frame ``R_mountᵀ ω_f``;
* specific force ``f = R(q)ᵀ (a + (0, 0, g))`` with ``a`` the foot's acceleration (ENU);

derivatives by central differences of the closed forms (step 1e-5 s and 1e-4 s), far
below the sensor noise. Biases and white noise are added on request.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdr import quaternion as quat
from pdr.constants import GRAVITY


@dataclass(frozen=True)
class FootWalk:
    """A synthetic recording and its truth."""

    t: np.ndarray  # (n,) s
    acc: np.ndarray  # (n, 3) m/s², IMU frame (with bias and noise)
    gyr: np.ndarray  # (n, 3) rad/s, IMU frame (with bias and noise)
    position: np.ndarray  # (n, 3) m, ENU, true foot position
    q: np.ndarray  # (n, 4) true IMU attitude, body -> ENU
    stance: np.ndarray  # (n,) bool, the foot is at rest
    stance_positions: np.ndarray  # (k + 1, 3) m, where the foot rests: the start, then after each stride
    stance_times: np.ndarray  # (k + 1,) s, the middle of each rest
    acc_bias: np.ndarray  # (3,) m/s²
    gyr_bias: np.ndarray  # (3,) rad/s


def _min_jerk(tau):
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)


def square_strides(side_strides: int = 6, length: float = 1.2, sides: int = 4, clockwise: bool = False):
    """Strides of a closed square walk: ``side_strides`` per side, a quarter turn at each corner."""
    turn = -math.pi / 2 if clockwise else math.pi / 2
    out = []
    for side in range(sides):
        for k in range(side_strides):
            out.append((length, turn if (k == 0 and side > 0) else 0.0, 0.0))
    return out


def foot_walk(strides, rate_hz: float = 200.0, stance_s: float = 0.45, swing_s: float = 0.65,
              still_start_s: float = 2.0, still_end_s: float = 2.0, clearance_m: float = 0.12,
              pitch_rad: float = 0.9, yaw0: float = 0.0, mount: np.ndarray | None = None,
              acc_bias=(0.0, 0.0, 0.0), gyr_bias=(0.0, 0.0, 0.0), acc_noise: float = 0.0, gyr_noise: float = 0.0,
              gravity: float = GRAVITY, seed: int = 0, t0: float = 0.0) -> FootWalk:
    """Synthesise a walk of ``strides``: a sequence of ``(length m, turn rad, dz m)`` or
    ``(length, turn, dz, rest pitch rad)``.

    ``mount`` (w, x, y, z) is the IMU's attitude on the foot (foot ← IMU; default: the
    3DM-GX3 of the PyShoe data, z down, a half turn about x). ``acc_noise`` (m/s²) and
    ``gyr_noise`` (rad/s) are per-sample standard deviations.
    """
    strides = np.asarray(strides, dtype=float)
    strides = strides.reshape(-1, strides.shape[-1] if strides.size else 3)
    if strides.shape[1] == 3:
        strides = np.column_stack((strides, np.zeros(strides.shape[0])))
    k = strides.shape[0]
    rest_pitch = np.concatenate(([0.0], strides[:, 3]))
    mount = np.array([0.0, 1.0, 0.0, 0.0]) if mount is None else np.asarray(mount, float)
    # rest positions and headings
    yaw = yaw0 + np.concatenate(([0.0], np.cumsum(strides[:, 1])))
    rest = np.zeros((k + 1, 3))
    for i in range(k):
        d = np.array([strides[i, 0] * math.cos(yaw[i + 1]), strides[i, 0] * math.sin(yaw[i + 1]), strides[i, 2]])
        rest[i + 1] = rest[i] + d
    # timeline: still_start, then (swing, stance) per stride, the last stance as long as still_end
    swing_start = still_start_s + np.arange(k) * (swing_s + stance_s)
    duration = still_start_s + k * (swing_s + stance_s) - (stance_s if k else 0.0) + still_end_s
    n = int(math.floor(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz

    def state(tt):
        """position (m, 3), yaw, pitch at times tt (closed forms)."""
        i = np.clip(np.searchsorted(swing_start, tt, side="right") - 1, -1, k - 1)
        tau = np.where(i >= 0, (tt - swing_start[np.maximum(i, 0)]) / swing_s, 0.0)
        swinging = (i >= 0) & (tau < 1.0)
        tau = np.clip(tau, 0.0, 1.0)
        s = _min_jerk(tau)
        a = rest[np.maximum(i, 0)]
        b = rest[np.maximum(i, 0) + (i >= 0)]
        pos = np.where((i >= 0)[:, None], a + s[:, None] * (b - a), rest[0])
        pos[:, 2] += np.where(swinging, clearance_m * np.sin(np.pi * tau) ** 2, 0.0)
        y0 = yaw[np.maximum(i, 0)]
        y1 = yaw[np.maximum(i, 0) + (i >= 0)]
        psi = np.where(i >= 0, y0 + s * (y1 - y0), yaw[0])
        p0 = rest_pitch[np.maximum(i, 0)]
        p1 = rest_pitch[np.maximum(i, 0) + (i >= 0)]
        theta = np.where(i >= 0, p0 + s * (p1 - p0), rest_pitch[0])
        theta = theta + np.where(swinging, pitch_rad * np.sin(2 * np.pi * tau) * np.sin(np.pi * tau) ** 2, 0.0)
        return pos, psi, theta, swinging

    h1, h2 = 1e-5, 1e-4
    pos, psi, theta, swinging = state(t)
    _, psi_p, th_p, _ = state(t + h1)
    _, psi_m, th_m, _ = state(t - h1)
    dpsi, dth = (psi_p - psi_m) / (2 * h1), (th_p - th_m) / (2 * h1)
    pp, _, _, _ = state(t + h2)
    pm, _, _, _ = state(t - h2)
    acc_nav = (pp - 2 * pos + pm) / (h2 * h2)
    w_foot = np.column_stack((-dpsi * np.sin(theta), dth, dpsi * np.cos(theta)))
    zeros = np.zeros(n)
    q_foot = quat.multiply(np.column_stack((np.cos(psi / 2), zeros, zeros, np.sin(psi / 2))),
                           np.column_stack((np.cos(theta / 2), zeros, np.sin(theta / 2), zeros)))
    q = quat.multiply(q_foot, mount)
    w_imu = quat.rotate_inverse(mount, w_foot)
    f_nav = acc_nav + np.array([0.0, 0.0, gravity])
    f_imu = quat.rotate_inverse(q, f_nav)
    rng = np.random.default_rng(seed)
    ab, gb = np.asarray(acc_bias, float), np.asarray(gyr_bias, float)
    acc = f_imu + ab + (rng.normal(0.0, acc_noise, (n, 3)) if acc_noise > 0 else 0.0)
    gyr = w_imu + gb + (rng.normal(0.0, gyr_noise, (n, 3)) if gyr_noise > 0 else 0.0)
    rest_mid = np.concatenate(([still_start_s / 2], swing_start + swing_s + stance_s / 2))
    if k:
        rest_mid[-1] = swing_start[-1] + swing_s + still_end_s / 2
    return FootWalk(t=t + t0, acc=acc, gyr=gyr, position=pos, q=q, stance=~swinging, stance_positions=rest,
                    stance_times=rest_mid + t0, acc_bias=ab, gyr_bias=gb)
