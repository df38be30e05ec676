"""The dead-reckoning engine: many responders at once, one round at a time.

A service worker keeps hundreds of responders, each sending a frame of ten samples ten times
a second. Run one responder at a time, the cost is the Python around each stage, not the
arithmetic (issue 15: 0.4-0.6 ms per frame, for about 2 µs of compiled work). Here a **round**
— every frame a worker took, for all its responders — goes through each stage once, in
compiled kernels over rows of state, one row per responder (:class:`pdr.fleet_rows.FleetRows`):
height and floor (:mod:`pdr.fleet_kernels`), heading per sample, the motion windows, step
detection (:mod:`pdr.detector_kernels`) and the motion-state grid. One responder alone is a
fleet of one (:class:`pdr.pipeline.PdrPipeline`).

What happens a few times a second per responder — a compass epoch closing, a step, a floor
change — runs in the responder's :class:`FleetMember`: its compass filter and step headings
(:class:`pdr.heading.HeadingEstimator`), its floor tracker (:class:`pdr.floors.FloorTracker`,
working on views of its rows), its :class:`pdr.step_events.StepAssembler` and
:class:`pdr.step_events.FloorEvents`. A responder's events are the same, bit for bit, alone
or among a thousand, in rounds of any size (``tests/test_fleet.py``).

Use: ``fleet = PdrFleet(settings, floors)``, ``m = fleet.member(start_floor)`` per responder,
then ``fleet.run([(m1, frame1), (m2, frame2), ...])`` per round -> one list of events (or the
``ValueError`` that frame raised) per item. A member is also a motion model on its own
(``m.update(frame)``, ``m.finish()``, ``m.anchor_floor(...)``), a round of one.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import signal

from pdr import detector_kernels as DK
from pdr import fleet_kernels as K
from pdr.air_guard import AirGuardSettings, air_stage
from pdr.constants import GRAVITY
from pdr.events import FloorEvent, MotionEvent, MotionState, StepDetection, StepEvent
from pdr.fleet_buffers import get_rows, set_rows
from pdr.fleet_rows import FleetRows
from pdr.floor_kernels import REASONS
from pdr.floors import FloorChange, FloorElevations, FloorTracker
from pdr.frames import ImuFrame
from pdr.heading import HeadingEstimator
from pdr.heading_kernels import EPOCH_COLUMNS
from pdr.height import ALTIMETER_START, reanchor, relative_height
from pdr.pipeline_settings import PipelineSettings
from pdr.step_events import FloorEvents, StepAssembler, assemble_round
from pdr.steps import make_detector
from pdr.steps.base import TAIL_MARGIN_S
from pdr.windows import norm3

_STATES = {K.WALKING: MotionState.WALKING, K.STILL: MotionState.STILL, K.NO_MOTION: MotionState.NO_MOTION}


class FleetMember:
    """One responder of a :class:`PdrFleet`: a motion model (the ``MotionModel`` protocol of
    the service) whose per-sample work is done in the fleet's rounds."""

    __slots__ = ("fleet", "slot", "heading", "floor_tracker", "assembler", "floor_events")

    def __init__(self, fleet: PdrFleet, slot: int, start_floor: int):
        s = fleet.settings
        self.fleet, self.slot = fleet, slot
        self.heading = HeadingEstimator(s.heading)  # its compass filter and step headings; samples are the fleet's
        self.floor_tracker = FloorTracker(fleet.floors, start_floor, s.floor)
        self.assembler = StepAssembler(s)
        self.floor_events = FloorEvents()

    def __getstate__(self):
        return {k: getattr(self, k) for k in self.__slots__}

    def __setstate__(self, d) -> None:
        for k, v in d.items():
            setattr(self, k, v)
        if "rows" in vars(self.fleet):  # a fleet already restored (else its own __setstate__ attaches)
            self.floor_tracker.attach(self.fleet.rows.floor_rows(self.slot))

    def update(self, frame: ImuFrame) -> list:
        out = self.fleet.run([(self, frame)])[0]
        if isinstance(out, Exception):
            raise out
        return out

    def finish(self) -> list:
        return self.fleet.finish(self)

    def release(self) -> None:
        """Leave the fleet (:meth:`PdrFleet.release`): the responder is gone or changed model."""
        self.fleet.release(self)

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        self.fleet.anchor_floor(self, floor, t)

    @property
    def steps(self) -> int:
        """Steps emitted so far."""
        return self.assembler.count

    @property
    def floor(self) -> int:
        return self.floor_tracker.floor

    def floor_at(self, t: float) -> int:
        """The floor at time ``t`` as the barometer has it now (the last 256 changes are remembered)."""
        return self.floor_tracker.floor_at(t)

    @property
    def height(self) -> float:
        return float(self.fleet.rows.height[self.slot])

    @property
    def last_time(self) -> float:
        """Device time of the newest sample seen (s); -inf before the first."""
        return float(self.fleet.rows.mot[self.slot, K.M_TLAST])

    @property
    def state(self) -> MotionState:
        return _STATES[int(self.fleet.rows.mot[self.slot, K.M_STATE])]

    @property
    def state_since(self) -> float:
        return float(self.fleet.rows.mot[self.slot, K.M_SINCE])

    @property
    def motionless_since(self) -> float:
        """s, device time of the newest sample that was not motionless (the stillness, if any,
        began after it; the first sample's time when none moved, NaN before any). Unlike the
        motion state it is not held back by ``state_delay_s``: motionlessness needs no steps."""
        mot = self.fleet.rows.mot[self.slot]
        last, first = float(mot[K.M_LAST_MOVING]), float(mot[K.M_FIRST])
        return last if math.isfinite(last) else first


@dataclasses.dataclass(frozen=True)
class _ImuStack:
    """A round's IMU samples, every member's frame one after the other: offsets ``off`` (J + 1),
    times ``T``, specific force ``ACC`` (N, 3) and its norm ``AN``."""

    off: np.ndarray
    T: np.ndarray
    ACC: np.ndarray
    AN: np.ndarray

    @staticmethod
    def of(imu) -> "_ImuStack":
        off = np.zeros(len(imu) + 1, np.int64)
        off[1:] = np.cumsum([t.size for _, _, t, _ in imu])
        ACC = np.ascontiguousarray(np.concatenate([_floats(f.acc, 3) for _, _, _, f in imu]))
        return _ImuStack(off, np.concatenate([t for _, _, t, _ in imu]), ACC, norm3(ACC))


class PdrFleet:
    """The pipeline of many responders, run a round at a time (module docstring)."""

    def __init__(self, settings: PipelineSettings | None = None, floors: FloorElevations | None = None,
                 capacity: int = 64):
        self.settings = s = settings or PipelineSettings()
        self.floors = floors or FloorElevations.uniform(3.0, 0, 0)
        probe = HeadingEstimator(s.heading)
        ahrs = probe.ahrs
        self._ahrs_start = ahrs.kernel_state
        self._ahrs_p = ahrs.kernel_params
        self._turn = ahrs.frame_turn
        self._fwd = probe.forward_axes
        hs = s.heading
        self._bias_cfg = np.array([1.0 if hs.estimate_bias else 0.0, hs.still_window, hs.still_gyr_std,
                                   hs.still_gyr_max, hs.still_acc_std])
        self._hbuf_keep = 4 * hs.max_step_duration
        self._detector = d = make_detector(s.detector, dict(s.detector_params))
        ds = d.settings
        self._det_cfg = np.array([ds.floor, ds.relative, ds.reference_steps, ds.reference_window_s,
                                  ds.min_interval_s, ds.bout_gap_s, ds.min_bout_steps, ds.max_step_s, TAIL_MARGIN_S,
                                  ds.max_gap_s])
        if ds.reference_steps > DK.MAX_SWINGS:
            raise ValueError(f"reference_steps above {DK.MAX_SWINGS} is not supported")
        self._bout_n = max(int(ds.min_bout_steps), 1)
        self._rate_window = float(ds.rate_window_s)
        self._elev = self.floors.heights
        self._floor_p = FloorTracker(self.floors, int(self.floors.floors[0]), s.floor).kernel_params
        self._air_p = s.air.kernel_params
        self._grid_cfg = np.array([s.state_grid_s, s.state_delay_s, s.still_after_s, s.no_motion_after_s])
        self.rows = FleetRows(d.filter_sections(100.0).shape[0], self._bout_n, self._elev.shape[0], capacity)
        self.members: list[FleetMember] = []
        self._floor_work: set[int] = set()  # slots with floor changes queued or steps held behind one
        self._designs: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # rate -> (sos, zi): designed once

    def __getstate__(self) -> dict:
        d = dict(self.__dict__)
        d.pop("_designs", None)  # a cache, designed again on demand
        d.pop("_air_p", None)  # the guard's settings as numbers: made again from the settings
        return d

    def __setstate__(self, d: dict) -> None:
        if not hasattr(d["settings"], "air"):  # a snapshot from before the air guard: the default guard
            object.__setattr__(d["settings"], "air", AirGuardSettings())
        # never the pickled numbers: a snapshot from before a guard setting existed held fewer, and the
        # kernel would read past them (its settings read the new ones' defaults)
        d["_air_p"] = d["settings"].air.kernel_params
        self.__dict__.update(d)
        self._designs = {}
        self._attach()  # pickled with the fleet, the trackers' views came back as copies: views again

    def _attach(self) -> None:
        for m in self.members:  # (a service's snapshot names members by slot: they attach when they load)
            if isinstance(m, FleetMember):
                m.floor_tracker.attach(self.rows.floor_rows(m.slot))

    # ------------------------------------------------------------------ members
    def member(self, start_floor: int = 0) -> FleetMember:
        """A new responder starting on ``start_floor``."""
        R = self.rows
        slot, moved = R.take()
        if moved:
            self._attach()
        m = FleetMember(self, slot, start_floor)
        R.ahrs[slot] = self._ahrs_start
        R.bias[slot] = m.heading.bias
        R.det[slot, [DK.D_ZI_SET, DK.D_NEXT, DK.D_PEAK_ON, DK.D_NSWING, DK.D_BOUT, DK.D_NBOUT]] = [0, 1, 0, 0, 0, 0]
        R.det[slot, [DK.D_LAST_STEP, DK.D_LAST_PEAK]] = -np.inf
        R.det[slot, [DK.D_G0, DK.D_GM, DK.D_TP, DK.D_AP]] = [np.nan, 0, np.nan, np.nan]
        R.mot[slot, [K.M_LAST_MOVING, K.M_GRID_K, K.M_STATE, K.M_TLAST, K.M_JUDGED]] = [-np.inf, 1, K.STILL, -np.inf,
                                                                                      -np.inf]
        R.alt[slot] = ALTIMETER_START
        R.h0[slot] = self.floors.elevation(start_floor)
        for row, value in zip(R.floor_rows(slot), m.floor_tracker.rows()):
            row[...] = value
        m.floor_tracker.attach(R.floor_rows(slot))
        if self._detector.settings.rate_hz > 0:  # a configured rate: the filter is designed now
            R.det[slot, DK.D_RATE] = self._detector.settings.rate_hz
            self._design(slot)
        self.members.append(m)
        return m

    def release(self, m: FleetMember) -> None:
        """``m`` leaves the fleet (an expired responder): its slot goes to the next new member,
        so the fleet's memory follows the responders present, not every one ever seen."""
        if m.fleet is not self or m not in self.members:
            raise ValueError("release: not a current member of this fleet")
        self.members.remove(m)
        self._floor_work.discard(m.slot)
        if self.rows.give_back(m.slot):
            self._attach()

    # ------------------------------------------------------------------ a round
    def run(self, items: Sequence[tuple[FleetMember, ImuFrame]]) -> list:
        """One round: each member's consecutive frame -> its events, or the ``ValueError`` of
        a frame that does not come after the member's last (its state then unchanged). A
        member appears at most once per round."""
        R = self.rows
        results: list = [[] for _ in items]
        imu, pres = [], []  # (item index, member, t, frame) / (item index, member, pt, p)
        times = [_floats(f.t) for _, f in items]
        # the order check for the whole round at once: a frame's first sample after the member's last
        firsts = np.array([t[0] if t.size else np.inf for t in times])
        late = (firsts <= R.mot[np.array([m.slot for m, _ in items], np.int64), K.M_TLAST]).tolist()
        for k, (m, f) in enumerate(items):
            t = times[k]
            if late[k]:
                results[k] = ValueError(f"frame starts at {t[0]:.6f} s, not after the previous sample at "
                                        f"{R.mot[m.slot, K.M_TLAST]:.6f} s")
                continue
            if f.pressure is not None and f.pressure_t is not None and len(f.pressure):
                pres.append((k, m, _floats(f.pressure_t), _floats(f.pressure)))
            if t.size:
                imu.append((k, m, t, f))
        stack = _ImuStack.of(imu) if imu else None  # the round's IMU samples, stacked once for the guard and the IMU round
        if self.settings.air.enabled and (pres or imu):  # pressure changes no motion explains are the air's (the IMU samples feed its walking test even without pressure)
            pres = self._air_round(imu, stack, pres)
        if pres:
            self._height_round(pres)
        steps: dict[int, list] = {}
        motion: dict[int, list] = {}
        if imu:
            steps, motion = self._imu_round(imu, stack)
        for k, m, _, _ in imu:  # a frame of pressure alone answers nothing
            ev = steps.get(k)
            if ev is None and m.slot in self._floor_work:
                ev = self._release(m, [], R.mot[m.slot, K.M_TLAST] - self.settings.floor_event_hold_s)
            results[k] = merge_events(ev or [], motion.get(k, []))
        return results

    def _air_round(self, imu, stack, pres) -> list:
        """Each member's frame through its air guard (:mod:`pdr.air_guard`): the IMU samples as
        evidence, the pressure samples less the air offset (returned as ``pres`` is)."""
        order = [m.slot for _, m, _, _ in imu]
        at = {slot: i for i, slot in enumerate(order)}
        alone = [m.slot for _, m, _, _ in pres if m.slot not in at]  # pressure without IMU samples
        for slot in alone:
            at[slot] = len(order)
            order.append(slot)
        n = len(order)
        ioff = np.zeros(n + 1, np.int64)
        if stack is not None:
            ioff[:len(imu) + 1] = stack.off
        ioff[len(imu) + 1:] = ioff[len(imu)]
        TI, AN = (stack.T, stack.AN) if stack is not None else (np.empty(0), np.empty(0))
        by = {m.slot: (t, p) for _, m, t, p in pres}
        sizes = [by[slot][0].size if slot in by else 0 for slot in order]
        poff = np.zeros(n + 1, np.int64)
        poff[1:] = np.cumsum(sizes)
        PT = np.concatenate([by[slot][0] for slot in order if slot in by]) if pres else np.empty(0)
        PV = np.concatenate([by[slot][1] for slot in order if slot in by]) if pres else np.empty(0)
        PV = air_stage(np.array(order, np.int64), ioff, TI, AN, poff, PT, PV, self.rows.air, self._air_p)
        return [(k, m, t, PV[poff[at[m.slot]]:poff[at[m.slot] + 1]]) for k, m, t, _ in pres]

    def _height_round(self, pres) -> None:
        s, R = self.settings, self.rows
        slots = np.array([m.slot for _, m, _, _ in pres], np.int64)
        poff = np.zeros(len(pres) + 1, np.int64)
        poff[1:] = np.cumsum([pt.size for _, _, pt, _ in pres])
        PT = np.concatenate([pt for _, _, pt, _ in pres])
        PV = np.concatenate([p for _, _, _, p in pres])
        filt = np.full(PT.size, np.nan)
        pref = np.full(PT.size, np.nan)
        good = np.zeros(PT.size, np.bool_)
        K.altimeter_stage(slots, poff, PT, PV, R.alt, s.altimeter.tau_s, s.altimeter.reference_s, filt, pref, good)
        H = np.full(PT.size, np.nan)
        if good.any():
            H[good] = relative_height(filt[good], pref[good], s.altimeter)
        ch = np.empty((PT.size, 5))
        ch_slot = np.empty(PT.size, np.int64)
        n = K.floor_stage(slots, poff, PT, H, good, R.h0, R.height, R.fs, R.ring_t, R.ring_z, R.rr, R.known, R.learned,
                          R.pred, self._elev, self._floor_p, R.pres, ch, ch_slot)
        floors = self.floors.floors
        for i in range(n):
            m = pres[ch_slot[i]][1]
            c = FloorChange(float(ch[i, 0]), int(floors[int(ch[i, 1])]), int(floors[int(ch[i, 2])]), float(ch[i, 3]),
                            REASONS[int(ch[i, 4])] or "height")
            m.floor_tracker.record(c)
            m.floor_events.changed(c)
            self._floor_work.add(m.slot)

    def _imu_round(self, imu, stack: _ImuStack):
        s, R = self.settings, self.rows
        J = len(imu)
        slots = np.array([m.slot for _, m, _, _ in imu], np.int64)
        off, T, ACC, AN = stack.off, stack.T, stack.ACC, stack.AN
        GYR = np.ascontiguousarray(np.concatenate([_floats(f.gyr, 3) for _, _, _, f in imu]))
        has_mag = np.array([f.mag is not None for _, _, _, f in imu], np.bool_)
        if has_mag.all():
            MAG = np.ascontiguousarray(np.concatenate([_floats(f.mag, 3) for _, _, _, f in imu]))
        elif has_mag.any():
            MAG = np.ascontiguousarray(np.concatenate([
                _floats(f.mag, 3) if f.mag is not None else np.zeros((t.size, 3))
                for _, _, t, f in imu]))
        else:
            MAG = np.zeros((T.size, 3))
        first = T[off[:-1]]
        new = np.isnan(R.mot[slots, K.M_T0])
        if new.any():
            for j in np.flatnonzero(new):
                imu[j][1].heading.start(float(first[j]))
            R.mot[slots[new], K.M_T0] = first[new]
        R.mot[slots, K.M_TLAST] = T[off[1:] - 1]
        R.t_first[slots] = first
        # heading, per sample
        hs = s.heading
        ep_rows = np.empty((T.size + J, len(EPOCH_COLUMNS)))
        ep_slot = np.empty(T.size + J, np.int64)
        n_ep = K.heading_stage(slots, off, T, ACC, GYR, MAG, has_mag, AN, R.ahrs, self._ahrs_p, self._turn,
                               R.bias, R.bias_tails, self._bias_cfg, self._fwd, bool(hs.use_mag), hs.declination,
                               R.raw_last, R.turns, R.t0h, R.ep, hs.epoch, R.hbufs, R.hbases, R.hb_end, self._hbuf_keep,
                               ep_rows, ep_slot)
        if n_ep:  # closed compass epochs: each responder's filter
            which = ep_slot[:n_ep]
            bounds = np.flatnonzero(np.diff(which)) + 1
            for lo, hi in zip(np.r_[0, bounds].tolist(), np.r_[bounds, n_ep].tolist()):
                j = int(which[lo])
                heading = imu[j][1].heading
                heading.prune_history(float(first[j]))
                heading.take_epochs(ep_rows[lo:hi])
        K.motion_windows(slots, off, T, GYR, AN, R.mot, R.mot_tails, R.lms, s.motionless_window_s,
                         0.9 * s.motionless_window_s, s.motionless_acc_std, s.motionless_gyr,
                         s.motionless_pause_s)
        # step detection
        A = AN - GRAVITY
        ready = DK.detector_buffer(slots, off, T, A, R.det, R.raws, self._rate_window)
        for j in np.flatnonzero(ready):
            self._design(imu[j][1].slot)
        det_out = np.empty((T.size + J * (self._bout_n + 1) + sum(get_rows(R.raws, r).shape[0] for r in slots[ready > 0]), 6))
        det_slot = np.empty(det_out.shape[0], np.int64)
        n_det = DK.detector_stage(slots, off, T, A, ready, R.det, R.sos, R.zi, R.zi_unit, R.raws,
                                  R.det_tails, R.swings, R.bouts, self._det_cfg, det_out, det_slot)
        steps: dict[int, list] = {}
        new_off = np.zeros(J + 1, np.int64)
        if n_det:
            new_off[1:] = np.cumsum(np.bincount(det_slot[:n_det], minlength=J))
            jobs = []  # each member's headings first, then every member's steps assembled at once
            for j in np.unique(det_slot[:n_det]):
                k, m = imu[j][0], imu[j][1]
                rows = det_out[new_off[j]:new_off[j + 1]]
                jobs.append((k, m, self._headed(m, [StepDetection(*map(float, row)) for row in rows])))
            for (k, m, _), ev in zip(jobs, assemble_round([job for _, _, job in jobs])):
                steps[k] = self._release(m, ev, R.mot[m.slot, K.M_TLAST] - s.floor_event_hold_s)
        grid, delay = s.state_grid_s, s.state_delay_s
        k_hi = np.floor((R.mot[slots, K.M_TLAST] - delay + 1e-9 - R.mot[slots, K.M_T0]) / grid)
        mo = np.empty((int(np.maximum(k_hi - R.mot[slots, K.M_GRID_K] + 1, 0).sum()) + 1, 3))
        mo_slot = np.empty(mo.shape[0], np.int64)
        n_mo = K.motion_grid(slots, R.mot, R.lms, R.step_times, det_out[:n_det, 0].copy(), new_off,
                             self._grid_cfg, mo, mo_slot)
        motion: dict[int, list] = {}
        for i in range(n_mo):
            k = imu[mo_slot[i]][0]
            motion.setdefault(k, []).append(MotionEvent(t=float(mo[i, 0]), state=_STATES[int(mo[i, 1])],
                                                        since=float(mo[i, 2])))
        return steps, motion

    def _design(self, slot: int) -> None:
        R = self.rows
        rate = float(R.det[slot, DK.D_RATE])
        design = self._designs.get(rate)
        if design is None:  # the same rate, the same filter: scipy's design (~1.5 ms) once per rate
            sos = self._detector.filter_sections(rate)
            design = self._designs[rate] = (sos, signal.sosfilt_zi(sos))
            if len(self._designs) > 64:  # estimated rates vary: keep the cache small
                self._designs.pop(next(iter(self._designs)))
        R.sos[slot], R.zi_unit[slot] = design

    def _steps(self, m: FleetMember, found: list[StepDetection], horizon: float) -> list:
        """Detected steps -> their headings, lengths, dz, floors and the floor events around them."""
        return self._release(m, assemble_round([self._headed(m, found)])[0], horizon)

    def _headed(self, m: FleetMember, found: list[StepDetection]) -> tuple:
        """Detected steps -> their headings; the member's job for :func:`pdr.step_events.assemble_round`."""
        R = self.rows
        m.heading.prune_history(float(R.t_first[m.slot]))
        hd = m.heading.answer_steps(get_rows(R.hbufs, m.slot), [d.t for d in found])
        m.assembler.detected(found)
        return m.assembler, hd, get_rows(R.pres, m.slot), m.floor_tracker.floor_at

    def _release(self, m: FleetMember, steps: list, horizon: float) -> list:
        out = m.floor_events.release(steps, horizon)
        if m.floor_events.waiting:
            self._floor_work.add(m.slot)
        else:
            self._floor_work.discard(m.slot)
        return out

    # ------------------------------------------------------------------ end of stream, fixes
    def finish(self, m: FleetMember) -> list[StepEvent | MotionEvent | FloorEvent]:
        """The stream has ended: steps still inside the detector, and floor changes, are released."""
        R, r = self.rows, m.slot
        found: list[StepDetection] = []
        raw = get_rows(R.raws, r)
        if math.isnan(R.det[r, DK.D_RATE]) and raw.shape[0] >= 2 and np.ptp(raw[:, 0]) > 0:
            R.det[r, DK.D_RATE] = DK.estimate_rate(raw[:, 0].copy())
            self._design(r)
            slots = np.array([r], np.int64)
            off = np.zeros(2, np.int64)
            out = np.empty((raw.shape[0] + self._bout_n + 2, 6))
            out_slot = np.empty(out.shape[0], np.int64)
            n = DK.detector_stage(slots, off, np.empty(0), np.empty(0), np.ones(1, np.int64), R.det, R.sos,
                                  R.zi, R.zi_unit, R.raws, R.det_tails, R.swings, R.bouts, self._det_cfg, out, out_slot)
            found = [StepDetection(*map(float, row)) for row in out[:n]]
        return self._steps(m, found, math.inf)

    def anchor_floor(self, m: FleetMember, floor: int, t: float | None = None) -> None:
        """A fix says the responder was on ``floor`` at time ``t`` (default: now): re-reference
        height and floor. A fix is applied when the first step after it arrives; if the
        barometer has changed floor since ``t`` (a lift between the fix and the next step), the
        fix speaks of the floor left behind: when that was right nothing is re-referenced, when
        it was wrong the current floor is shifted by the same number of floors. When the
        barometer has since reached the fix's floor, it was only late (a landmark pressed on
        the last stairs, before the change was decided): the fix holds as it is."""
        R, r, tracker = self.rows, m.slot, m.floor_tracker
        if t is not None and tracker.floor_at(t) != tracker.floor and int(floor) != tracker.floor:
            then = tracker.floor_at(t)
            if then == floor:
                return
            floors = self.floors.floors.tolist()
            k = floors.index(tracker.floor) + floors.index(int(floor)) - floors.index(then)
            floor = floors[min(max(k, 0), len(floors) - 1)]
        h = self.floors.elevation(floor)
        before = float(R.height[r])
        R.h0[r] = h  # the altimeter reads the configured elevation from here on
        if reanchor(R.alt[r]):
            R.height[r] = h
        # the floor tracker keeps its own level frame continuous across that jump and learns
        # from the fix what it can
        tracker.anchor(floor, h, shift=h - before if math.isfinite(before) else 0.0)
        m.floor_events.superseded()
        pr = get_rows(R.pres, r)
        if pr.shape[0]:
            pr = pr.copy()
            pr[:, 1] = pr[:, 1] + (h - pr[-1, 1])
            set_rows(R.pres, r, pr)
        m.assembler.reanchor(h)
        if not m.floor_events.waiting:
            self._floor_work.discard(r)


_F8 = np.dtype(float)


def _floats(a, cols: int = 0) -> np.ndarray:
    """``np.asarray(a, float)`` as a vector, or as rows of ``cols``; an array that is so already (a
    decoded frame's) as it is: a round takes five per frame, and numpy's calls cost more than the rest."""
    if type(a) is np.ndarray and a.dtype is _F8 and (a.ndim == 1 if not cols else a.ndim == 2 and a.shape[1] == cols):
        return a
    return np.asarray(a, float).reshape((-1, cols) if cols else -1)


def merge_events(steps: list, motion: list[MotionEvent]) -> list:
    """Steps and floor events, and motion changes, in one time-ordered list (stable: a step
    at a floor change's time stays before it; a motion change after the step of its time)."""
    if not motion:
        return list(steps)
    return sorted([*steps, *motion], key=lambda e: (e.t, isinstance(e, MotionEvent)))


__all__ = ["PdrFleet", "FleetMember", "merge_events"]
