"""Synthetic sensor data whose truth is known, for tests and benchmarks.

Nothing here is fitted to a recording: motions are smooth sums of sinusoids and the
sensors see the true gravity and field through the true orientation, plus noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr import quaternion as quat
from pdr.constants import GRAVITY

# a mid-European field in ENU (µT): 20 north, 44 down (inclination ≈ 65°)
FIELD_ENU = np.array([0.0, 20.0, -44.0])


@dataclass(frozen=True)
class SyntheticImu:
    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray
    q_true: np.ndarray  # body -> ENU


def rotating_imu(
    seconds: float = 60.0,
    rate_hz: float = 100.0,
    max_rate: float = 1.5,
    seed: int = 0,
    acc_noise: float = 0.05,
    gyr_noise: float = 0.005,
    mag_noise: float = 0.3,
    gyr_bias: tuple[float, float, float] = (0.0, 0.0, 0.0),
    q0: np.ndarray | None = None,
) -> SyntheticImu:
    """An IMU turning smoothly (body rates up to about ``max_rate`` rad/s) but not translating.

    The true orientation integrates the body rate exactly; the gyroscope reports that rate
    (plus bias and noise), the accelerometer the specific force ``R(q)ᵀ [0,0,g]`` and the
    magnetometer ``R(q)ᵀ B`` (plus noise).
    """
    rng = np.random.default_rng(seed)
    n = int(round(seconds * rate_hz))
    t = np.arange(n) / rate_hz
    freqs = rng.uniform(0.05, 0.6, size=(3, 3))
    phases = rng.uniform(0, 2 * np.pi, size=(3, 3))
    amps = rng.uniform(0.2, 1.0, size=(3, 3)) * max_rate / 3
    omega = np.stack([(amps[k] * np.sin(2 * np.pi * freqs[k] * t[:, None] + phases[k])).sum(1) for k in range(3)], axis=1)
    q = np.empty((n, 4))
    q[0] = quat.IDENTITY if q0 is None else quat.normalize(q0)
    steps = quat.from_rotation_vector(omega[1:] / rate_hz)
    for i in range(1, n):  # exact integration of the truth; a test fixture, not a hot path
        q[i] = quat.multiply(q[i - 1], steps[i - 1])
    q = quat.normalize(q)
    acc = quat.rotate_inverse(q, np.array([0.0, 0.0, GRAVITY])) + rng.normal(0, acc_noise, (n, 3))
    mag = quat.rotate_inverse(q, FIELD_ENU) + rng.normal(0, mag_noise, (n, 3))
    gyr = omega + np.asarray(gyr_bias) + rng.normal(0, gyr_noise, (n, 3))
    return SyntheticImu(t, acc, gyr, mag, q)


def static_imu(seconds: float = 30.0, rate_hz: float = 100.0, q_true: np.ndarray | None = None, seed: int = 0) -> SyntheticImu:
    """A motionless IMU at orientation ``q_true`` (body -> ENU), with sensor noise."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * rate_hz))
    q = np.tile(quat.IDENTITY if q_true is None else quat.normalize(q_true), (n, 1))
    acc = quat.rotate_inverse(q, np.array([0.0, 0.0, GRAVITY])) + rng.normal(0, 0.03, (n, 3))
    mag = quat.rotate_inverse(q, FIELD_ENU) + rng.normal(0, 0.2, (n, 3))
    gyr = rng.normal(0, 0.002, (n, 3))
    return SyntheticImu(np.arange(n) / rate_hz, acc, gyr, mag, q)
