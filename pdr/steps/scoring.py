"""Run a step detector on a :class:`~pdr.recording.Recording` and compare with its true count.

The detector's signal comes from the recording: the norm minus g for ``norm``; for the
vertical detectors, the accelerometer rotated to ENU by the FSCF AHRS (gyroscope, and the
magnetometer when present) minus g, or — when there is no gyroscope, as in the Oxford
set — the projection on a low-passed gravity estimate (:func:`vertical_from_gravity_estimate`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr.events import StepDetection
from pdr.recording import Recording
from pdr.steps import SIGNAL, make_detector
from pdr.steps.signals import (
    norm_minus_gravity,
    vertical_from_gravity_estimate,
    vertical_linear_acceleration,
)


@dataclass(frozen=True)
class StepCount:
    source: str
    detector: str
    signal: str  # "norm", "vertical (fscf)" or "vertical (gravity estimate)"
    steps: list[StepDetection]
    true_steps: int | None
    carry: str | None = None  # where the phone was, when the recording says

    @property
    def detected_steps(self) -> int:
        return len(self.steps)

    @property
    def error_pct(self) -> float | None:
        """Signed ``100 (detected - true) / true``; None without a true count."""
        if not self.true_steps:
            return None
        return 100.0 * (self.detected_steps - self.true_steps) / self.true_steps


def detector_signal(recording: Recording, kind: str) -> tuple[np.ndarray, np.ndarray, str]:
    """``(t, a, description)``: the 1-D signal a detector of signal ``kind`` reads."""
    if recording.acc is None or len(recording.acc) < 2:
        raise ValueError(f"{recording.source}: no accelerometer samples")
    if kind == "norm":
        return recording.acc.t, norm_minus_gravity(recording.acc.values), "norm"
    if recording.gyr is not None and len(recording.gyr) > 1:
        from pdr.ahrs import make_filter  # only the vertical path needs an AHRS

        imu = recording.imu_samples()
        q = make_filter("fscf").update(imu.t, imu.acc, imu.gyr, imu.mag)
        return imu.t, vertical_linear_acceleration(q, imu.acc), "vertical (fscf)"
    t = recording.acc.t
    return t, vertical_from_gravity_estimate(t, recording.acc.values), "vertical (gravity estimate)"


def count_steps(recording: Recording, detector: str, params: dict | None = None, zero_phase: bool = False) -> StepCount:
    """Detect the steps of a whole recording (causal unless ``zero_phase``)."""
    det = make_detector(detector, params)
    t, a, described = detector_signal(recording, SIGNAL[det.name])
    steps = det.detect(t, a, zero_phase=zero_phase)
    return StepCount(recording.source, det.name, described, steps, recording.true_steps, recording.meta.get("carry"))


def mean_abs_error_pct(counts: list[StepCount]) -> float | None:
    """Mean of ``|error_pct|`` over the recordings that have a true count."""
    errors = [abs(c.error_pct) for c in counts if c.error_pct is not None]
    return float(np.mean(errors)) if errors else None
