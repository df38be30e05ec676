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
from dataclasses import dataclass

import numpy as np

from pdr.angles import bearing_deg, yaw_from_bearing  # noqa: F401  (re-exported)


class MotionState(str, enum.Enum):
    """What a commander reads about a responder's motion.

    The handheld pipeline tells walking, still and no motion; a boot-mounted INS
    (:mod:`pdr.zupt`) also tells running, crawling and climbing stairs, each a kind of
    moving (:attr:`moving`).
    """

    WALKING = "walking"
    STILL = "still"
    NO_MOTION = "no_motion"  # still for the configured time (30 s): the basis of man-down
    RUNNING = "running"
    CRAWLING = "crawling"
    STAIRS = "stairs"  # climbing or descending stairs

    @property
    def moving(self) -> bool:
        return self not in (MotionState.STILL, MotionState.NO_MOTION)


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


@dataclass(frozen=True)
class PoseEstimate:
    """Where a track estimator puts the responder after a step or a fix: the one pose type
    from the estimator (dead reckoning, the factor graph) to the wire's ``Pose``.

    ``x``, ``y`` local ENU (m); ``heading`` ENU yaw of travel (rad); ``cov`` (2, 2) m² of
    (x, y) in ENU; ``source`` ``"pdr"`` before any accepted absolute fix, ``"fused"`` after.
    """

    t: float  # s, device clock
    x: float
    y: float
    heading: float  # rad, ENU yaw (CCW from East)
    cov: np.ndarray  # (2, 2) m²
    floor: int
    steps: int
    source: str = "pdr"
    heading_sigma: float = math.nan  # rad, 1-sigma of the heading, when the estimator knows it
    index: int = 0  # StepEvent.index of the step that made this pose (0: a start or a fix)
    length_scale: float = math.nan  # the estimated factor on the PDR's step length (NaN: not estimated)

    @property
    def bearing_deg(self) -> float:
        """Compass bearing of ``heading``, degrees clockwise from North."""
        return bearing_deg(self.heading)

    @property
    def position_sigma(self) -> float:
        """m, square root of the larger eigenvalue of ``cov`` (the worst direction)."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.cov)[-1], 0.0)))
