"""Step detection: streaming detectors over one gravity-free acceleration signal.

Each detector is ``det.update(t, a) -> list[StepDetection]`` (then ``det.finish()`` when
the stream ends), causal, and gives the same steps for any batching of the samples; see
:mod:`pdr.steps.base`. The detectors, by name, and the signal each expects:

* ``norm`` — :class:`NormDetector`, any carry position, the default:
  ``norm_minus_gravity(acc)``. Oxford step-counter set: 1.5 % mean absolute count error.
* ``vertical`` — :class:`VerticalPairDetector`, Ryšánek §3.5.2:
  ``vertical_linear_acceleration(q, acc)``.
* ``peak`` — :class:`PeakDetector`, Tupý §2.2.1: vertical linear acceleration (or the norm).
* ``zero_crossing`` — :class:`ZeroCrossingDetector`, Tupý §2.2.2: the same.

The vertical signal needs the phone's orientation (a gyroscope: ``make_filter("fscf")``);
accelerometer-only logs and phones in a pocket or bag use ``norm``.
:mod:`pdr.steps.scoring` runs a detector on a whole :class:`~pdr.recording.Recording`.
"""
from __future__ import annotations

from pdr.steps.base import DetectorSettings, StepDetector, settings_with
from pdr.steps.handheld import HandheldSettings, PeakDetector, ZeroCrossingDetector
from pdr.steps.norm import NormDetector, NormSettings
from pdr.steps.signals import (
    GRAVITY,
    estimate_rate,
    norm_minus_gravity,
    vertical_from_gravity_estimate,
    vertical_linear_acceleration,
)
from pdr.steps.vertical import VerticalPairDetector, VerticalSettings

DETECTORS: dict[str, type[StepDetector]] = {
    d.name: d for d in (NormDetector, VerticalPairDetector, PeakDetector, ZeroCrossingDetector)
}
DEFAULT_DETECTOR = NormDetector.name
# which signal each detector was designed for: "norm" (‖f‖ - g) or "vertical" (ENU up, gravity removed)
SIGNAL = {"norm": "norm", "vertical": "vertical", "peak": "vertical", "zero_crossing": "vertical"}


def make_detector(name: str = DEFAULT_DETECTOR, params: dict | None = None) -> StepDetector:
    """A detector by name with its defaults, some replaced by ``params`` (``{"floor": 0.6}``)."""
    try:
        cls = DETECTORS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown step detector {name!r}; choose one of {', '.join(DETECTORS)}") from None
    return cls(settings_with(cls.Settings(), params or {}))


__all__ = [
    "DETECTORS", "DEFAULT_DETECTOR", "SIGNAL", "make_detector", "settings_with", "StepDetector", "DetectorSettings",
    "NormDetector", "NormSettings", "VerticalPairDetector", "VerticalSettings",
    "PeakDetector", "ZeroCrossingDetector", "HandheldSettings",
    "GRAVITY", "estimate_rate", "norm_minus_gravity", "vertical_linear_acceleration",
    "vertical_from_gravity_estimate",
]
