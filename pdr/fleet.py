"""Many responders' dead reckoning at once: :class:`PdrFleet`, the columnar form of
:class:`pdr.pipeline.PdrPipeline`.

A service worker keeps hundreds of responders, each sending a frame of ten samples ten times
a second. Run one responder at a time, the cost is the Python around each stage, not the
arithmetic (issue 15: 0.4-0.6 ms per frame, for about 2 µs of compiled work). Here a **round**
— every frame a worker took, for all its responders — goes through each stage of the
pipeline once, in compiled kernels (:mod:`pdr.fleet_kernels`) over arrays of state with a
responder axis:

============================  ==========================================================
stage                          state per responder (one row each)
============================  ==========================================================
height and floor               altimeter filter, floor tracker (its ring and levels),
                               pressure history for the steps' dz
heading (per sample)           gyro-bias window, levelling AHRS, gyro-heading turns, the
                               open compass epoch, samples kept for the steps' headings
motion windows                 the trailing motionless window, the time each sample last moved
step detection                 the rate estimate's samples, band-pass sections, the detector's
                               tail, peak, recent swings, the bout
motion state                   the state grid
============================  ==========================================================

What happens a few times a second per responder — a compass epoch closing, a step, a floor
change — runs in the responder's own :class:`~pdr.pipeline.PdrPipeline` (its heading filter,
step-length, stairs and floor-event code), whose array state are views of the fleet's rows.
So the fleet computes exactly what the pipeline computes: a responder's events are the same,
bit for bit, alone in a :class:`PdrPipeline` or among a thousand in a fleet, in rounds of any
size (``tests/test_fleet.py``, on real walks and simulated ones).

The fleet takes the default algorithms (the ``decoupled`` levelling filter and the ``norm``
step detector) with any settings; :meth:`PdrFleet.supports` says whether a
:class:`~pdr.pipeline.PipelineSettings` can run here (otherwise use :class:`PdrPipeline`).

Use: ``fleet = PdrFleet(settings, floors)``, ``m = fleet.member(start_floor)`` per responder,
then ``fleet.run([(m1, frame1), (m2, frame2), ...])`` per round -> one list of events (or the
``ValueError`` that frame raised) per item. A member is also a motion model on its own
(``m.update(frame)``, ``m.finish()``, ``m.anchor_floor(...)``), a round of one.
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

import numpy as np
from numba import types
from numba.typed import List
from scipy import signal

from pdr import fleet_kernels as K
from pdr.constants import GRAVITY
from pdr.events import FloorEvent, MotionEvent, MotionState, StepDetection, StepEvent
from pdr.angles import wrap
from pdr.floors import _REASONS, FloorChange, FloorElevations
from pdr.heading import BUF_COLUMNS, StepHeadings
from pdr.height import relative_height
from pdr.pipeline import ImuFrame, PdrPipeline, PipelineSettings, _merge
from pdr.steps.base import _TAIL_MARGIN_S
from pdr.windows import norm3, spans_gap

_STATES = {K.WALKING: MotionState.WALKING, K.STILL: MotionState.STILL, K.NO_MOTION: MotionState.NO_MOTION}
_EMPTY2 = np.empty((0, 2))
HBUF_COLS = len(BUF_COLUMNS)  # the heading's per-sample columns (pdr.heading.BUF_COLUMNS)


def _list2(n: int, cols: int):
    out = List.empty_list(types.float64[:, ::1])
    for _ in range(n):
        out.append(np.empty((0, cols)))
    return out


def _list1(n: int):
    out = List.empty_list(types.float64[::1])
    for _ in range(n):
        out.append(np.empty(0))
    return out


class FleetMember:
    """One responder of a :class:`PdrFleet`: a motion model (the ``MotionModel`` protocol of
    the service) whose work is done in the fleet's rounds."""

    __slots__ = ("fleet", "slot", "pipe")

    def __init__(self, fleet: PdrFleet, slot: int, pipe: PdrPipeline):
        self.fleet, self.slot, self.pipe = fleet, slot, pipe

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
        return self.pipe._step_index

    @property
    def floor(self) -> int:
        return self.pipe._tracker.floor

    def floor_at(self, t: float) -> int:
        return self.pipe._tracker.floor_at(t)

    @property
    def height(self) -> float:
        return float(self.fleet._height[self.slot])

    @property
    def last_time(self) -> float:
        return float(self.fleet._mot[self.slot, K.M_TLAST])

    @property
    def state(self) -> MotionState:
        return _STATES[int(self.fleet._mot[self.slot, K.M_STATE])]

    @property
    def state_since(self) -> float:
        return float(self.fleet._mot[self.slot, K.M_SINCE])


class PdrFleet:
    """The pipeline of many responders, run a round at a time (module docstring)."""

    def __init__(self, settings: PipelineSettings | None = None, floors: FloorElevations | None = None,
                 capacity: int = 64):
        self.settings = s = settings or PipelineSettings()
        if not self.supports(s):
            raise ValueError(f"PdrFleet runs the decoupled levelling filter and the norm detector; got "
                             f"ahrs={s.heading.ahrs!r}, detector={s.detector!r} (use PdrPipeline)")
        self.floors = floors or FloorElevations.uniform(3.0, 0, 0)
        probe = PdrPipeline(s, self.floors, int(self.floors.floors[0]))
        h, d, tr = probe._heading, probe._detector, probe._tracker
        self._ahrs_p = h._ahrs._p
        self._turn = np.ascontiguousarray(h._ahrs._turn, float)
        self._fwd = h._fwd
        hs = s.heading
        self._bias_cfg = np.array([1.0 if hs.estimate_bias else 0.0, hs.still_window, hs.still_gyr_std,
                                   hs.still_gyr_max, hs.still_acc_std])
        self._hbuf_keep = 4 * hs.max_step_duration
        self._hist_keep = 4 * hs.max_step_duration + hs.epoch
        ds = d.settings
        self._det_cfg = np.array([ds.floor, ds.relative, ds.reference_steps, ds.reference_window_s,
                                  ds.min_interval_s, ds.bout_gap_s, ds.min_bout_steps, ds.max_step_s, _TAIL_MARGIN_S])
        if ds.reference_steps > K.MAX_SWINGS:
            raise ValueError(f"reference_steps above {K.MAX_SWINGS} is not supported by the fleet")
        self._bout_n = max(int(ds.min_bout_steps), 1)
        self._rate_window = float(ds.rate_window_s)
        self._nsec = d._design(100.0).shape[0]
        self._elev = tr._elev
        self._floor_p = tr._params
        self._grid_cfg = np.array([s.state_grid_s, s.state_delay_s, s.still_after_s, s.no_motion_after_s])
        self._n = 0
        self._cap = 0
        self.members: list[FleetMember] = []
        self._first_cap = max(int(capacity), 1)
        self._alloc(self._first_cap)
        # typed lists of per-slot buffers
        self._bias_tails = _list2(0, 5)
        self._hbufs = _list2(0, HBUF_COLS)
        self._mot_tails = _list2(0, 3)
        self._lms = _list2(0, 2)
        self._raws = _list2(0, 2)
        self._det_tails = _list2(0, 2)
        self._pres = _list2(0, 2)
        self._step_times = _list1(0)
        self._floor_work: set[int] = set()  # slots with floor changes queued or steps held behind one
        self._free: list[int] = []  # slots of released members, reused by the next new one

    # ------------------------------------------------------------------ slots
    @staticmethod
    def supports(settings: PipelineSettings) -> bool:
        """Whether ``settings`` can run in a fleet (the default algorithms, any numbers)."""
        return settings.detector == "norm" and settings.heading.ahrs == "decoupled"

    # the arrays with a row per slot and what _alloc fills a new row with
    _SLOT_FILL = {"_ahrs": 0.0, "_bias": 0.0, "_raw_last": np.nan, "_turns": 0, "_t0h": np.nan, "_ep": 0.0,
                  "_det": np.nan, "_sos": 0.0, "_zi": 0.0, "_zi_unit": 0.0, "_swings": 0.0, "_bouts": 0.0,
                  "_mot": np.nan, "_alt": np.nan, "_h0": 0.0, "_height": np.nan, "_fs": np.nan, "_ring_t": 0.0,
                  "_ring_z": 0.0, "_rr": 0.0, "_known": 0, "_learned": 0.0, "_pred": 0.0, "_t_first": np.nan}

    def _alloc(self, cap: int) -> None:
        nf = self._elev.shape[0]
        shapes = {
            "_ahrs": (K_N_STATE(), float, 0.0), "_bias": (3, float, 0.0), "_raw_last": ((), float, np.nan),
            "_turns": ((), np.int64, 0), "_t0h": ((), float, np.nan), "_ep": (8, float, 0.0),
            "_det": (K.D_STATE, float, np.nan), "_sos": ((self._nsec, 6), float, 0.0), "_zi": ((self._nsec, 2), float, 0.0),
            "_zi_unit": ((self._nsec, 2), float, 0.0), "_swings": ((K.MAX_SWINGS, 2), float, 0.0),
            "_bouts": ((self._bout_n, 6), float, 0.0), "_mot": (K.M_STATE_N, float, np.nan),
            "_alt": (6, float, np.nan), "_h0": ((), float, 0.0), "_height": ((), float, np.nan),
            "_fs": (15, float, np.nan), "_ring_t": (1024, float, 0.0), "_ring_z": (1024, float, 0.0),
            "_rr": (nf, float, 0.0), "_known": (nf, np.int64, 0), "_learned": (nf, float, 0.0), "_pred": (nf, float, 0.0),
        }
        assert set(shapes) | {"_t_first"} == set(self._SLOT_FILL), "every slot array has its fill"
        for name, (shape, dtype, fill) in shapes.items():
            shape = (cap,) + (shape if isinstance(shape, tuple) else (shape,))
            new = np.full(shape, fill, dtype=dtype)
            old = getattr(self, name, None)
            if old is not None:
                new[:self._n] = old[:self._n]
            setattr(self, name, new)
        t_first = np.full(cap, np.nan)
        if self._cap:
            t_first[:self._n] = self._t_first[:self._n]
        self._t_first = t_first
        self._cap = cap
        for m in self.members:  # the pipelines' array state are views of the rows
            self._bind(m.slot, m.pipe)

    def _bind(self, slot: int, pipe: PdrPipeline) -> None:
        pipe._altimeter._state = self._alt[slot]
        tr = pipe._tracker
        tr._state, tr._ring_t, tr._ring_z = self._fs[slot], self._ring_t[slot], self._ring_z[slot]
        tr._r, tr._known, tr._learned_in, tr._pred = self._rr[slot], self._known[slot], self._learned[slot], self._pred[slot]

    # the per-slot numba typed lists (2: rows of samples, 1: a vector) and their columns; in a
    # pickle each is one array of every slot's rows and the slots' row counts
    _TYPED_LISTS = {"_bias_tails": (2, 5), "_hbufs": (2, HBUF_COLS), "_mot_tails": (2, 3), "_lms": (2, 2), "_raws": (2, 2),
                    "_det_tails": (2, 2), "_pres": (2, 2), "_step_times": (1, 0)}

    def __getstate__(self) -> dict:
        """Picklable state (a service's snapshot): numba's typed lists packed (``pack_rows``,
        one compiled pass each, not a Python object per slot); the slot arrays up to the slots
        in use (the rest is refilled on reading)."""
        d = dict(self.__dict__)
        for k, (dim, cols) in self._TYPED_LISTS.items():
            d[k] = ("packed",) + (K.pack_rows(d[k], cols) if dim == 2 else K.pack_vectors(d[k]))
        for k in self._SLOT_FILL:
            d[k] = d[k][:self._n]
        return d

    def __setstate__(self, d: dict) -> None:
        for k, (dim, cols) in self._TYPED_LISTS.items():
            out = List.empty_list(types.float64[:, ::1] if dim == 2 else types.float64[::1])
            v = d[k]
            if isinstance(v, tuple) and v and v[0] == "packed":
                lens, rows = v[1], v[2]
                ends = np.cumsum(lens)
                v = [rows[e - n:e] for n, e in zip(lens.tolist(), ends.tolist())]
            for a in v:
                out.append(np.ascontiguousarray(a, dtype=np.float64))
            d[k] = out
        d.setdefault("_free", [])
        n, cap = d["_n"], d["_cap"]
        for k, fill in self._SLOT_FILL.items():  # back to the capacity, the free rows as _alloc fills them
            a = d[k]
            if a.shape[0] < cap:
                full = np.full((cap,) + a.shape[1:], fill, dtype=a.dtype)
                full[:n] = a[:n]
                d[k] = full
        self.__dict__.update(d)
        for m in self.members:  # pickled with the fleet, the pipelines' views came back as copies: views again
            if getattr(m, "pipe", None) is not None:  # (a service's snapshot gives members their pipelines later)
                self._bind(m.slot, m.pipe)

    def member(self, start_floor: int = 0) -> FleetMember:
        """A new responder starting on ``start_floor``."""
        reuse = bool(self._free)
        if reuse:  # a released slot: its rows are set afresh (here and below), its buffers emptied
            slot = self._free.pop()
            for name in ("_sos", "_zi", "_zi_unit", "_swings", "_bouts"):  # as _alloc fills a new row
                getattr(self, name)[slot] = 0.0
        else:
            if self._n == self._cap:
                self._alloc(2 * self._cap)
            slot = self._n
            self._n += 1
        pipe = PdrPipeline(self.settings, self.floors, start_floor)
        h, tr, alt = pipe._heading, pipe._tracker, pipe._altimeter
        self._ahrs[slot] = h._ahrs._s
        self._bias[slot] = h.bias
        self._raw_last[slot], self._turns[slot], self._t0h[slot] = np.nan, 0, np.nan
        self._ep[slot] = h._epoch_state
        self._det[slot] = np.nan
        self._det[slot, [K.D_ZI_SET, K.D_NEXT, K.D_PEAK_ON, K.D_NSWING, K.D_BOUT, K.D_NBOUT]] = [0, 1, 0, 0, 0, 0]
        self._det[slot, [K.D_LAST_STEP, K.D_LAST_PEAK]] = -np.inf
        self._mot[slot] = np.nan
        self._mot[slot, [K.M_LAST_MOVING, K.M_GRID_K, K.M_STATE, K.M_TLAST]] = [-np.inf, 1, K.STILL, -np.inf]
        self._alt[slot] = alt._state
        self._h0[slot], self._height[slot] = alt._h0, np.nan
        self._fs[slot], self._ring_t[slot], self._ring_z[slot] = tr._state, tr._ring_t, tr._ring_z
        self._rr[slot], self._known[slot], self._learned[slot], self._pred[slot] = tr._r, tr._known, tr._learned_in, tr._pred
        self._bind(slot, pipe)
        for lst, cols in ((self._bias_tails, 5), (self._hbufs, HBUF_COLS), (self._mot_tails, 3), (self._lms, 2),
                          (self._raws, 2), (self._det_tails, 2), (self._pres, 2)):
            if reuse:
                lst[slot] = np.empty((0, cols))
            else:
                K.append_rows(lst, np.empty((0, cols)))
        if reuse:
            self._step_times[slot] = np.empty(0)
        else:
            self._step_times.append(np.empty(0))
        self._t_first[slot] = np.nan
        m = FleetMember(self, slot, pipe)
        if pipe._detector.rate_hz is not None:  # a configured rate: the filter is designed now
            self._det[slot, K.D_RATE] = pipe._detector.rate_hz
            self._design(m)
        self.members.append(m)
        return m

    def release(self, m: FleetMember) -> None:
        """``m`` leaves the fleet (an expired responder): its pipeline and buffers are freed
        and its slot goes to the next new member, so the fleet's memory follows the responders
        present, not every one ever seen."""
        if m.fleet is not self or m.slot in self._free or m not in self.members:
            raise ValueError("release: not a current member of this fleet")
        self.members.remove(m)
        for lst, cols in ((self._bias_tails, 5), (self._hbufs, HBUF_COLS), (self._mot_tails, 3), (self._lms, 2),
                          (self._raws, 2), (self._det_tails, 2), (self._pres, 2)):
            lst[m.slot] = np.empty((0, cols))
        self._step_times[m.slot] = np.empty(0)
        self._floor_work.discard(m.slot)
        self._free.append(m.slot)
        self._shrink()

    def _shrink(self) -> None:
        """Free slots at the top leave the fleet (their rows back to a new row's fill, their
        buffers dropped), and the rows' capacity halves while at most a quarter is in use (not
        below the first capacity): the arrays of a crowd that came and left are given back."""
        free = set(self._free)
        top = self._n
        while top and top - 1 in free:
            top -= 1
        if top == self._n:
            return
        self._free = [k for k in self._free if k < top]
        for name, fill in self._SLOT_FILL.items():
            getattr(self, name)[top:self._n] = fill
        for lst in (self._bias_tails, self._hbufs, self._mot_tails, self._lms, self._raws, self._det_tails, self._pres,
                    self._step_times):
            for _ in range(self._n - top):
                lst.pop()
        self._n = top
        cap, least = self._cap, getattr(self, "_first_cap", 1)
        while cap // 2 >= least and self._n <= cap // 4:
            cap //= 2
        if cap != self._cap:
            self._alloc(cap)

    # ------------------------------------------------------------------ a round
    def run(self, items: Sequence[tuple[FleetMember, ImuFrame]]) -> list:
        """One round: each member's consecutive frame -> its events (``PdrPipeline.update``),
        or the ``ValueError`` the pipeline would raise for it (its state then unchanged).
        A member appears at most once per round."""
        results: list = [[] for _ in items]
        imu, pres = [], []  # (item index, member, t, acc, gyr, mag) / (item index, member, pt, p)
        for k, (m, f) in enumerate(items):
            t = np.asarray(f.t, float).reshape(-1)
            if t.size and t[0] <= self._mot[m.slot, K.M_TLAST]:
                results[k] = ValueError(f"frame starts at {t[0]:.6f} s, not after the previous sample at "
                                        f"{self._mot[m.slot, K.M_TLAST]:.6f} s")
                continue
            if f.pressure is not None and f.pressure_t is not None and len(f.pressure):
                pres.append((k, m, np.asarray(f.pressure_t, float).reshape(-1), np.asarray(f.pressure, float).reshape(-1)))
            if t.size:
                imu.append((k, m, t, f))
        if pres:
            self._height_round(pres)
        steps: dict[int, list] = {}
        motion: dict[int, list] = {}
        if imu:
            steps, motion = self._imu_round(imu)
        for k, m, _, _ in imu:  # a frame of pressure alone answers nothing (PdrPipeline.update)
            ev = steps.get(k)
            if ev is None and m.slot in self._floor_work:
                ev = self._release(m, [], self._mot[m.slot, K.M_TLAST] - self.settings.floor_event_hold_s)
            results[k] = _merge(ev or [], motion.get(k, []))
        return results

    def _height_round(self, pres) -> None:
        s = self.settings
        slots = np.array([m.slot for _, m, _, _ in pres], np.int64)
        poff = np.zeros(len(pres) + 1, np.int64)
        poff[1:] = np.cumsum([pt.size for _, _, pt, _ in pres])
        PT = np.concatenate([pt for _, _, pt, _ in pres])
        PV = np.concatenate([p for _, _, _, p in pres])
        filt = np.full(PT.size, np.nan)
        pref = np.full(PT.size, np.nan)
        good = np.zeros(PT.size, np.bool_)
        K.altimeter_stage(slots, poff, PT, PV, self._alt, s.altimeter.tau_s, s.altimeter.reference_s, filt, pref, good)
        H = np.full(PT.size, np.nan)
        if good.any():
            H[good] = relative_height(filt[good], pref[good], s.altimeter)
        ch = np.empty((PT.size, 5))
        ch_slot = np.empty(PT.size, np.int64)
        n = K.floor_stage(slots, poff, PT, H, good, self._h0, self._height, self._fs, self._ring_t, self._ring_z,
                          self._rr, self._known, self._learned, self._pred, self._elev, self._floor_p, self._pres,
                          ch, ch_slot)
        floors = self.floors.floors
        for i in range(n):
            m = pres[ch_slot[i]][1]
            c = FloorChange(float(ch[i, 0]), int(floors[int(ch[i, 1])]), int(floors[int(ch[i, 2])]), float(ch[i, 3]),
                            _REASONS[int(ch[i, 4])] or "height")
            m.pipe._tracker._history.append(c)
            m.pipe._floor_queue.append(c)
            self._floor_work.add(m.slot)

    def _imu_round(self, imu):
        s = self.settings
        J = len(imu)
        slots = np.array([m.slot for _, m, _, _ in imu], np.int64)
        sizes = np.array([t.size for _, _, t, _ in imu], np.int64)
        off = np.zeros(J + 1, np.int64)
        off[1:] = np.cumsum(sizes)
        T = np.concatenate([t for _, _, t, _ in imu])
        ACC = np.ascontiguousarray(np.concatenate([np.asarray(f.acc, float).reshape(-1, 3) for _, _, _, f in imu]))
        GYR = np.ascontiguousarray(np.concatenate([np.asarray(f.gyr, float).reshape(-1, 3) for _, _, _, f in imu]))
        has_mag = np.array([f.mag is not None for _, _, _, f in imu], np.bool_)
        if has_mag.all():
            MAG = np.ascontiguousarray(np.concatenate([np.asarray(f.mag, float).reshape(-1, 3) for _, _, _, f in imu]))
        elif has_mag.any():
            MAG = np.ascontiguousarray(np.concatenate([
                np.asarray(f.mag, float).reshape(-1, 3) if f.mag is not None else np.zeros((t.size, 3))
                for _, _, t, f in imu]))
        else:
            MAG = np.zeros((T.size, 3))
        first = T[off[:-1]]
        new = np.isnan(self._mot[slots, K.M_T0])
        if new.any():
            for j in np.flatnonzero(new):
                pipe = imu[j][1].pipe
                pipe._t0 = pipe._heading._t0 = float(first[j])
            self._mot[slots[new], K.M_T0] = first[new]
        self._mot[slots, K.M_TLAST] = T[off[1:] - 1]
        self._t_first[slots] = first
        AN = norm3(ACC)
        # heading, per sample
        hs = s.heading
        ep_rows = np.empty((T.size + J, 7))
        ep_slot = np.empty(T.size + J, np.int64)
        n_ep = K.heading_stage(slots, off, T, ACC, GYR, MAG, has_mag, AN, self._ahrs, self._ahrs_p, self._turn,
                               self._bias, self._bias_tails, self._bias_cfg, self._fwd, bool(hs.use_mag), hs.declination,
                               self._raw_last, self._turns, self._t0h, self._ep, hs.epoch, self._hbufs, self._hbuf_keep,
                               ep_rows, ep_slot)
        if n_ep:
            self._epochs(imu, first, ep_rows[:n_ep], ep_slot[:n_ep])
        K.motion_windows(slots, off, T, GYR, AN, self._mot, self._mot_tails, self._lms, s.motionless_window_s,
                         0.9 * s.motionless_window_s, s.motionless_acc_std, s.motionless_gyr)
        # step detection
        A = AN - GRAVITY
        ready = K.detector_buffer(slots, off, T, A, self._det, self._raws, self._rate_window)
        for j in np.flatnonzero(ready):
            self._design(imu[j][1])
        det_out = np.empty((T.size + J * (self._bout_n + 1) + sum(K.get_rows(self._raws, r).shape[0] for r in slots[ready > 0]), 6))
        det_slot = np.empty(det_out.shape[0], np.int64)
        n_det = K.detector_stage(slots, off, T, A, ready, self._det, self._sos, self._zi, self._zi_unit, self._raws,
                                 self._det_tails, self._swings, self._bouts, self._det_cfg, det_out, det_slot)
        steps: dict[int, list] = {}
        new_off = np.zeros(J + 1, np.int64)
        if n_det:
            new_off[1:] = np.cumsum(np.bincount(det_slot[:n_det], minlength=J))
            for j in np.unique(det_slot[:n_det]):
                k, m = imu[j][0], imu[j][1]
                rows = det_out[new_off[j]:new_off[j + 1]]
                found = [StepDetection(*map(float, row)) for row in rows]
                steps[k] = self._steps(m, found, self._mot[m.slot, K.M_TLAST] - s.floor_event_hold_s)
        grid, delay = s.state_grid_s, s.state_delay_s
        k_hi = np.floor((self._mot[slots, K.M_TLAST] - delay + 1e-9 - self._mot[slots, K.M_T0]) / grid)
        mo = np.empty((int(np.maximum(k_hi - self._mot[slots, K.M_GRID_K] + 1, 0).sum()) + 1, 3))
        mo_slot = np.empty(mo.shape[0], np.int64)
        n_mo = K.motion_grid(slots, self._mot, self._lms, self._step_times, det_out[:n_det, 0].copy(), new_off,
                             self._grid_cfg, mo, mo_slot)
        motion: dict[int, list] = {}
        for i in range(n_mo):
            k = imu[mo_slot[i]][0]
            motion.setdefault(k, []).append(MotionEvent(t=float(mo[i, 0]), state=_STATES[int(mo[i, 1])],
                                                        since=float(mo[i, 2])))
        return steps, motion

    def _epochs(self, imu, first, rows: np.ndarray, which: np.ndarray) -> None:
        """Closed compass epochs of the round (``HeadingEstimator._take_epochs``, columnar): the
        spread and the measurement sigma for all at once, then each responder's filter."""
        hs = self.settings.heading
        t_end, psi_end, cs, sn, nrm, inc_m, rate = rows.T
        dm = np.arctan2(sn, cs)
        rho = np.clip(np.hypot(cs, sn), 1e-12, 1.0)
        spread = np.sqrt(-2.0 * np.log(rho))
        bounds = np.flatnonzero(np.diff(which)) + 1
        groups = list(zip(np.r_[0, bounds].tolist(), np.r_[bounds, which.size].tolist()))
        ref_n = np.empty(which.size)
        ref_i = np.empty(which.size)
        learned_by = np.empty(which.size)
        for lo, hi in groups:
            heading = imu[int(which[lo])][1].pipe._heading
            if not (np.isfinite(heading._ref_norm) and np.isfinite(heading._ref_inc)):
                heading._learn_reference(t_end[lo:hi], nrm[lo:hi], inc_m[lo:hi],
                                         np.where(rate[lo:hi] > hs.max_rate, np.inf, spread[lo:hi]))
            ref_n[lo:hi], ref_i[lo:hi] = heading._ref_norm, heading._ref_inc
            learned_by[lo:hi] = -math.inf if heading._t0 is None else heading._t0 + hs.reference_seconds
        sig = _measurement_sigma(hs, spread, nrm, inc_m, t_end, ref_n, ref_i, learned_by)
        sig = np.where(rate > hs.max_rate, np.inf, sig)
        for lo, hi in groups:
            j = int(which[lo])
            heading = imu[j][1].pipe._heading
            self._prune_history(heading, first[j])
            for i in range(lo, hi):
                heading._kf_step(t_end[i], psi_end[i], dm[i], sig[i])

    def _design(self, m: FleetMember) -> None:
        r = m.slot
        fs = float(self._det[r, K.D_RATE])
        det = m.pipe._detector
        det._start(fs)
        self._sos[r] = det._sos
        self._zi_unit[r] = signal.sosfilt_zi(det._sos)

    def _prune_history(self, heading, t_first: float) -> None:
        """The heading filter's history leaves as ``HeadingEstimator.update`` lets it (its
        first sample's limit); a step never looks further back than the limit."""
        limit = t_first - self._hist_keep
        hist = heading._hist
        while len(hist) > 1 and hist[1][0] < limit:
            hist.popleft()

    def _steps(self, m: FleetMember, found: list[StepDetection], horizon: float) -> list:
        """Detected steps -> their headings, lengths, dz, floors and the floor events around
        them, in the member's pipeline (``PdrPipeline.update`` after the detector)."""
        pipe = m.pipe
        heading = pipe._heading
        self._prune_history(heading, self._t_first[m.slot])
        hd = _step_headings(heading, K.get_rows(self._hbufs, m.slot), [d.t for d in found])
        pipe._pending += found
        pr = K.get_rows(self._pres, m.slot)
        pipe._pres_t, pipe._pres_h = pr[:, 0], pr[:, 1]
        return self._release(m, pipe._make_steps(hd), horizon)

    def _release(self, m: FleetMember, steps: list, horizon: float) -> list:
        pipe = m.pipe
        out = pipe._release(steps, horizon)
        if pipe._floor_queue or pipe._held:
            self._floor_work.add(m.slot)
        else:
            self._floor_work.discard(m.slot)
        return out

    # ------------------------------------------------------------------ end of stream, fixes
    def finish(self, m: FleetMember) -> list[StepEvent | MotionEvent | FloorEvent]:
        """``PdrPipeline.finish``: steps still inside the detector, and floor changes, are released."""
        r = m.slot
        found: list[StepDetection] = []
        raw = K.get_rows(self._raws, r)
        if math.isnan(self._det[r, K.D_RATE]) and raw.shape[0] >= 2 and np.ptp(raw[:, 0]) > 0:
            self._det[r, K.D_RATE] = K.estimate_rate(raw[:, 0].copy())
            self._design(m)
            slots = np.array([r], np.int64)
            off = np.zeros(2, np.int64)
            out = np.empty((raw.shape[0] + self._bout_n + 2, 6))
            out_slot = np.empty(out.shape[0], np.int64)
            n = K.detector_stage(slots, off, np.empty(0), np.empty(0), np.ones(1, np.int64), self._det, self._sos,
                                 self._zi, self._zi_unit, self._raws, self._det_tails, self._swings, self._bouts,
                                 self._det_cfg, out, out_slot)
            found = [StepDetection(*map(float, row)) for row in out[:n]]
        return self._steps(m, found, math.inf)

    def anchor_floor(self, m: FleetMember, floor: int, t: float | None = None) -> None:
        """``PdrPipeline.anchor_floor`` on the member's rows."""
        pipe, r = m.pipe, m.slot
        alt = pipe._altimeter
        alt._h0, alt._height = float(self._h0[r]), float(self._height[r])
        pr = K.get_rows(self._pres, r)
        pipe._pres_t, pipe._pres_h = pr[:, 0].copy(), pr[:, 1].copy()
        pipe.anchor_floor(floor, t)
        self._h0[r], self._height[r] = alt._h0, alt._height
        K.set_rows(self._pres, r, np.ascontiguousarray(np.column_stack((pipe._pres_t, pipe._pres_h)), float).reshape(-1, 2))
        if not (pipe._floor_queue or pipe._held):
            self._floor_work.discard(r)


def _step_headings(h, buf: np.ndarray, times: list[float]) -> StepHeadings:
    """``HeadingEstimator.steps(times)`` on the samples ``buf`` (rows t, ψ, δ, |b|, I, in time
    order) kept by the fleet: the same arithmetic, step by step; the samples of a step are an
    index range (the times are sorted) instead of a mask over the buffer."""
    s = h.settings
    if not len(buf) or not times:
        return StepHeadings.concatenate([])
    bt = buf[:, 0]
    t_last = bt[-1]
    order = np.argsort(h._pending + list(times), kind="stable")
    pend = np.asarray(h._pending + list(times))[order]
    ready = pend <= t_last
    h._pending = list(pend[~ready])
    h._pending_off = [0.0] * len(h._pending)
    hist = h._hist
    hist_t = [e[0] for e in hist]
    rows = []
    for tk in pend[ready].tolist():
        t_prev = h._prev_step[0] if h._prev_step else -math.inf
        lo = max(t_prev, tk - s.max_step_duration)
        i0 = int(np.searchsorted(bt, lo, side="right"))
        i1 = int(np.searchsorted(bt, tk, side="right"))
        if i1 <= i0:  # no sample in the step: the last one at or before it
            i0 = i1 - 1
        psi_g = float(np.mean(buf[i0:i1, 1]))
        w0 = int(np.searchsorted(bt, tk - s.grip.window, side="right"))
        omega, jumped = h._grip_step(buf[w0:i1, 0], buf[w0:i1, 5], buf[w0:i1, 6], buf[w0:i1, 7])
        k = bisect.bisect_right(hist_t, tk) - 1
        _, delta, P = hist[max(k, 0)]
        if not np.isfinite(delta):  # before the first compass epoch
            delta = float(buf[i1 - 1, 2]) if np.isfinite(buf[i1 - 1, 2]) else 0.0
            P = math.pi**2
        elapsed = tk - hist[max(k, 0)][0]
        P = P + s.sigma_rw**2 * elapsed if np.isfinite(P) and np.isfinite(elapsed) else P
        dev = float(wrap(psi_g + delta))
        dd = buf[i0:i1, 2]
        okd = np.isfinite(dd)
        if okd.sum() >= 2:
            ddo = dd[okd]
            c, sn = np.cos(ddo).mean(), np.sin(ddo).mean()
            spread = math.sqrt(-2.0 * math.log(min(max(math.hypot(c, sn), 1e-12), 1.0)))
            sig_m = float(h._measurement_sigma(
                np.array([spread]), np.array([buf[i0:i1, 3][okd].mean()]), np.array([buf[i0:i1, 4][okd].mean()]),
                np.array([tk]),
            )[0])
            magh = float(wrap(psi_g + math.atan2(sn, c) + omega)) if np.isfinite(sig_m) else math.nan
        else:
            sig_m, magh = math.inf, math.nan
        if h._prev_step is None:
            dch, dsig = 0.0, math.inf
        else:
            dt = tk - h._prev_step[0]
            dch = psi_g - h._prev_step[1]
            unknown = jumped or spans_gap(bt, h._prev_step[0], tk, s.epoch)  # as HeadingEstimator._answer_steps
            dsig = math.inf if unknown else math.sqrt(s.sigma_arw**2 * dt + (s.sigma_bias * dt) ** 2 + (s.scale_error * dch) ** 2)
        h._prev_step = (tk, psi_g)
        rows.append((tk, float(wrap(dev + omega)), math.sqrt(P), float(wrap(dch)), dsig, magh, sig_m, dev, omega))
    if not rows:
        return StepHeadings.concatenate([])
    a = np.array(rows, float)
    return StepHeadings(*[a[:, i] for i in range(a.shape[1])])


def _measurement_sigma(s, spread, nrm, inc_m, t, ref_norm, ref_inc, learned_by) -> np.ndarray:
    """``HeadingEstimator._measurement_sigma`` for epochs of many responders (each with its own
    field reference and learning window): the same elementwise operations, so the same bits."""
    var = s.sigma_mag**2 + spread**2
    bad = ~np.isfinite(spread) | (spread > s.spread_gate) | ~np.isfinite(nrm)
    known = t > learned_by
    has_n = np.isfinite(ref_norm)
    if has_n.any():
        dn = np.where(has_n & (np.isfinite(s.field_norm) | known), np.abs(nrm - np.where(has_n, ref_norm, 0.0)), 0.0)
        var = np.where(has_n, var + (s.norm_weight * dn) ** 2, var)
        if np.isfinite(s.field_norm):
            bad |= has_n & (dn > s.norm_gate)
    has_i = np.isfinite(ref_inc)
    if has_i.any():
        di = np.where(has_i & (np.isfinite(s.field_inclination) | known), np.abs(inc_m - np.where(has_i, ref_inc, 0.0)), 0.0)
        var = np.where(has_i, var + (s.inclination_weight * di) ** 2, var)
        if np.isfinite(s.field_inclination):
            bad |= has_i & (di > s.inclination_gate)
    return np.where(bad, np.inf, np.sqrt(var))


def K_N_STATE() -> int:
    from pdr.ahrs._decoupled_kernel import N_STATE

    return N_STATE


__all__ = ["PdrFleet", "FleetMember"]
