"""Walkers that stream IMU batches: :class:`SimulatedWalker` (one) and :class:`WalkerFleet` (many at once).

Both are the same machine: per walker a :class:`~pdr.simulation.plan.WalkerPlan` (Python,
once per leg) and a small window of its rows held in arrays ``(fields, walkers, rows)``;
per batch, every sample of every walker finds its time row and path row by comparison
with the window (no Python loop over walkers or samples) and
:func:`~pdr.simulation.motion.evaluate` computes all of them in one numpy pass. Only
walkers whose window no longer reaches the end of the batch are replanned.

Streaming: sample ``k`` of a walker is at ``t = start_t + k / rate_hz`` and its value
depends only on ``k`` and the walker's plan, so batches of any size concatenate to one long
call, and a walker in a fleet produces exactly what it produces alone (same seed).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from pdr.simulation.motion import (
    NOISE_CHANNELS,
    NPC,
    NSEG,
    PC_PHI0,
    SEG_HI,
    SEG_LO,
    SEG_T0,
    evaluate,
)
from pdr.simulation.plan import WalkerPlan
from pdr.simulation.strides import WalkerTraits
from pdr.simulation.settings import Bounds, FloorRange, Route, WalkerSettings

DEFAULT_BOUNDS: Bounds = (0.0, 40.0, 0.0, 20.0)
DEFAULT_FLOORS: FloorRange = (0, 2)
BLOCK_SAMPLES = 4096  # samples evaluated together (all walkers' arrays of a block: 32 kB each)


@dataclasses.dataclass
class SimBatch:
    """One walker's samples: raw sensors and the truth (ENU m, rad, hPa, s on the device clock).

    ``acc`` (n, 3) m/s² specific force, ``gyr`` (n, 3) rad/s, ``mag`` (n, 3) µT, all in the
    phone's body frame (x right, y forward, z up); ``pressure`` (m,) hPa at ``pressure_t``
    (every ``WalkerSettings.pressure_every``-th sample). Truth per IMU sample: position
    ``x, y, z``, ``floor``, ``heading`` (walking direction as ENU yaw, CCW from East, in
    (-π, π]), ``step_count`` (whole steps taken since the start), ``q`` (n, 4) the phone's
    attitude, body -> ENU, scalar first (None when not computed).
    """

    responder: str
    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray
    pressure_t: np.ndarray
    pressure: np.ndarray
    t_truth: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    floor: np.ndarray
    heading: np.ndarray
    step_count: np.ndarray
    q: np.ndarray | None = None

    def __len__(self) -> int:
        return self.t.shape[0]

    @staticmethod
    def concatenate(batches: Sequence[SimBatch]) -> SimBatch:
        """Batches of one walker, in order, as one batch."""
        if not batches:
            raise ValueError("SimBatch.concatenate needs at least one batch")
        out = {}
        for f in dataclasses.fields(SimBatch):
            vals = [getattr(b, f.name) for b in batches]
            if f.name == "responder":
                out[f.name] = vals[0]
            elif any(v is None for v in vals):
                out[f.name] = None
            else:
                out[f.name] = np.concatenate(vals)
        return SimBatch(**out)


@dataclasses.dataclass
class FleetBatch:
    """The same quantities as :class:`SimBatch` for W walkers and n samples each: arrays (W, n, ...).

    ``pressure`` (W, n) is NaN where ``pressure_mask`` is False (no barometer sample there).
    """

    responders: list[str]
    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray
    pressure: np.ndarray
    pressure_mask: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    floor: np.ndarray
    heading: np.ndarray
    step_count: np.ndarray
    q: np.ndarray | None = None

    def walker(self, i: int) -> SimBatch:
        """Walker ``i``'s part as a :class:`SimBatch` (views where possible)."""
        m = self.pressure_mask[i]
        return SimBatch(
            self.responders[i], self.t[i], self.acc[i], self.gyr[i], self.mag[i], self.t[i][m], self.pressure[i][m],
            self.t[i], self.x[i], self.y[i], self.z[i], self.floor[i], self.heading[i], self.step_count[i],
            None if self.q is None else self.q[i],
        )

    def batches(self) -> list[SimBatch]:
        return [self.walker(i) for i in range(len(self.responders))]


def _last_at_or_before(v: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Per sample, the index of the last of its walker's ``starts`` (W, S; ascending, +inf padded)
    that is <= the sample's value ``v`` (W, n; ascending along each row).

    Most walkers stay in one row through a short batch, so the first and last samples decide;
    only walkers that cross a row boundary compare every sample."""
    first = (v[:, :1] >= starts).sum(axis=1) - 1
    last = (v[:, -1:] >= starts).sum(axis=1) - 1
    idx = np.repeat(first[:, None], v.shape[1], axis=1)
    cross = np.flatnonzero(first != last)
    if cross.size:
        idx[cross] = (v[cross][:, :, None] >= starts[cross][:, None, :]).sum(axis=2) - 1
    return idx


def walker_seed(seed: int, index: int) -> int:
    """The seed of walker ``index`` in a fleet seeded ``seed`` (SeedSequence: independent streams)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint64)[0])


class WalkerFleet:
    """Many walkers advanced together: ``next_arrays(n)`` -> :class:`FleetBatch`, one numpy pass.

    ``n_walkers`` random-route walkers named ``responders`` (default ``sim-000``, ...), walker i
    seeded :func:`walker_seed` ``(seed, i)``; or give ``routes`` (one per walker, None for a
    random route). All share ``settings`` and the sampling rate; ``start_t`` is a scalar or
    one device-clock start per walker. ``attitude=False`` skips the truth quaternion.
    """

    def __init__(self, n_walkers: int | None = None, settings: WalkerSettings | None = None, seed: int = 0, *,
                 routes: Sequence[Route | None] | None = None, responders: Sequence[str] | None = None,
                 bounds: Bounds = DEFAULT_BOUNDS, floors: FloorRange = DEFAULT_FLOORS, start_t=0.0,
                 attitude: bool = True, seeds: Sequence[int] | None = None):
        if routes is None:
            if n_walkers is None or n_walkers < 1:
                raise ValueError(f"WalkerFleet needs n_walkers >= 1 or routes, got n_walkers={n_walkers!r}")
            routes = [None] * n_walkers
        elif n_walkers is not None and n_walkers != len(routes):
            raise ValueError(f"n_walkers={n_walkers} but {len(routes)} routes")
        w = len(routes)
        if w < 1:
            raise ValueError("WalkerFleet needs at least one walker")
        self.settings = settings or WalkerSettings()
        self.responders = list(responders) if responders is not None else [f"sim-{i:03d}" for i in range(w)]
        if len(self.responders) != w:
            raise ValueError(f"{len(self.responders)} responder names for {w} walkers")
        self.seeds = list(seeds) if seeds is not None else [walker_seed(seed, i) for i in range(w)]
        if len(self.seeds) != w:
            raise ValueError(f"{len(self.seeds)} seeds for {w} walkers")
        start = np.broadcast_to(np.asarray(start_t, dtype=float), (w,)).copy()
        if not np.isfinite(start).all():
            raise ValueError("start_t must be finite")
        self.start_t = start
        self.attitude = attitude
        self.plans: list[WalkerPlan] = []
        traits = []
        for i in range(w):
            rng = np.random.default_rng(self.seeds[i])
            tr = WalkerTraits.draw(rng, self.settings)
            traits.append(tr)
            self.plans.append(WalkerPlan(self.settings, tr, rng, routes[i], float(start[i]), bounds, floors))
        self.traits = traits
        self._trait_rows = np.stack([tr.row for tr in traits])
        self._keys = np.array([tr.key for tr in traits], dtype=np.uint64)
        self.k = np.zeros(w, dtype=np.int64)  # index of each walker's next sample
        self._seg = np.zeros((NSEG, w, 8))
        self._pc = np.zeros((NPC, w, 8))
        self._seg[SEG_T0] = np.inf
        self._pc[PC_PHI0] = np.inf
        self._pbase = np.zeros(w, dtype=np.int64)
        self._cover = np.full(w, -np.inf)  # end time of each window
        self._edited: set[int] = set()  # walkers whose future rows changed since their window was built
        self._noise_buf: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.plans)

    # -- time ---------------------------------------------------------------------------------------
    @property
    def rate_hz(self) -> float:
        return self.settings.rate_hz

    def next_time(self, i: int) -> float:
        """Device time of walker ``i``'s next sample."""
        return float(self.start_t[i] + self.k[i] / self.settings.rate_hz)

    # -- interruptions (future samples only) ---------------------------------------------------------
    def _at(self, i: int, at: float | None) -> float:
        t_next = self.next_time(i)
        if at is None:
            return t_next
        if not (at >= t_next - 1e-12):
            raise ValueError(f"walker {self.responders[i]!r}: time {at} lies before its next sample ({t_next}); "
                             "only the future can be changed")
        return float(at)

    def collapse(self, i: int, at: float | None = None) -> None:
        """Walker ``i`` collapses at ``at`` (default: its next sample) and lies still for good."""
        self.plans[i].collapse(self._at(i, at))
        self._edited.add(i)

    def stand_still(self, i: int, seconds: float, at: float | None = None) -> None:
        """Walker ``i`` stops from ``at`` (default: its next sample), stands ``seconds`` (inf: for good),
        then walks on."""
        self.plans[i].stand_still(float(seconds), self._at(i, at))
        self._edited.add(i)

    # -- batches ------------------------------------------------------------------------------------------
    def _refill(self, i: int, t_first: float, t_last: float) -> None:
        seg, pcs, base, cover = self.plans[i].window(t_first, t_last)
        if seg.shape[0] > self._seg.shape[2] or pcs.shape[0] > self._pc.shape[2]:
            self._grow(max(seg.shape[0], self._seg.shape[2]), max(pcs.shape[0], self._pc.shape[2]))
        self._seg[:, i, : seg.shape[0]] = seg.T
        self._seg[:, i, seg.shape[0]:] = 0.0
        self._seg[SEG_T0, i, seg.shape[0]:] = np.inf
        self._pc[:, i, : pcs.shape[0]] = pcs.T
        self._pc[:, i, pcs.shape[0]:] = 0.0
        self._pc[PC_PHI0, i, pcs.shape[0]:] = np.inf
        self._pbase[i] = base
        self._cover[i] = cover

    def _grow(self, rows: int, pieces: int) -> None:
        """Room for more rows per window (a walker with many short legs ahead)."""
        if rows > self._seg.shape[2]:
            rows = max(rows, 2 * self._seg.shape[2])
        if pieces > self._pc.shape[2]:
            pieces = max(pieces, 2 * self._pc.shape[2])
        seg = np.zeros((NSEG, len(self), rows))
        seg[SEG_T0] = np.inf
        seg[:, :, : self._seg.shape[2]] = self._seg
        pc = np.zeros((NPC, len(self), pieces))
        pc[PC_PHI0] = np.inf
        pc[:, :, : self._pc.shape[2]] = self._pc
        self._seg, self._pc = seg, pc

    def next_arrays(self, n: int) -> FleetBatch:
        """The next ``n`` samples of every walker, as arrays (W, n, ...)."""
        if n < 1:
            raise ValueError(f"a batch needs n >= 1 samples, got {n}")
        s = self.settings
        w = len(self)
        imu = np.empty((w, n, 3, 3))
        res = {name: np.empty((w, n)) for name in ("pressure", "x", "y", "z", "heading", "phase")}
        q = np.empty((w, n, 4)) if self.attitude else None
        # blocks of at most BLOCK_SAMPLES samples keep every temporary small (cache-resident, and
        # below the allocation size whose fresh pages the kernel must fault in)
        n_step = min(n, BLOCK_SAMPLES)
        w_step = max(1, BLOCK_SAMPLES // n_step)
        for c0 in range(0, n, n_step):
            c1 = min(n, c0 + n_step)
            k = self.k[:, None] + np.arange(c0, c1)
            t = self.start_t[:, None] + k / s.rate_hz
            stale = self._cover <= t[:, -1]
            for i in np.flatnonzero(stale):
                self._refill(int(i), float(t[i, 0]), float(t[i, -1]))
            for i in self._edited - set(np.flatnonzero(stale).tolist()):
                self._refill(i, float(t[i, 0]), float(t[i, -1]))
            self._edited.clear()
            for w0 in range(0, w, w_step):
                w1 = min(w, w0 + w_step)
                out = {name: a[w0:w1, c0:c1] for name, a in res.items()}
                out["imu"] = imu[w0:w1, c0:c1]
                if q is not None:
                    out["q"] = q[w0:w1, c0:c1]
                out["noise"] = self._scratch(w1 - w0, c1 - c0)
                self._evaluate(w0, w1, t[w0:w1], k[w0:w1], out)
        self.k += n
        return FleetBatch(
            self.responders, self.start_t[:, None] + (self.k[:, None] - n + np.arange(n)) / s.rate_hz,
            imu[:, :, 0], imu[:, :, 1], imu[:, :, 2], res["pressure"], ~np.isnan(res["pressure"]),
            res["x"], res["y"], res["z"], np.rint(res["z"] / s.floor_height_m).astype(np.int64), res["heading"],
            np.floor(res["phase"] + 1e-9).astype(np.int64), q,
        )

    def _scratch(self, w: int, n: int) -> np.ndarray:
        """A reused noise buffer (2, w, n, NOISE_CHANNELS), contiguous: one allocation for all blocks."""
        size = 2 * w * n * NOISE_CHANNELS
        if self._noise_buf is None or self._noise_buf.size < size:
            self._noise_buf = np.empty(size)
        return self._noise_buf[:size].reshape(2, w, n, NOISE_CHANNELS)

    def _evaluate(self, w0: int, w1: int, t: np.ndarray, k: np.ndarray, out: dict) -> None:
        """Walkers ``w0:w1`` at samples ``t``, ``k`` (w1 - w0, n) into ``out``."""
        seg_tab, pc_tab = self._seg[:, w0:w1], self._pc[:, w0:w1]
        w, rows, pieces = w1 - w0, seg_tab.shape[2], pc_tab.shape[2]
        # each sample's time row: the last row starting at or before it
        si = _last_at_or_before(t, seg_tab[SEG_T0])
        seg = np.take(seg_tab.reshape(NSEG, -1), si + (np.arange(w) * rows)[:, None], axis=1)
        pbase = self._pbase[w0:w1, None]
        lo = seg[SEG_LO].astype(np.int64) - pbase
        hi = seg[SEG_HI].astype(np.int64) - pbase

        def path_rows(phi):  # each sample's path row: the last starting at or before its phase, within its time row's range
            pi = np.clip(_last_at_or_before(phi, pc_tab[PC_PHI0]), lo, hi)
            return np.take(pc_tab.reshape(NPC, -1), pi + (np.arange(w) * pieces)[:, None], axis=1)

        evaluate(t, k, seg, path_rows, self._trait_rows[w0:w1], self._keys[w0:w1], self.settings, out)

    def next_batches(self, n: int) -> list[SimBatch]:
        """The next ``n`` samples of every walker, one :class:`SimBatch` each."""
        return self.next_arrays(n).batches()


class SimulatedWalker:
    """One simulated responder: ``next_batch(n)`` streams its raw IMU and barometer with the truth.

    ``route`` None walks an endless random route inside ``bounds`` (xmin, xmax, ymin, ymax;
    ENU m) over ``floors`` (lowest, highest). ``collapse_at`` (device time) schedules a
    collapse: the walker stops dead, its phone tips over and then lies still with only sensor
    noise (man-down). A fleet walker with the same seed gives identical samples.
    """

    def __init__(self, responder: str, route: Route | None = None, settings: WalkerSettings | None = None,
                 rng_seed: int = 0, start_t: float = 0.0, bounds: Bounds = DEFAULT_BOUNDS,
                 floors: FloorRange = DEFAULT_FLOORS, collapse_at: float | None = None, attitude: bool = True):
        self._fleet = WalkerFleet(routes=[route], settings=settings, responders=[responder], bounds=bounds,
                                  floors=floors, start_t=start_t, attitude=attitude, seeds=[rng_seed])
        if collapse_at is not None:
            self.collapse(collapse_at)

    @property
    def responder(self) -> str:
        return self._fleet.responders[0]

    @property
    def settings(self) -> WalkerSettings:
        return self._fleet.settings

    @property
    def traits(self) -> WalkerTraits:
        """This walker's cadence (Hz), step length (m), oscillations, gyro bias (``traits.row[8:11]``)."""
        return self._fleet.traits[0]

    @property
    def gyro_bias(self) -> np.ndarray:
        return self.traits.row[8:11].copy()

    @property
    def next_t(self) -> float:
        """Device time of the next sample."""
        return self._fleet.next_time(0)

    def next_batch(self, n: int) -> SimBatch:
        """The next ``n`` samples."""
        return self._fleet.next_arrays(n).walker(0)

    def stand_still(self, seconds: float, at: float | None = None) -> None:
        """Stop from ``at`` (default: the next sample) within about a step, stand ``seconds``
        (``math.inf``: for good, upright, motionless but for sensor noise), then walk on."""
        self._fleet.stand_still(0, seconds, at)

    def collapse(self, at: float | None = None) -> None:
        """Collapse at ``at`` (default: the next sample): stop dead, tip over, lie still for good."""
        self._fleet.collapse(0, at)


def simulate_walk(route: Route | None = None, settings: WalkerSettings | None = None, seconds: float = 60.0,
                  seed: int = 0, **walker_options) -> SimBatch:
    """``seconds`` of one walker in one call (``walker_options`` as for :class:`SimulatedWalker`)."""
    settings = settings or WalkerSettings()
    n = int(round(seconds * settings.rate_hz))
    if n < 1:
        raise ValueError(f"seconds={seconds} gives no sample at {settings.rate_hz} Hz")
    return SimulatedWalker("sim", route, settings, seed, **walker_options).next_batch(n)
