"""What the PDR engine emits per responder: step events and motion-state changes.

These are the interface between dead reckoning and everything downstream (the factor-graph
fusion, the live service, the console, recordings). Every quantity carries its own
uncertainty so the fusion can weigh it.

Angles: ``heading`` is the direction of travel as yaw, counter-clockwise from East in the
ENU frame (gtsam Pose2's theta), radians. What a person reads is a compass bearing,
clockwise from North in degrees: :func:`bearing_deg`.
"""
from __future__ import annotations

import enum
import math

import numpy as np
from dataclasses import dataclass


class MotionState(str, enum.Enum):
    WALKING = "walking"
    STILL = "still"
    NO_MOTION = "no_motion"  # still for the configured time (30 s): the basis of man-down


@dataclass(frozen=True)
class StepDetection:
    """One step found by a step detector, with the signal statistics step-length models need.

    ``t`` is the time the step was recognised (device clock, s); the step spans
    ``(t_start, t]``. ``a_max``/``a_min``/``a_mean``/``a_mean_abs`` are the maximum, minimum,
    mean and mean absolute value of the detector's linear-acceleration signal over the step
    (m/s²) — the inputs of the Weinberg, Kim and Scarlett models.
    """

    t: float
    t_start: float
    a_max: float
    a_min: float
    a_mean: float
    a_mean_abs: float

    @property
    def duration(self) -> float:
        return self.t - self.t_start


@dataclass(frozen=True)
class StepEvent:
    """A step with everything dead reckoning knows about it, each with its 1-sigma uncertainty."""

    t: float  # s, device clock
    index: int  # 1 for the first step of the responder
    length: float  # m
    length_sigma: float  # m
    heading: float  # rad, yaw of the direction of travel, CCW from East
    heading_sigma: float  # rad, of the absolute heading
    heading_change: float  # rad, since the previous step (gyro: precise short-term)
    heading_change_sigma: float  # rad
    dz: float  # m, height change since the previous step (barometer)
    dz_sigma: float  # m
    floor: int
    on_stairs: bool
    mag_heading: float  # rad, compass heading of travel when the field looked undisturbed, else NaN
    mag_heading_sigma: float  # rad (inf when disturbed)

    @property
    def bearing_deg(self) -> float:
        return bearing_deg(self.heading)


@dataclass(frozen=True)
class MotionEvent:
    """The responder's motion state changed at ``t``."""

    t: float
    state: MotionState
    since: float  # s, when the motion (or stillness) began


@dataclass(frozen=True)
class FloorEvent:
    """The barometer moved the responder to another floor at ``t`` (device clock, s): a
    staircase or a lift passed a floor's level, or a dwell was recognised as another floor's
    (``reason``, see :class:`pdr.floors.FloorChange`). A fix that names the floor is not one.

    It lets a responder who changes floor without walking (a lift) be shown on the new floor
    before the next step; steps carry their floor anyway."""

    t: float
    floor: int
    floor_from: int
    reason: str = "height"


def bearing_deg(yaw):
    """ENU yaw (CCW from East, rad) -> compass bearing (CW from North, degrees in [0, 360)).

    A float for a float, an array for an array. A yaw a rounding error past π/2 would come out
    as 360.0 after the modulo; that is folded to 0 so the result stays in [0, 360)."""
    b = np.mod(90.0 - np.degrees(yaw), 360.0)
    b = np.where(b >= 360.0, 0.0, b)
    return float(b) if b.ndim == 0 else b


def yaw_from_bearing(bearing: float) -> float:
    """Compass bearing (degrees, CW from North) -> ENU yaw (rad, CCW from East), in (-π, π]."""
    y = math.radians(90.0 - bearing)
    return math.atan2(math.sin(y), math.cos(y))
