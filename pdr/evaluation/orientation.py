"""Orientation error of an AHRS against a reference: two published metrics.

* Justa (2022), eqs. 16 and 35 (:func:`score_orientation`): the filter starts from the
  reference quaternion at the first sample and runs over the whole recording with each
  sample's own interval; the error of sample i is the angle
  ``θ(q_ref,i ⊗ q_est,i*) = 2 atan2(|v|, |w|)``. MAE and RMSE are over all samples.
* BROAD (Laidig et al. 2021; :func:`score_benchmark`): the filter starts from its own
  estimate; per trial the RMSE over the ``movement`` samples of the total, heading and
  inclination error of ``q_est ⊗ q_ref*`` (reference gaps left out); the score is the mean
  over trials, also reported by group.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

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
    return orientation_score(recording, q_est, filter_name, samples)


def orientation_score(recording: Recording, q_est: np.ndarray, label: str,
                      samples: slice = slice(None)) -> OrientationScore:
    """Score estimates ``q_est`` (one per accelerometer sample) against the reference (eq. 35)."""
    imu_t = recording.acc.t
    ref = recording.orientation_ref
    if ref.t.shape == imu_t.shape and np.array_equal(ref.t, imu_t):
        q_ref = ref.values
    else:  # reference on its own clock: nearest sample in time
        idx = np.clip(np.searchsorted(ref.t, imu_t), 0, len(ref.t) - 1)
        q_ref = ref.values[idx]
    err = np.degrees(quat.angle_between(q_ref, q_est))[samples]
    return OrientationScore(recording.source, label, err)


def pooled(scores: list[OrientationScore]) -> tuple[float, float]:
    """MAE and RMSE over every sample of every file (each sample weighs the same)."""
    e = np.concatenate([s.errors_deg for s in scores])
    return float(e.mean()), float(np.sqrt(np.mean(e**2)))


# ---------------------------------------------------------------------------------------------
# The BROAD benchmark's metric (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021, §3.3)
# ---------------------------------------------------------------------------------------------

METRICS = ("total", "heading", "inclination")


def earth_error_angles(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Total, heading and inclination error per sample (rad), shape (N, 3); NaN where ``q_ref`` is.

    The error is the rotation ``q_e = q_est ⊗ q_ref*`` expressed in the earth frame (z up).
    It splits uniquely into a rotation about the vertical followed by one about a
    horizontal axis, ``q_e = q_z ⊗ q_h`` with ``q_z = [w, 0, 0, z] / √(w² + z²)``; then

        total       = 2 arccos |w|
        heading     = angle(q_z) = 2 arctan(|z| / |w|)
        inclination = angle(q_h) = 2 arccos √(w² + z²)

    (``q_z* ⊗ q_e`` has a zero z part and scalar ``√(w² + z²)``, so ``q_h`` turns about a
    horizontal axis.) Heading is what a magnetometer fixes, inclination what gravity fixes.
    """
    e = quat.multiply(np.asarray(q_est, float), quat.conjugate(np.asarray(q_ref, float)))
    n = np.linalg.norm(e, axis=-1, keepdims=True)
    e = e / n
    w, z = np.abs(e[..., 0]), np.abs(e[..., 3])
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    heading = 2.0 * np.arctan2(z, w)
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return np.stack([total, heading, inclination], axis=-1)


@dataclass(frozen=True)
class BenchmarkScore:
    """One trial scored with the benchmark's metric (degrees)."""

    source: str
    trial: str
    filter: str
    errors_deg: np.ndarray  # (N, 3): total, heading, inclination per sample (NaN without reference)
    movement: np.ndarray  # (N,) bool: the samples that count
    t: np.ndarray  # (N,) s

    def rmse_deg(self, metric: str = "total") -> float:
        """RMSE over the ``movement`` samples, reference gaps (NaN) left out."""
        e = self.errors_deg[self.movement, METRICS.index(metric)]
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")

    def as_dict(self) -> dict:
        return {"trial": self.trial, "file": self.source,
                **{f"{m}_rmse_deg": self.rmse_deg(m) for m in METRICS}}


def benchmark_score(recording: Recording, q_est: np.ndarray, label: str) -> BenchmarkScore:
    """Score estimates ``q_est`` (body -> ``recording.frame``, one per accelerometer sample)."""
    ref = recording.orientation_ref
    if ref is None:
        raise ValueError(f"{recording.source}: no orientation reference to score against")
    movement = recording.meta.get("movement")
    if movement is None:
        raise ValueError(f"{recording.source}: no 'movement' mask; the benchmark metric needs one")
    if q_est.shape != ref.values.shape:
        raise ValueError(f"{recording.source}: {q_est.shape[0]} estimates for {ref.values.shape[0]} reference samples")
    err = np.degrees(earth_error_angles(q_est, ref.values))
    trial = recording.meta.get("trial") or Path(recording.source).stem
    return BenchmarkScore(recording.source, trial, label, err, np.asarray(movement, bool), ref.t)


def run_from_own_estimate(recording: Recording, filter_name: str, params: dict | None = None,
                          use_mag: bool = True) -> np.ndarray:
    """The filter over the recording, starting from its own first estimate (no reference)."""
    imu = recording.imu_samples()
    f = make_filter(filter_name, params, q0=None, frame=recording.frame)
    mag = imu.mag if (use_mag and imu.mag is not None) else None
    return f.update(imu.t, imu.acc, imu.gyr, mag)


def score_benchmark(recording: Recording, filter_name: str, params: dict | None = None,
                    use_mag: bool = True) -> BenchmarkScore:
    """BROAD metric: the filter starts from its own estimate; RMSE over ``movement`` samples."""
    q = run_from_own_estimate(recording, filter_name, params, use_mag)
    return benchmark_score(recording, q, filter_name)


def benchmark_summary(scores: list[BenchmarkScore], groups: dict[str, list[str]] | None = None) -> dict:
    """Mean over trials of each RMSE, and the same means within every group of ``groups``.

    ``groups`` maps a trial name to its groups (BROAD's ``trials.json``); a trial not listed
    there counts only in the overall mean. Each group reports how many trials it averaged.
    """
    summary = {f"mean_{m}_rmse_deg": float(np.mean([s.rmse_deg(m) for s in scores])) for m in METRICS}
    by_group: dict[str, list[BenchmarkScore]] = {}
    for s in scores:
        for g in (groups or {}).get(s.trial, []):
            by_group.setdefault(g, []).append(s)
    summary["groups"] = {
        g: {"trials": len(members), **{f"mean_{m}_rmse_deg": float(np.mean([s.rmse_deg(m) for s in members]))
                                       for m in METRICS}}
        for g, members in by_group.items()
    }
    return summary
