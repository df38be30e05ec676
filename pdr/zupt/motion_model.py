"""One boot-mounted responder: raw IMU frames in, stride events and motion states out.

:class:`ZuptMotionModel` has the call shape of :class:`pdr.pipeline.PdrPipeline`, so the
service's tracker can hold either: ``events = model.update(frame)`` with consecutive
:class:`pdr.pipeline.ImuFrame`, ``model.finish()`` at the end, and the properties the
tracker and the status reader use (``steps``, ``floor``, ``height``, ``last_time``,
``state``, ``state_since``, ``anchor_floor``).

Per frame:

1. **INS** — :class:`pdr.zupt.ins.ZuptIns` (detector + error-state Kalman filter), half a
   detector window behind the newest sample.
2. **Strides** — each stance after the first becomes a :class:`pdr.events.StepEvent`
   (:mod:`pdr.zupt.strides`): length and direction of travel of the horizontal
   displacement, the turn since the previous stride, the vertical displacement, and their
   sigmas from the filter. One event per stride of the instrumented foot (two steps).
   The INS has no compass: ``heading`` is in the INS's frame (yaw 0 = the boot's x axis at
   the start, unless ``initial_yaw`` is given) with ``heading_sigma`` = π unless aligned;
   ``mag_heading`` is NaN. The factor graph uses only the turns, so a checkpoint or two
   place and orient the track.
3. **Height and floor** — with pressure samples, :class:`pdr.height.BarometricAltimeter`
   then :class:`pdr.floors.FloorTracker`, as in the handheld pipeline; without, the
   INS's height at each stance (start floor's elevation + z) feeds the floor tracker.
   Either way ``dz`` of a stride is the INS's, and ``on_stairs`` is ``|dz|`` past
   :attr:`GaitSettings.stairs_min_dz_m`.
4. **Motion state** on a grid of ``state_grid_s`` of data time, decided up to
   ``min_swing_s`` behind the INS (a stride is known by then):

   * the gait class most frequent among the last ``vote_strides`` strides (walking,
     running, crawling, stairs; a tie goes to the latest) while a stride came within
     ``still_after_s``;
   * ``no_motion`` after ``no_motion_after_s`` (30 s) without a moving sample — moving
     meaning the detector's strict test (SHOE above its base threshold, about 0.17 rad/s
     RMS or 1 m/s² off gravity) failed;
   * ``still`` otherwise.

Frames must come in time order. Events are returned in time order; a step event precedes
a motion event of the same time. Bit for bit the same whatever the batching.
"""
from __future__ import annotations

import math

import numpy as np

from pdr.events import MotionEvent, MotionState, StepEvent
from pdr.floors import FloorElevations, FloorSettings, FloorTracker
from pdr.height import AltimeterSettings, BarometricAltimeter
from pdr.pipeline import ImuFrame
from pdr.zupt.ins import InsOutput, ZuptIns
from pdr.zupt.settings import ZuptSettings
from pdr.zupt.strides import Stride, StrideMaker


class ZuptMotionModel:
    """Streaming boot-mounted dead reckoning of one responder: ``events = model.update(frame)``.

    ``floors`` are the building's floor elevations and ``start_floor`` the floor the
    responder starts on. ``initial_yaw`` (rad, ENU) orients the INS frame when known;
    ``None`` leaves it unknown (``heading_sigma`` = π).
    """

    def __init__(self, settings: ZuptSettings | None = None, floors: FloorElevations | None = None,
                 start_floor: int = 0, initial_yaw: float | None = None,
                 floor_settings: FloorSettings | None = None, altimeter: AltimeterSettings | None = None):
        self.settings = s = settings or ZuptSettings()
        self.floors = floors or FloorElevations.uniform(3.0, min(start_floor, 0), max(start_floor, 0))
        self.ins = ZuptIns(s, 0.0 if initial_yaw is None else initial_yaw)
        self._aligned = initial_yaw is not None
        self._strides = StrideMaker(s.stride, s.gait)
        self._altimeter = BarometricAltimeter(altimeter or AltimeterSettings(),
                                              start_height_m=self.floors.elevation(start_floor))
        self._tracker = FloorTracker(self.floors, start_floor, floor_settings or FloorSettings())
        self._baro = False  # pressure samples seen: the barometer owns the floor
        self._ins_height_offset = self.floors.elevation(start_floor)  # building elevation of INS z = 0
        self._index = 0
        self._t_last = -math.inf
        self._t0: float | None = None
        self._grid_k = 1
        self._last_moving = -math.inf  # time of the latest moving sample
        self._lm_t = np.empty(0)  # recent sample times and, per sample, the time it last moved
        self._lm_v = np.empty(0)
        self._lm_before = -math.inf  # the last-moving time of the samples pruned from _lm_*
        self._first_sample = math.nan
        self._decided_t = -math.inf  # newest sample the INS has run
        self._recent: list[tuple[float, MotionState, float]] = []  # (t, voted class, run start) of recent strides
        self._votes: list[MotionState] = []  # gait classes of the last strides of the current bout
        self._last_z = math.nan
        self.state = MotionState.STILL
        self.state_since = math.nan
        self.track: list[InsOutput] | None = None  # set to [] to keep every INS output (evaluation)

    # ------------------------------------------------------------------ public state
    @property
    def steps(self) -> int:
        """Stride events emitted so far (one per stride of the instrumented foot)."""
        return self._index

    @property
    def floor(self) -> int:
        return self._tracker.floor

    @property
    def height(self) -> float:
        """Height (m, building elevation) of the latest stance, or the barometer's when it has one."""
        if self._baro:
            return self._altimeter.height
        return self._ins_height_offset + self._last_z if math.isfinite(self._last_z) else self._ins_height_offset

    @property
    def last_time(self) -> float:
        """Device time of the newest sample seen (s); -inf before the first."""
        return self._t_last

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """A fix says the responder is on ``floor`` (at ``t``; a boot's floor is re-referenced
        now: strides between ``t`` and now are already on their floor)."""
        h = self.floors.elevation(floor)
        self._altimeter.anchor(h)
        if math.isfinite(self._last_z):
            self._ins_height_offset = h - self._last_z
        else:
            self._ins_height_offset = h
        self._tracker.anchor(floor, h)

    # ------------------------------------------------------------------ streaming
    def update(self, frame: ImuFrame) -> list[StepEvent | MotionEvent]:
        t = np.asarray(frame.t, float).reshape(-1)
        if t.size and t[0] <= self._t_last:
            raise ValueError(f"frame starts at {t[0]:.6f} s, not after the previous sample at {self._t_last:.6f} s")
        if frame.pressure is not None and frame.pressure_t is not None and len(frame.pressure):
            pt = np.asarray(frame.pressure_t, float).reshape(-1)
            h = self._altimeter.update(pt, np.asarray(frame.pressure, float).reshape(-1))
            self._tracker.update(pt, h)
            self._baro = True
        if t.size == 0:
            return []
        if self._t0 is None:
            self._t0 = float(t[0])
            self._first_sample = float(t[0])
        self._t_last = float(t[-1])
        out = self.ins.update(t, frame.acc, frame.gyr)
        return self._consume(out, final=False)

    def finish(self) -> list[StepEvent | MotionEvent]:
        """The stream has ended: the detector's last samples run through the INS."""
        return self._consume(self.ins.finish(), final=True)

    # ------------------------------------------------------------------ parts
    def _consume(self, out: InsOutput, final: bool) -> list[StepEvent | MotionEvent]:
        if self.track is not None and len(out):
            self.track.append(out)
        steps = self._make_steps(self._strides.update(out.stances))
        motion = self._update_motion(out, final)
        if not motion:
            return list(steps)
        return sorted([*steps, *motion], key=lambda e: (e.t, isinstance(e, MotionEvent)))

    def _make_steps(self, strides: list[Stride]) -> list[StepEvent]:
        events = []
        s = self.settings
        for st in strides:
            self._last_z = st_z = (self._last_z if math.isfinite(self._last_z) else 0.0) + st.dz
            if not self._baro:
                self._tracker.update(np.array([st.t]), np.array([self._ins_height_offset + st_z]))
            self._index += 1
            heading_sigma = st.yaw_sigma if self._aligned else math.hypot(st.yaw_sigma, s.stride.unaligned_heading_sigma)
            events.append(StepEvent(
                t=st.t, index=self._index, length=st.length, length_sigma=st.length_sigma, heading=st.heading,
                heading_sigma=heading_sigma, heading_change=st.heading_change if self._index > 1 else 0.0,
                heading_change_sigma=st.heading_change_sigma, dz=st.dz, dz_sigma=st.dz_sigma,
                floor=int(self._tracker.floor_at(st.t)), on_stairs=abs(st.dz) >= s.gait.stairs_min_dz_m,
                mag_heading=math.nan, mag_heading_sigma=math.inf,
            ))
            prev = self._recent[-1] if self._recent else None
            if prev is None or st.t - prev[0] >= s.gait.still_after_s:
                self._votes = []
            self._votes = (self._votes + [st.gait])[-s.gait.vote_strides:]
            gait = max(reversed(self._votes), key=self._votes.count)  # most frequent; a tie goes to the latest
            same_run = prev is not None and prev[1] is gait and st.t - prev[0] < s.gait.still_after_s
            self._recent.append((st.t, gait, prev[2] if same_run else st.t))
        return events

    def _update_motion(self, out: InsOutput, final: bool) -> list[MotionEvent]:
        g = self.settings.gait
        if len(out):
            # per sample, the time of the latest moving sample at or before it
            moving = np.where(out.quiet, -np.inf, out.t)
            lm = np.maximum.accumulate(np.concatenate(([self._last_moving], moving)))[1:]
            self._last_moving = float(lm[-1])
            self._lm_t = np.concatenate([self._lm_t, out.t])
            self._lm_v = np.concatenate([self._lm_v, lm])
            self._decided_t = float(out.t[-1])
        horizon = self._decided_t if final else self._decided_t - self.settings.stride.min_swing_s
        if self._t0 is None or not math.isfinite(horizon):
            return []
        k_hi = math.floor((horizon + 1e-9 - self._t0) / g.state_grid_s)
        events: list[MotionEvent] = []
        if k_hi < self._grid_k:
            return events
        grid = self._t0 + g.state_grid_s * np.arange(self._grid_k, k_hi + 1)  # whole indices: batching-proof
        self._grid_k = k_hi + 1
        i = np.searchsorted(self._lm_t, grid, side="right") - 1
        lms = np.where(i >= 0, self._lm_v[np.maximum(i, 0)], self._lm_before)
        for gt, lm in zip(grid.tolist(), lms.tolist()):
            lm = lm if math.isfinite(lm) else self._first_sample
            last = self._last_stride_before(gt)
            if last is not None and gt - last[0] < g.still_after_s:
                new, since = last[1], last[2]
            elif gt - lm >= g.no_motion_after_s:
                new, since = MotionState.NO_MOTION, lm
            else:
                new = MotionState.STILL
                since = max(last[0] + g.still_after_s, self._first_sample) if last is not None else self._first_sample
            if new is self.state and not math.isnan(self.state_since):
                continue
            self.state, self.state_since = new, float(since)
            events.append(MotionEvent(t=float(gt), state=new, since=float(since)))
        # forget what no later grid point can ask for: strides before the last one at or
        # before the grid, moving times more than a second behind it
        j = len(self._recent) - 1
        while j > 0 and self._recent[j][0] > grid[-1]:
            j -= 1
        if j > 0:
            del self._recent[:j]
        keep = self._lm_t >= grid[-1] - 1.0
        if not keep.all():
            self._lm_before = float(self._lm_v[~keep][-1])
            self._lm_t, self._lm_v = self._lm_t[keep], self._lm_v[keep]
        return events

    def _last_stride_before(self, gt: float) -> tuple[float, MotionState, float] | None:
        """(time, gait class, start of that class's run) of the latest stride at or before ``gt``."""
        for rec in reversed(self._recent):
            if rec[0] <= gt:
                return rec
        return None


__all__ = ["ZuptMotionModel"]
