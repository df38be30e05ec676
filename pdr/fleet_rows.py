"""The state of every responder of a :class:`pdr.fleet.PdrFleet`: arrays with a row per slot,
and per-slot buffers whose length follows the data (numba typed lists of arrays).

=====================  ===================================================================
rows                   what they hold (one row per responder)
=====================  ===================================================================
``ahrs``, ``bias``     the levelling filter's state, the gyro bias (``bias_tails``: the
                       still window's samples)
``raw_last``,          the gyro heading's unwrapping, the first sample of the heading
``turns``, ``t0h``,    stream, the open compass epoch (``hbufs``: the samples kept for the
``ep``                 steps' headings, columns :data:`pdr.heading.BUF_COLUMNS`)
``det``, ``sos``,      the step detector: its scalars (:mod:`pdr.fleet_kernels` ``D_*``), its
``zi``, ``zi_unit``,   band-pass and filter state, recent swings and the bout (``raws``:
``swings``, ``bouts``  samples before the rate is known; ``det_tails``: the filtered tail)
``mot``                the motion state's scalars (``M_*``; ``mot_tails``: the motionless
                       window, ``lms``: when each recent sample last moved; ``step_times``)
``alt``, ``h0``,       the altimeter (:data:`pdr.height.ALTIMETER_START` layout), its
``height``             reference height and last height (``pres``: recent (t, height))
``fs`` ... ``pred``    the floor tracker (:meth:`pdr.floors.FloorTracker.rows`)
``t_first``            the first sample time of the responder's frame in the current round
``air``                the air guard (:mod:`pdr.air_guard`, ``A_*``)
=====================  ===================================================================
"""
from __future__ import annotations

import numpy as np
from numba import types
from numba.typed import List

from pdr import detector_kernels as DK
from pdr import fleet_buffers as B
from pdr import fleet_kernels as K
from pdr.ahrs._decoupled_kernel import N_STATE as AHRS_STATE
from pdr.air_guard import A_STATE, AIR_START
from pdr.floor_kernels import F_RING, F_STATE
from pdr.heading import BUF_COLUMNS
from pdr.heading_kernels import EPOCH_STATE

HBUF_COLS = len(BUF_COLUMNS)
# the per-slot buffers: (1: a vector, 2: rows of samples, their columns)
TYPED_LISTS = {"bias_tails": (2, 5), "hbufs": (2, HBUF_COLS), "mot_tails": (2, 3), "lms": (2, 2), "raws": (2, 2),
               "det_tails": (2, 2), "pres": (2, 2), "step_times": (1, 0), "hbases": (2, HBUF_COLS)}
# hbufs[r] is a view of hbases[r] ending at row hb_end[r] (pdr.fleet_buffers.kept_with_room): room
# for the next frames' samples; a snapshot keeps the views' rows only (the bases start again)


def _empty(dim: int, cols: int) -> np.ndarray:
    return np.empty((0, cols)) if dim == 2 else np.empty(0)


class FleetRows:
    """Rows for ``capacity`` responders, grown and shrunk as they come and go."""

    def __init__(self, n_sections: int, bout_steps: int, n_floors: int, capacity: int = 64):
        # name -> (shape of one row, dtype, what a fresh row holds); plain values: pickled in a snapshot
        self.layout = {
            "ahrs": ((AHRS_STATE,), "f8", 0.0), "bias": ((3,), "f8", 0.0), "raw_last": ((), "f8", np.nan),
            "turns": ((), "i8", 0), "t0h": ((), "f8", np.nan), "ep": ((EPOCH_STATE,), "f8", 0.0),
            "det": ((DK.D_STATE,), "f8", np.nan), "sos": ((n_sections, 6), "f8", 0.0),
            "zi": ((n_sections, 2), "f8", 0.0), "zi_unit": ((n_sections, 2), "f8", 0.0),
            "swings": ((DK.MAX_SWINGS, 2), "f8", 0.0), "bouts": ((bout_steps, 6), "f8", 0.0),
            "mot": ((K.M_STATE_N,), "f8", np.nan), "alt": ((6,), "f8", np.nan), "h0": ((), "f8", 0.0),
            "height": ((), "f8", np.nan), "fs": ((F_STATE,), "f8", np.nan), "ring_t": ((F_RING,), "f8", 0.0),
            "ring_z": ((F_RING,), "f8", 0.0), "rr": ((n_floors,), "f8", 0.0), "known": ((n_floors,), "i8", 0),
            "learned": ((n_floors,), "f8", 0.0), "pred": ((n_floors,), "f8", 0.0), "t_first": ((), "f8", np.nan),
            "hb_end": ((), "i8", -1), "air": ((A_STATE,), "f8", AIR_START),
        }
        self.n = 0  # slots in use or free below the top
        self.cap = 0
        self.first_cap = max(int(capacity), 1)
        self.free: list[int] = []  # slots given back, reused by the next new responder
        self._alloc(self.first_cap)
        for name, (dim, _) in TYPED_LISTS.items():
            setattr(self, name, List.empty_list(types.float64[:, ::1] if dim == 2 else types.float64[::1]))

    def _alloc(self, cap: int) -> None:
        for name, (shape, dtype, fill) in self.layout.items():
            new = np.full((cap,) + shape, fill, dtype=dtype)
            old = getattr(self, name, None)
            if old is not None:
                new[:self.n] = old[:self.n]
            setattr(self, name, new)
        self.cap = cap

    def floor_rows(self, slot: int) -> tuple[np.ndarray, ...]:
        """Views of the floor tracker's rows (the order of :meth:`pdr.floors.FloorTracker.rows`)."""
        return (self.fs[slot], self.ring_t[slot], self.ring_z[slot], self.rr[slot], self.known[slot],
                self.learned[slot], self.pred[slot])

    def take(self) -> tuple[int, bool]:
        """A slot for a new responder, its rows fresh and its buffers empty; and whether the
        arrays moved (their views must be taken again)."""
        moved = False
        if self.free:
            slot = self.free.pop()
            for name, (_, _, fill) in self.layout.items():
                getattr(self, name)[slot] = fill
            for name, (dim, cols) in TYPED_LISTS.items():
                getattr(self, name)[slot] = _empty(dim, cols)
            return slot, moved
        if self.n == self.cap:
            self._alloc(2 * self.cap)
            moved = True
        slot = self.n
        self.n += 1
        for name, (dim, cols) in TYPED_LISTS.items():
            lst = getattr(self, name)
            if dim == 2:
                B.append_rows(lst, _empty(dim, cols))
            else:
                lst.append(_empty(dim, cols))
        return slot, moved

    def give_back(self, slot: int) -> bool:
        """The responder of ``slot`` left: its buffers are dropped and the slot reused. Free
        slots at the top leave, and the capacity halves while at most a quarter is in use
        (not below the first capacity): the arrays of a crowd that came and left are given
        back. Returns whether the arrays moved."""
        for name, (dim, cols) in TYPED_LISTS.items():
            getattr(self, name)[slot] = _empty(dim, cols)
        self.free.append(slot)
        free = set(self.free)
        top = self.n
        while top and top - 1 in free:
            top -= 1
        if top == self.n:
            return False
        self.free = [k for k in self.free if k < top]
        for name, (_, _, fill) in self.layout.items():
            getattr(self, name)[top:self.n] = fill
        for name in TYPED_LISTS:
            lst = getattr(self, name)
            for _ in range(self.n - top):
                lst.pop()
        self.n = top
        cap = self.cap
        while cap // 2 >= self.first_cap and self.n <= cap // 4:
            cap //= 2
        if cap == self.cap:
            return False
        self._alloc(cap)
        return True

    def __getstate__(self) -> dict:
        """Picklable (a service's snapshot): the typed lists packed (one compiled pass each,
        not a Python object per slot), the rows up to the slots in use."""
        d = dict(self.__dict__)
        for k, (dim, cols) in TYPED_LISTS.items():
            d[k] = B.pack_rows(d[k], cols) if dim == 2 else B.pack_vectors(d[k])
        for k in self.layout:
            d[k] = d[k][:self.n]
        d["hbases"] = (np.zeros(len(self.hbases), np.int64), np.empty((0, HBUF_COLS)))  # rows to come, not state
        d["hb_end"] = np.full(self.n, -1, np.int64)
        return d

    def __setstate__(self, d: dict) -> None:
        if "hb_end" not in d["layout"]:  # a snapshot from before the bases: none yet
            d["layout"]["hb_end"] = ((), "i8", -1)
            d["hb_end"] = np.full(d["n"], -1, np.int64)
            d["hbases"] = (np.zeros(len(d["hbufs"][0]), np.int64), np.empty((0, HBUF_COLS)))
        if "air" not in d["layout"]:  # a snapshot from before the air guard: each guard starts afresh
            d["layout"]["air"] = ((A_STATE,), "f8", AIR_START)
            d["air"] = np.full((d["n"], A_STATE), AIR_START)
        air_shape, air_type, _ = d["layout"]["air"]
        if air_shape[0] < A_STATE:  # a snapshot from before the guard's later fields: they start as a new guard's
            d["layout"]["air"] = ((A_STATE,), air_type, AIR_START)
            d["air"] = np.concatenate([d["air"], np.tile(np.array(AIR_START[air_shape[0]:]), (d["air"].shape[0], 1))],
                                      axis=1)
        fs_shape, fs_type, fs_fill = d["layout"]["fs"]
        if fs_shape[0] < F_STATE:  # a snapshot from before the floor tracker's later fields: they start empty
            d["layout"]["fs"] = ((F_STATE,), fs_type, fs_fill)
            d["fs"] = np.concatenate([d["fs"], np.full((d["fs"].shape[0], F_STATE - fs_shape[0]), np.nan)], axis=1)
        ep_shape, ep_type, ep_fill = d["layout"]["ep"]
        if ep_shape[0] < EPOCH_STATE:  # a snapshot from before the epochs summed ‖f‖: the open epoch's sums of it start at 0
            d["layout"]["ep"] = ((EPOCH_STATE,), ep_type, ep_fill)
            d["ep"] = np.concatenate([d["ep"], np.zeros((d["ep"].shape[0], EPOCH_STATE - ep_shape[0]))], axis=1)
        for k, (dim, _) in TYPED_LISTS.items():
            out = List.empty_list(types.float64[:, ::1] if dim == 2 else types.float64[::1])
            lens, rows = d[k]
            ends = np.cumsum(lens)
            for n, e in zip(lens.tolist(), ends.tolist()):
                out.append(np.ascontiguousarray(rows[e - n:e], dtype=np.float64))
            d[k] = out
        n, cap = d["n"], d["cap"]
        for k, (_, _, fill) in d["layout"].items():  # back to the capacity, the free rows fresh
            a = d[k]
            full = np.full((cap,) + a.shape[1:], fill, dtype=a.dtype)
            full[:n] = a[:n]
            d[k] = full
        self.__dict__.update(d)


__all__ = ["FleetRows", "TYPED_LISTS", "HBUF_COLS"]
