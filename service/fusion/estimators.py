"""Track estimators: steps and fixes in, a :class:`pdr.events.PoseEstimate` out, behind one protocol.

=========  ====================================================================  ==============
name       what                                                                  fixes it uses
=========  ====================================================================  ==============
``fusion`` gtsam fixed-lag factor graph (:class:`service.fusion.graph.TrackFusion`) all
``dr``     dead reckoning alone (:class:`pdr.dead_reckoning.DeadReckoning`): the   checkpoints
           baseline the fusion must beat; a checkpoint moves it
=========  ====================================================================  ==============

A new estimator (a particle filter on the floor plan, say) is one class with these methods and
one :func:`register_estimator` call; the tracker picks it by ``TrackerSettings.engine``.
"""
from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from pdr.dead_reckoning import DeadReckoning
from pdr.events import PoseEstimate, StepEvent
from service.fusion.fixes import CheckpointFix


class FixOutcome(NamedTuple):
    """What an estimator did with a fix: ``verdict`` is ``applied`` (``pose`` is the new live
    estimate), ``rejected`` (a gate refused it: ``reason``) or ``unused`` (nothing in this
    estimator can use it, e.g. GNSS in dead reckoning)."""

    verdict: str
    pose: PoseEstimate | None = None
    reason: str = ""


class TrackEstimator(Protocol):
    """One responder's track from the moment it is placed."""

    def start(self, t: float, x: float, y: float, heading: float, heading_sigma: float, position_sigma: float,
              floor: int) -> None: ...

    def add_step(self, ev: StepEvent) -> PoseEstimate: ...

    def add_fix(self, fix) -> FixOutcome: ...

    def add_gap(self, sigma_m: float) -> None:
        """No samples for a while before the next step: widen that step's position by
        ``sigma_m`` (m), so a fix after the gap re-anchors the track."""
        ...

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        """The responder changed floor at ``t`` without a step (a lift): the newest pose again,
        on ``floor``."""
        ...

    def smoothed_track(self) -> dict[str, np.ndarray] | None:
        """The best estimate in hindsight of every pose so far (columns ``t, x, y, heading,
        floor``), or None when the estimator keeps no history."""
        ...


class DeadReckoningEstimator:
    """Dead reckoning alone; a checkpoint moves the walker, other fixes are unused."""

    def __init__(self, settings=None):
        self._dr = DeadReckoning()

    def start(self, t, x, y, heading, heading_sigma, position_sigma, floor) -> None:
        self._dr.start(t, x, y, floor, position_sigma)

    def add_step(self, ev: StepEvent) -> PoseEstimate:
        return self._dr.add_step(ev)

    def add_gap(self, sigma_m: float) -> None:
        """Dead reckoning keeps no uncertainty to widen: a checkpoint moves it whatever it is."""

    def add_fix(self, fix) -> FixOutcome:
        if isinstance(fix, CheckpointFix):
            return FixOutcome("applied", self._dr.move_to(fix.x, fix.y, fix.sigma))
        return FixOutcome("unused", reason=f"{type(fix).__name__} is not used by dead reckoning")

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        p = self._dr.point
        self._dr.point = dataclasses.replace(p, t=max(p.t, t), floor=floor)
        return self._dr.point

    def smoothed_track(self) -> None:
        return None


class FusionEstimator:
    """The gtsam factor graph (:class:`service.fusion.graph.TrackFusion`) behind the protocol."""

    def __init__(self, settings=None):
        from service.fusion.graph import (
            TrackFusion,  # gtsam: loaded when a track starts
        )

        self.fusion = TrackFusion(settings)
        self._steps = 0

    def start(self, t, x, y, heading, heading_sigma, position_sigma, floor) -> None:
        self.fusion.start(t, x, y, heading, heading_sigma, position_sigma, floor)

    def add_step(self, ev: StepEvent) -> PoseEstimate:
        self._steps = ev.index
        return self._pose(self.fusion.add_step(ev))

    def add_gap(self, sigma_m: float) -> None:
        self.fusion.add_gap(sigma_m)

    def add_fix(self, fix) -> FixOutcome:
        before = Counter(self.fusion.rejected)
        fp = self.fusion.add_fix(fix)
        if fp is None:
            reason = next(iter(Counter(self.fusion.rejected) - before), "rejected")
            return FixOutcome("rejected", reason=reason)
        return FixOutcome("applied", self._pose(fp))

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        return self._pose(self.fusion.set_floor(t, floor))

    def smoothed_track(self) -> dict[str, np.ndarray]:
        return self.fusion.smoothed_track()

    def _pose(self, fp) -> PoseEstimate:
        return PoseEstimate(fp.t, fp.x, fp.y, fp.heading, np.asarray(fp.cov), fp.floor, self._steps, fp.source,
                            getattr(fp, "heading_sigma", math.nan))


_ESTIMATORS: dict[str, Callable[..., TrackEstimator]] = {}


def register_estimator(name: str, factory: Callable[..., TrackEstimator]) -> None:
    """``factory(fusion_settings) -> TrackEstimator``, chosen by ``TrackerSettings.engine``."""
    _ESTIMATORS[name] = factory


def estimator_names() -> tuple[str, ...]:
    return tuple(_ESTIMATORS)


def make_estimator(name: str, settings=None) -> TrackEstimator:
    try:
        factory = _ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown track estimator {name!r}; choose one of {', '.join(_ESTIMATORS)}") from None
    return factory(settings)


register_estimator("fusion", FusionEstimator)
register_estimator("dr", DeadReckoningEstimator)
