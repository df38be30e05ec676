"""One responder's dead reckoning: raw IMU in, :class:`StepEvent` and :class:`MotionEvent` out.

The live service, a replay and the offline evaluation all feed a :class:`PdrPipeline` the
same way — ``pipeline.update(frame)`` with consecutive frames of samples — and get the
same events, whatever the batching (a recording at once, or live frames of 10 samples).

Per frame:

1. **Height and floor** — :class:`pdr.height.BarometricAltimeter` on the pressure samples
   (their own clock), then :class:`pdr.floors.FloorTracker`.
2. **Heading** — :class:`pdr.heading.HeadingEstimator` (gyro bias at standstill, levelling
   AHRS, compass offset filter). Its levelling quaternions also rotate the acceleration for
   the vertical detectors, so only one AHRS runs per responder.
3. **Steps** — a detector from :mod:`pdr.steps` (``norm`` by default: any carry position)
   on its signal; the detected steps go back to the heading estimator, which answers each
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
   :class:`pdr.events.FloorEvent` in the event stream, in time order with the steps: steps at
   or before the change come before it, later ones after it. A change is released once the
   newest sample is ``floor_event_hold_s`` past it (every step before it has been detected by
   then: the norm detector releases a bout's first steps at most ≈3 s late); steps after a
   change wait for it. So the stream is the same whatever the batching, and a responder in a
   lift is moved to the new floor without a step.
7. **Motion state** on a grid of ``state_grid_s`` (data time), decided ``state_delay_s``
   behind the newest sample so that every step up to the grid time is already known (the
   norm detector releases the first steps of a bout about 1.5-3 s late):

   * ``walking`` — a step within the last ``still_after_s``;
   * ``no_motion`` — the device has been motionless for ``no_motion_after_s`` (30 s, as a
     PASS device — NFPA 1982 — alarms after 30 s without motion): over every
     ``motionless_window_s`` window the specific-force norm varies less than
     ``motionless_acc_std`` and the gyro stays below ``motionless_gyr``;
   * ``still`` — otherwise.

   A :class:`MotionEvent` is emitted at each change, with the time the new state began.

Frames must come in time order (the service's frame gate sees to that). Events are returned
in time order per kind; a step event always precedes a motion event of a later time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pdr.constants import GRAVITY
from pdr.events import FloorEvent, MotionEvent, MotionState, StepDetection, StepEvent
from pdr.floors import (
    FloorElevations,
    FloorSettings,
    FloorTracker,
    StairsDetector,
    StairsSettings,
)
from pdr.frames import frame_bounds
from pdr.heading import HeadingEstimator, HeadingSettings
from pdr.height import AltimeterSettings, BarometricAltimeter
from pdr.step_length import ResponderProfile, step_arrays, step_lengths
from pdr.steps import SIGNAL, make_detector
from pdr.steps.signals import vertical_linear_acceleration
from pdr.windows import norm3, window_moments


@dataclass(frozen=True)
class ImuFrame:
    """Consecutive samples of one responder: what one wire frame (or a slice of a file) holds.

    ``t`` (N,) s device clock, ``acc`` (N, 3) m/s², ``gyr`` (N, 3) rad/s, ``mag`` (N, 3) µT or
    None; pressure on its own clock: ``pressure_t`` (M,) s and ``pressure`` (M,) hPa, or None.
    """

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None = None
    pressure_t: np.ndarray | None = None
    pressure: np.ndarray | None = None

    def __len__(self) -> int:
        return int(np.shape(self.t)[0])


@dataclass(frozen=True)
class PipelineSettings:
    """Every setting of one responder's pipeline, each part with its own record."""

    detector: str = "norm"
    detector_params: tuple[tuple[str, float], ...] = ()
    profile: ResponderProfile = field(default_factory=ResponderProfile)
    heading: HeadingSettings = field(default_factory=HeadingSettings)
    altimeter: AltimeterSettings = field(default_factory=AltimeterSettings)
    floor: FloorSettings = field(default_factory=FloorSettings)
    stairs: StairsSettings = field(default_factory=StairsSettings)
    length_sigma_m: float = 0.05  # σ_0, m: step-length uncertainty floor
    length_sigma_frac: float = 0.08  # k: fraction of the step length
    dz_sigma_m: float = 0.1  # m, per-step height change (barometer after the low-pass)
    min_step_length_m: float = 0.2  # m, a model answer below this is clipped (no negative steps)
    max_step_length_m: float = 1.4  # m, and above this (a running firefighter's long stride)
    floor_event_hold_s: float = 4.0  # s, a floor change is released this long after it (steps before it are out)
    # motion state
    state_grid_s: float = 0.5  # s
    state_delay_s: float = 4.0  # s, decisions lag the newest sample by this much
    still_after_s: float = 2.0  # s without a step -> still
    no_motion_after_s: float = 30.0  # s motionless -> no motion (man-down)
    motionless_window_s: float = 1.0  # s
    motionless_acc_std: float = 0.25  # m/s², std of ‖f‖ over the window
    motionless_gyr: float = 0.15  # rad/s, largest gyro norm in the window

    def __post_init__(self) -> None:
        if self.detector not in SIGNAL:
            raise ValueError(f"unknown step detector {self.detector!r}; choose one of {', '.join(SIGNAL)}")
        if self.state_grid_s <= 0 or self.state_delay_s < 0:
            raise ValueError("state_grid_s must be positive and state_delay_s not negative")


class PdrPipeline:
    """Streaming dead reckoning of one responder: ``events = pipeline.update(frame)``.

    ``floors`` are the building's floor elevations and ``start_floor`` the floor the
    responder starts on (an incident config, or a checkpoint fix, says which).
    """

    def __init__(self, settings: PipelineSettings | None = None, floors: FloorElevations | None = None,
                 start_floor: int = 0):
        self.settings = s = settings or PipelineSettings()
        self.floors = floors or FloorElevations.uniform(3.0, min(start_floor, 0), max(start_floor, 0))
        self._detector = make_detector(s.detector, dict(s.detector_params))
        self._signal = SIGNAL[self._detector.name]
        self._heading = HeadingEstimator(s.heading)
        self._altimeter = BarometricAltimeter(s.altimeter, start_height_m=self.floors.elevation(start_floor))
        self._tracker = FloorTracker(self.floors, start_floor, s.floor)
        self._stairs = StairsDetector(s.stairs)
        self._pending: list[StepDetection] = []  # detected steps waiting for their heading
        self._floor_queue: list = []  # floor changes (FloorChange) not yet released as FloorEvent
        self._held: list[StepEvent] = []  # steps after an unreleased floor change
        self._pres_t = np.empty(0)  # pressure-sample times and heights kept for step dz
        self._pres_h = np.empty(0)
        self._last_step: tuple[float, float] | None = None  # (t, height) of the previous step
        self._step_index = 0
        self._step_times = np.empty(0)  # recent step times, for the motion state
        self._t_last = -math.inf
        self._t0: float | None = None
        self._motion_tail = {"t": np.empty(0), "a": np.empty(0), "g": np.empty(0)}
        self._last_moving = -math.inf  # time of the latest sample that was not motionless
        self._lm_t = np.empty(0)  # recent sample times and, per sample, the time it last moved
        self._lm_v = np.empty(0)
        self._first_sample = math.nan
        self._grid_k = 1  # index of the next motion-state grid point: t0 + k · state_grid_s
        self.state = MotionState.STILL
        self.state_since = math.nan
        self._walk_start = math.nan

    # ------------------------------------------------------------------ public state
    @property
    def steps(self) -> int:
        """Steps emitted so far."""
        return self._step_index

    @property
    def floor(self) -> int:
        return self._tracker.floor

    def floor_at(self, t: float) -> int:
        """The floor at time ``t`` as the barometer has it now (the last 256 changes are remembered)."""
        return self._tracker.floor_at(t)

    @property
    def height(self) -> float:
        return self._altimeter.height

    @property
    def last_time(self) -> float:
        """Device time of the newest sample seen (s); -inf before the first."""
        return self._t_last

    @property
    def motionless_since(self) -> float:
        """s, device time of the newest sample that was not motionless (the stillness, if any,
        began after it; the first sample's time when none moved, NaN before any). Unlike the
        motion state it is not held back by ``state_delay_s``: motionlessness needs no steps."""
        return self._last_moving if math.isfinite(self._last_moving) else self._first_sample

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """A fix says the responder was on ``floor`` at time ``t`` (default: now): re-reference
        height and floor. A fix is applied when the first step after it arrives; if the
        barometer has changed floor since ``t`` (a lift between the fix and the next step), the
        fix speaks of the floor left behind: when that was right nothing is re-referenced, when
        it was wrong the current floor is shifted by the same number of floors."""
        if t is not None and self._tracker.floor_at(t) != self._tracker.floor:
            then = self._tracker.floor_at(t)
            if then == floor:
                return
            floors = self.floors.floors.tolist()
            k = floors.index(self._tracker.floor) + floors.index(int(floor)) - floors.index(then)
            floor = floors[min(max(k, 0), len(floors) - 1)]
        h = self.floors.elevation(floor)
        before = self._altimeter.height
        self._altimeter.anchor(h)
        # the altimeter now reads the configured elevation; the floor tracker keeps its own level
        # frame continuous across that jump and learns from the fix what it can
        self._tracker.anchor(floor, h, shift=h - before if math.isfinite(before) else 0.0)
        self._floor_queue = []  # changes the barometer made before the fix are superseded by it
        if self._pres_h.size:
            self._pres_h = self._pres_h + (h - self._pres_h[-1])
        if self._last_step is not None:
            self._last_step = (self._last_step[0], h)

    # ------------------------------------------------------------------ streaming
    def update(self, frame: ImuFrame) -> list[StepEvent | FloorEvent | MotionEvent]:
        t = np.asarray(frame.t, float).reshape(-1)
        if t.size and t[0] <= self._t_last:
            raise ValueError(f"frame starts at {t[0]:.6f} s, not after the previous sample at {self._t_last:.6f} s")
        acc = np.asarray(frame.acc, float).reshape(-1, 3)
        gyr = np.asarray(frame.gyr, float).reshape(-1, 3)
        mag = None if frame.mag is None else np.asarray(frame.mag, float).reshape(-1, 3)
        if frame.pressure is not None and frame.pressure_t is not None and len(frame.pressure):
            self._update_height(np.asarray(frame.pressure_t, float).reshape(-1), np.asarray(frame.pressure, float).reshape(-1))
        if t.size == 0:
            return []
        if self._t0 is None:
            self._t0 = float(t[0])
        self._t_last = float(t[-1])

        acc_norm = norm3(acc)  # once: the heading's stillness test, the detector, the motion state
        self._heading.update(t, acc, gyr, mag, acc_norm=acc_norm)
        if self._signal == "norm":
            a = acc_norm - GRAVITY  # norm_minus_gravity
        else:
            a = vertical_linear_acceleration(self._heading.samples["q"], acc)
        found = self._detector.update(t, a)
        headings = self._heading.steps([d.t for d in found])
        self._pending += found
        steps = self._release(self._make_steps(headings), self._t_last - self.settings.floor_event_hold_s)
        motion = self._update_motion(t, acc_norm, gyr)
        return _merge(steps, motion)

    def finish(self) -> list[StepEvent | MotionEvent | FloorEvent]:
        """The stream has ended: steps still inside the detector, and floor changes, are released."""
        found = self._detector.finish()
        headings = self._heading.steps([d.t for d in found])
        self._pending += found
        return self._release(self._make_steps(headings), math.inf)

    def _release(self, steps: list[StepEvent], horizon: float) -> list[StepEvent | FloorEvent]:
        """Steps and floor events in time order: changes up to ``horizon``, and the steps before
        the first change still held (see the module docstring, 6)."""
        self._held += steps
        out: list[StepEvent | FloorEvent] = []
        while self._floor_queue and self._floor_queue[0].t <= horizon:
            c = self._floor_queue.pop(0)
            n = sum(1 for e in self._held if e.t <= c.t)
            out += self._held[:n]
            self._held = self._held[n:]
            out.append(FloorEvent(t=c.t, floor=c.floor_to, floor_from=c.floor_from, reason=c.reason))
        bound = self._floor_queue[0].t if self._floor_queue else math.inf
        n = sum(1 for e in self._held if e.t <= bound)
        out += self._held[:n]
        self._held = self._held[n:]
        return out

    # ------------------------------------------------------------------ parts
    def _update_height(self, pt: np.ndarray, p: np.ndarray) -> None:
        h = self._altimeter.update(pt, p)
        self._floor_queue += [c for c in self._tracker.update(pt, h).changes if c.reason != "anchor"]
        keep = self._pres_t > (pt[-1] - 60.0)
        self._pres_t = np.concatenate([self._pres_t[keep], pt])
        self._pres_h = np.concatenate([self._pres_h[keep], h])

    def _height_before(self, t: np.ndarray) -> np.ndarray:
        """Height at the last pressure sample at or before each ``t`` (NaN before any)."""
        if self._pres_t.size == 0:
            return np.full(t.shape, np.nan)
        i = np.searchsorted(self._pres_t, t, side="right") - 1
        return np.where(i >= 0, self._pres_h[np.maximum(i, 0)], np.nan)

    def _make_steps(self, hd) -> list[StepEvent]:
        n = len(hd)
        if n == 0:
            return []
        s = self.settings
        det, self._pending = self._pending[:n], self._pending[n:]
        L = np.clip(step_lengths(step_arrays(det), s.profile), s.min_step_length_m, s.max_step_length_m)
        h = self._height_before(hd.t)
        h_prev = np.concatenate(([self._last_step[1] if self._last_step else np.nan], h[:-1]))
        dz = np.where(np.isfinite(h) & np.isfinite(h_prev), h - h_prev, 0.0)
        dz_sigma = np.where(np.isfinite(h) & np.isfinite(h_prev), s.dz_sigma_m, math.inf)
        stairs = self._stairs.update(dz)
        L = np.where(stairs.on_stairs, stairs.length, L)
        sigma_L = s.length_sigma_m + s.length_sigma_frac * L
        events = []
        for k in range(n):
            self._step_index += 1
            events.append(StepEvent(
                t=float(hd.t[k]), index=self._step_index, length=float(L[k]), length_sigma=float(sigma_L[k]),
                heading=float(hd.heading[k]), heading_sigma=float(hd.heading_sigma[k]),
                heading_change=float(hd.heading_change[k]) if self._step_index > 1 else 0.0,
                heading_change_sigma=float(hd.heading_change_sigma[k]),
                dz=float(dz[k]), dz_sigma=float(dz_sigma[k]), floor=int(self._tracker.floor_at(float(hd.t[k]))),
                on_stairs=bool(stairs.on_stairs[k]), mag_heading=float(hd.mag_heading[k]),
                mag_heading_sigma=float(hd.mag_heading_sigma[k]),
            ))
        self._last_step = (float(hd.t[-1]), float(h[-1]))
        self._step_times = np.concatenate([self._step_times[-64:], hd.t])
        return events

    def _motionless(self, t, acc_norm, gyr) -> np.ndarray:
        """Per sample: the window ending at it was motionless (rolling std of ‖f‖, max ‖ω‖)."""
        s = self.settings
        T = np.concatenate([self._motion_tail["t"], t])
        A = np.concatenate([self._motion_tail["a"], acc_norm])
        G = np.concatenate([self._motion_tail["g"], norm3(gyr)])
        m = self._motion_tail["t"].size
        _, std, top, first = window_moments(T, np.column_stack((A, G)), m, s.motionless_window_s)
        full = (T[m:] - T[first]) >= 0.9 * s.motionless_window_s
        keep = T > T[-1] - s.motionless_window_s - 1e-9
        self._motion_tail = {"t": T[keep], "a": A[keep], "g": G[keep]}
        return full & (std[:, 0] < s.motionless_acc_std) & (top[:, 1] < s.motionless_gyr)

    def _update_motion(self, t, acc_norm, gyr) -> list[MotionEvent]:
        s = self.settings
        still = self._motionless(t, acc_norm, gyr)
        if math.isnan(self._first_sample):
            self._first_sample = float(t[0])
        # time of the latest moving sample at or before each sample
        moving_t = np.where(~still, t, -np.inf)
        last_moving = np.maximum.accumulate(np.concatenate(([self._last_moving], moving_t)))[1:]
        self._last_moving = float(last_moving[-1])
        self._lm_t = np.concatenate([self._lm_t, t])
        self._lm_v = np.concatenate([self._lm_v, last_moving])
        horizon = self._t_last - s.state_delay_s
        events: list[MotionEvent] = []
        k_hi = math.floor((horizon + 1e-9 - self._t0) / s.state_grid_s)
        if k_hi >= self._grid_k:  # grid times from whole indices: the same however frames were cut
            g = self._t0 + s.state_grid_s * np.arange(self._grid_k, k_hi + 1)
            self._grid_k = k_hi + 1
            i = np.searchsorted(self._lm_t, g, side="right") - 1
            lm = np.where(i >= 0, self._lm_v[np.maximum(i, 0)], -np.inf)
            lm = np.where(np.isfinite(lm), lm, self._first_sample)
            j = np.searchsorted(self._step_times, g, side="right") - 1
            known = np.concatenate(([-np.inf], self._step_times))
            last_step = known[j + 1]
            walking = g - last_step < s.still_after_s
            no_motion = ~walking & (g - lm >= s.no_motion_after_s)
            for k in range(g.size):  # a few grid points per frame
                new = MotionState.WALKING if walking[k] else MotionState.NO_MOTION if no_motion[k] else MotionState.STILL
                if new is self.state and not math.isnan(self.state_since):
                    continue
                since = {MotionState.WALKING: float(last_step[k]), MotionState.NO_MOTION: float(lm[k])}.get(
                    new, float(max(last_step[k] + s.still_after_s, self._first_sample)) if np.isfinite(last_step[k]) else self._first_sample)
                self.state, self.state_since = new, since
                events.append(MotionEvent(t=float(g[k]), state=new, since=since))
            drop = self._lm_t < g[-1] - 1.0
            self._lm_t, self._lm_v = self._lm_t[~drop], self._lm_v[~drop]
        return events


def _merge(steps: list[StepEvent | FloorEvent], motion: list[MotionEvent]) -> list[StepEvent | FloorEvent | MotionEvent]:
    if not motion:
        return list(steps)
    # stable: steps and floor events keep their order (a step at a change's time before it)
    return sorted([*steps, *motion], key=lambda e: (e.t, isinstance(e, MotionEvent)))


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
