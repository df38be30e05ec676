"""Motion models: raw IMU frames in, step (or stride) events and motion states out.

The wearable says where it is worn (``ImuBatch.carry``); the tracker takes the motion model
registered for that carry position. Every model emits :class:`pdr.events.StepEvent` (a step,
or a stride of a boot-mounted unit) and :class:`pdr.events.MotionEvent`, so the estimators,
floors, fixes, alarms and console work the same for all of them.

==============================  ==============================================================
carry                           model
==============================  ==============================================================
``foot``                        boot-mounted IMU: the zero-velocity-aided INS,
                                :class:`pdr.zupt.motion_model.ZuptMotionModel` (a stride event
                                at every stance)
anything else                   handheld / pocket / waist PDR: :class:`pdr.pipeline.PdrPipeline`
==============================  ==============================================================

A new model is a class with the :class:`MotionModel` methods and one
:func:`register_motion_model` call (``tests/test_extension_points.py`` adds one from a test).
The motion model also owns the floor: its floor tracker is anchored by checkpoint fixes that
carry a floor (:meth:`MotionModel.anchor_floor`), and every step event carries its floor.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from pdr.events import MotionEvent, MotionState, StepEvent
from pdr.floors import FloorElevations
from pdr.pipeline import ImuFrame, PdrPipeline


class MotionModel(Protocol):
    steps: int  # steps (strides) emitted so far
    floor: int  # the floor now
    state: MotionState
    state_since: float  # s, device time the state began (NaN before the first decision)
    last_time: float  # s, device time of the newest sample (NaN before the first)

    def update(self, frame: ImuFrame) -> list[StepEvent | MotionEvent]:
        """Consecutive samples in; the events they complete, in time order (the same for any batching)."""
        ...

    def finish(self) -> list[StepEvent | MotionEvent]:
        """The events still held back for samples that will not come."""
        ...

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """The responder was on ``floor`` at device time ``t`` (default: now); a checkpoint said so."""
        ...


MotionFactory = Callable[[object, FloorElevations, int], MotionModel]  # (TrackerSettings, floors, start floor)


def _handheld(settings, floors: FloorElevations, start_floor: int) -> MotionModel:
    return PdrPipeline(settings.pipeline, floors, start_floor)


def _foot(settings, floors: FloorElevations, start_floor: int) -> MotionModel:
    from pdr.zupt.motion_model import ZuptMotionModel

    pipeline = settings.pipeline  # the barometer and floor settings are the handheld pipeline's
    return ZuptMotionModel(floors=floors, start_floor=start_floor, floor_settings=pipeline.floor,
                           altimeter=pipeline.altimeter)


DEFAULT_CARRY = "handheld"
_MODELS: dict[str, MotionFactory] = {DEFAULT_CARRY: _handheld, "foot": _foot}


def register_motion_model(carry: str, factory: MotionFactory) -> None:
    """Frames whose ``carry`` is ``carry`` are tracked by ``factory(settings, floors, start_floor)``."""
    _MODELS[carry] = factory


def motion_model_for(carry: str | None) -> MotionFactory:
    """The factory registered for ``carry``; the handheld PDR for anything else."""
    return _MODELS.get(carry or DEFAULT_CARRY, _MODELS[DEFAULT_CARRY])
