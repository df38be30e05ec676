"""One responder's dead reckoning: raw IMU in, :class:`StepEvent` and :class:`MotionEvent` out.

The live service, a replay and the offline evaluation all run the same engine,
:class:`pdr.fleet.PdrFleet`: the service many responders per round, a :class:`PdrPipeline` one
(a fleet of one). Each is fed the same way — ``update(frame)`` with consecutive frames of
samples — and gives the same events, whatever the batching (a recording at once, or live
frames of 10 samples) and whoever else is in the fleet.

Per frame:

1. **Height and floor** — :class:`pdr.height.BarometricAltimeter` on the pressure samples
   (their own clock), then :class:`pdr.floors.FloorTracker`.
2. **Heading** — :class:`pdr.heading.HeadingEstimator` (gyro bias at standstill, levelling
   AHRS, compass offset filter). Its levelling quaternions also rotate the acceleration for
   the vertical detectors, so only one AHRS runs per responder.
3. **Steps** — the ``norm`` detector of :mod:`pdr.steps` (any carry position) on
   ``‖f‖ − g``, put on an even clock first (:mod:`pdr.steps.uniform`: a browser reads the
   sensors at uneven ticks); the detected steps go back to the heading estimator, which answers each
   with its heading once samples up to the step have arrived.
4. **Step length** — :func:`pdr.step_length.step_lengths` with the responder's profile
   (the linear step-frequency model ``L = a + b·f`` by default, seed 002 §2.8); on stairs
   (:class:`pdr.floors.StairsDetector` on the per-step height change) the horizontal
   length becomes whole treads (seed 000 §7: 0.80 m estimated against 0.28 m real).
   Uncertainty ``σ_L = σ_0 + k·L``.
5. **Height change per step** ``dz = h(t_k) − h(t_{k−1})`` where ``h(t)`` is the height at
   the last pressure sample at or before ``t`` — never a later one, so the answer does not
   depend on whether the next pressure sample came in the same frame.
6. **Floor events.** A floor change from the barometer (not from a fix) becomes a
   :class:`pdr.events.FloorEvent` in the event stream, in time order with the steps
   (:mod:`pdr.step_events`).
7. **Motion state** on a grid of ``state_grid_s`` (data time), decided ``state_delay_s``
   behind the newest sample so that every step up to the grid time is already known (the
   norm detector releases the first steps of a bout about 1.5-3 s late):

   * ``walking`` — a step within the last ``still_after_s``;
   * ``no_motion`` — the device has been motionless for ``no_motion_after_s`` (30 s, as a
     PASS device — NFPA 1982 — alarms after 30 s without motion): over every
     ``motionless_window_s`` window the specific-force norm varies less than
     ``motionless_acc_std`` and the gyro stays below ``motionless_gyr``. A window short of
     samples (a pause in the sensor feed) proves neither motion nor stillness: a pause of up to
     ``motionless_pause_s`` inside a stillness neither starts it again nor breaks it; a longer
     one is a gap, and the stillness counts from its end
     (:func:`pdr.fleet_kernels.motion_windows`);
   * ``still`` — otherwise.

   A :class:`MotionEvent` is emitted at each change, with the time the new state began.

Frames must come in time order (the service's frame gate sees to that). Events are returned
in time order per kind; a step event always precedes a motion event of a later time.
"""
from __future__ import annotations

import numpy as np

from pdr.events import FloorEvent, MotionEvent, MotionState, StepEvent
from pdr.fleet import PdrFleet
from pdr.floors import FloorElevations
from pdr.frames import ImuFrame, frame_bounds
from pdr.pipeline_settings import PipelineSettings


class PdrPipeline:
    """Streaming dead reckoning of one responder: ``events = pipeline.update(frame)``; a
    :class:`pdr.fleet.PdrFleet` of one member.

    ``floors`` are the building's floor elevations and ``start_floor`` the floor the
    responder starts on (an incident config, or a checkpoint fix, says which).
    """

    def __init__(self, settings: PipelineSettings | None = None, floors: FloorElevations | None = None,
                 start_floor: int = 0):
        self.floors = floors or FloorElevations.uniform(3.0, min(start_floor, 0), max(start_floor, 0))
        fleet = PdrFleet(settings, self.floors, capacity=1)
        self.settings = fleet.settings
        self.member = fleet.member(start_floor)

    def update(self, frame: ImuFrame) -> list[StepEvent | FloorEvent | MotionEvent]:
        return self.member.update(frame)

    def finish(self) -> list[StepEvent | MotionEvent | FloorEvent]:
        """The stream has ended: steps still inside the detector, and floor changes, are released."""
        return self.member.finish()

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """:meth:`pdr.fleet.PdrFleet.anchor_floor`."""
        self.member.anchor_floor(floor, t)

    @property
    def steps(self) -> int:
        """Steps emitted so far."""
        return self.member.steps

    @property
    def floor(self) -> int:
        return self.member.floor

    def floor_at(self, t: float) -> int:
        """The floor at time ``t`` as the barometer has it now (the last 256 changes are remembered)."""
        return self.member.floor_at(t)

    @property
    def height(self) -> float:
        return self.member.height

    @property
    def last_time(self) -> float:
        """Device time of the newest sample seen (s); -inf before the first."""
        return self.member.last_time

    @property
    def state(self) -> MotionState:
        return self.member.state

    @property
    def motionless_since(self) -> float:
        """:attr:`pdr.fleet.FleetMember.motionless_since`."""
        return self.member.motionless_since

    @property
    def state_since(self) -> float:
        return self.member.state_since


def frames_of(t, acc, gyr, mag=None, pressure_t=None, pressure=None, per_frame: int = 10):
    """Cut arrays into consecutive :class:`ImuFrame` of ``per_frame`` samples (the rule of
    :func:`pdr.frames.frame_bounds`: a pressure sample goes with the frame whose span ends at
    or after it)."""
    t = np.asarray(t, float)
    with_p = pressure_t is not None and pressure is not None
    starts, stops, p_lo, p_hi = frame_bounds(t, per_frame, pressure_t if with_p else None)
    for k, (a, b) in enumerate(zip(starts, stops)):
        pt = pv = None
        if with_p:
            pt, pv = pressure_t[p_lo[k]:p_hi[k]], pressure[p_lo[k]:p_hi[k]]
        yield ImuFrame(t[a:b], acc[a:b], gyr[a:b], None if mag is None else mag[a:b], pt, pv)


def run_pipeline(pipeline: PdrPipeline, frames) -> list[StepEvent | FloorEvent | MotionEvent]:
    """Every event of a finite stream of frames, the stream ended with :meth:`PdrPipeline.finish`."""
    events: list[StepEvent | MotionEvent] = []
    for f in frames:
        events += pipeline.update(f)
    return events + pipeline.finish()


__all__ = ["ImuFrame", "PipelineSettings", "PdrPipeline", "frames_of", "run_pipeline"]
