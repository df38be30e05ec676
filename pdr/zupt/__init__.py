"""Boot-mounted inertial navigation: zero-velocity detectors, the error-state INS, strides.

* :mod:`pdr.zupt.detectors` — streaming SHOE, ARED, MV and adaptive zero-velocity detectors;
* :mod:`pdr.zupt.ins` — :class:`ZuptIns`, the 15-state error-state Kalman filter INS;
* :mod:`pdr.zupt.motion_model` — :class:`ZuptMotionModel`, stride events and motion states
  in the shape of :class:`pdr.pipeline.PdrPipeline`'s, for the live service;
* :mod:`pdr.zupt.settings` — every number, with its unit.
"""
from pdr.zupt.detectors import Decisions, ZeroVelocityDetector
from pdr.zupt.ins import InsOutput, Stances, ZuptIns, initial_attitude
from pdr.zupt.motion_model import ZuptMotionModel
from pdr.zupt.settings import (
    DETECTORS,
    DetectorSettings,
    GaitSettings,
    InsSettings,
    StrideSettings,
    ZuptSettings,
)

__all__ = [
    "DETECTORS", "Decisions", "DetectorSettings", "GaitSettings", "InsOutput", "InsSettings", "Stances",
    "StrideSettings", "ZeroVelocityDetector", "ZuptIns", "ZuptMotionModel", "ZuptSettings", "initial_attitude",
]
