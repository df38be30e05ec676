"""Orientation error of an AHRS against a reference (Justa 2022, eqs. 16 and 35).

The filter starts from the reference quaternion at the first sample and runs over the
whole recording with each sample's own interval; the error of sample i is the angle
``θ(q_ref,i ⊗ q_est,i*) = 2 atan2(|v|, |w|)``. MAE and RMSE are over all samples.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr import quaternion as quat
from pdr.ahrs import make_filter
from pdr.recording import Recording


@dataclass(frozen=True)
class OrientationScore:
    source: str
    filter: str
    errors_deg: np.ndarray  # (N,)

    @property
    def mae_deg(self) -> float:
        return float(np.mean(self.errors_deg))

    @property
    def rmse_deg(self) -> float:
        return float(np.sqrt(np.mean(self.errors_deg**2)))


def run_filter_on(recording: Recording, filter_name: str, params: dict | None = None, use_mag: bool = True) -> np.ndarray:
    """The filter's quaternions at every accelerometer sample, started from the reference."""
    if recording.orientation_ref is None:
        raise ValueError(f"{recording.source}: no orientation reference to start from or score against")
    imu = recording.imu_samples()
    ref = recording.orientation_ref
    q0 = np.array([np.interp(imu.t[0], ref.t, ref.values[:, k]) for k in range(4)])
    f = make_filter(filter_name, params, q0=q0, frame=recording.frame)
    mag = imu.mag if (use_mag and imu.mag is not None) else None
    return f.update(imu.t, imu.acc, imu.gyr, mag)


def score_orientation(recording: Recording, filter_name: str, params: dict | None = None, use_mag: bool = True,
                      samples: slice = slice(None)) -> OrientationScore:
    """Run ``filter_name`` over ``recording`` and compare with its orientation reference.

    ``samples`` restricts the scored samples (the filter still starts at the first one).
    """
    q_est = run_filter_on(recording, filter_name, params, use_mag)
    imu_t = recording.acc.t
    ref = recording.orientation_ref
    if ref.t.shape == imu_t.shape and np.array_equal(ref.t, imu_t):
        q_ref = ref.values
    else:  # reference on its own clock: nearest sample in time
        idx = np.clip(np.searchsorted(ref.t, imu_t), 0, len(ref.t) - 1)
        q_ref = ref.values[idx]
    err = np.degrees(quat.angle_between(q_ref, q_est))[samples]
    return OrientationScore(recording.source, filter_name, err)


def pooled(scores: list[OrientationScore]) -> tuple[float, float]:
    """MAE and RMSE over every sample of every file (each sample weighs the same)."""
    e = np.concatenate([s.errors_deg for s in scores])
    return float(e.mean()), float(np.sqrt(np.mean(e**2)))
