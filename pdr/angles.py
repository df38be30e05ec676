"""Angles, one convention: yaw in radians, counter-clockwise from East (ENU; gtsam Pose2's
theta), wrapped to (-π, π]; what a person reads is a compass bearing, degrees clockwise from
North, in [0, 360)."""
from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap(a):
    """Angle(s) wrapped to (-π, π]: ``π − ((π − a) mod 2π)``. A float for a float, an array for an array.

    A float takes Python's ``%``, which is the same IEEE operations as ``np.mod`` (fmod, then the
    divisor added when the signs differ, a signed zero otherwise): the same bits, without numpy's
    per-call overhead (streaming code calls this per step)."""
    if isinstance(a, float):
        return math.pi - ((math.pi - float(a)) % TWO_PI)
    w = np.pi - np.mod(np.pi - np.asarray(a, dtype=float), TWO_PI)
    return float(w) if w.ndim == 0 else w


def bearing_deg(yaw):
    """ENU yaw (CCW from East, rad) -> compass bearing (CW from North, degrees in [0, 360)).

    A float for a float, an array for an array. A yaw a rounding error past π/2 would come out
    as 360.0 after the modulo; that is folded to 0 so the result stays in [0, 360)."""
    b = np.mod(90.0 - np.degrees(yaw), 360.0)
    b = np.where(b >= 360.0, 0.0, b)
    return float(b) if b.ndim == 0 else b


def yaw_from_bearing(bearing: float) -> float:
    """Compass bearing (degrees, CW from North) -> ENU yaw (rad, CCW from East), in (-π, π]."""
    return wrap(math.radians(90.0 - bearing))
