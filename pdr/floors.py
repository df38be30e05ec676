"""Which floor a responder is on, and whether a step is on stairs.

:class:`FloorElevations` is the building's configuration: integer floor numbers and their
elevations (m), uniform or not. :class:`FloorTracker` turns a height stream (for example
from :class:`pdr.height.BarometricAltimeter`) into a floor at every sample plus
:class:`FloorChange` events. :class:`StairsDetector` flags stair steps from their height
change, and :func:`stair_step_length` gives the horizontal length such a step covers.

Floor switching has two paths, both with hysteresis, on the drift-corrected height ``z``.
Between adjacent floors ``k`` and ``k+1`` (gap ``g = e_{k+1} - e_k``):

* threshold path (a Schmitt trigger): up when ``z`` passes ``e_k + (½ + m)·g``, down when
  it falls below ``e_{k+1} - (½ + m)·g`` (``m`` = ``switch_margin``), held for ``dwell_s``
  without a break. Several floors at once (a lift) are allowed. Floors passed on a
  staircase are reported while the responder passes their level, which is where they are.
* settle path: ``z`` stays within ``settle_band·g`` of another floor's elevation for
  ``settle_s``. It catches a floor whose measured height falls short of the threshold,
  e.g. a barometer that reads low or a configured floor height that is too large.

A landing halfway up a stair, with noise smaller than ``m·g``, therefore never changes the
floor. A floor height in the configuration that is off is tolerated while the measured
height of the floor reached falls less than ``0.3·g`` short of its configured elevation
(seen from the floor left) or overshoots it by less than ``0.7·g`` on the threshold path
(``m = 0.2``), and lies within ``±0.4·g`` of it on the settle path. A barometer that reads
short is the sensitive side, so when in doubt configure the lower floor height.

Drift. The tracker keeps a slowly varying offset ``b`` between the input height and the
building elevation, ``z = h - b``. Whenever ``z`` lies within ``drift_band·g`` of the
current floor's elevation the offset follows the residual with time constant ``drift_tau_s``:

    b_i = b_{i-1} + (1 - exp(-Δt_i / τ_d)) · (z_i - e_floor)

This cancels weather drift of the barometer (about 1 hPa ≈ 8 m per hour) and a floor height
that is slightly off, while the band keeps a long stop on a half-landing from dragging the
estimate. Residual error against a steady drift rate ``r`` is ``r·τ_d``: 0.3 m for 1 hPa/h
and the default 120 s. A fix that names the floor (a checkpoint) resets ``b`` through
:meth:`FloorTracker.anchor`.

Streaming: state is the floor, the offset, the starts of pending switches and the last
time; batches of any size give the same output as one batch (the recursion is compiled with numba,
like the AHRS kernels, because it is sequential by nature).
"""
from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Mapping

import numpy as np
from numba import njit


# ------------------------------------------------------------------------------------------
# Configuration of a building
# ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class FloorElevations:
    """Floor numbers and their elevations (m, any common datum), ascending with the number."""

    elevations: Mapping[int, float]

    def __post_init__(self) -> None:
        items = sorted((int(k), float(v)) for k, v in dict(self.elevations).items())
        if not items:
            raise ValueError("a building needs at least one floor")
        if any(b[1] <= a[1] for a, b in zip(items, items[1:])):
            raise ValueError(f"floor elevations must rise with the floor number: {items}")
        object.__setattr__(self, "elevations", dict(items))

    @classmethod
    def uniform(cls, floor_height_m: float, lowest: int, highest: int, ground_elevation_m: float = 0.0):
        """Floors ``lowest..highest``, floor 0 at ``ground_elevation_m``, ``floor_height_m`` apart."""
        if floor_height_m <= 0 or highest < lowest:
            raise ValueError("need floor_height_m > 0 and highest >= lowest")
        return cls({k: ground_elevation_m + k * floor_height_m for k in range(lowest, highest + 1)})

    @classmethod
    def from_config(cls, config: Mapping) -> FloorElevations:
        """From a configuration record: ``{"elevations": {floor: m, ...}}`` or
        ``{"floor_height_m": 3.0, "lowest": -2, "highest": 4, "ground_elevation_m": 0.0}``."""
        if "elevations" in config:
            return cls({int(k): float(v) for k, v in config["elevations"].items()})
        return cls.uniform(
            float(config["floor_height_m"]), int(config["lowest"]), int(config["highest"]),
            float(config.get("ground_elevation_m", 0.0)),
        )

    @property
    def floors(self) -> np.ndarray:
        return np.fromiter(self.elevations.keys(), dtype=np.int64)

    @property
    def heights(self) -> np.ndarray:
        return np.fromiter(self.elevations.values(), dtype=np.float64)

    def elevation(self, floor: int) -> float:
        try:
            return self.elevations[int(floor)]
        except KeyError:
            raise ValueError(f"floor {floor} is not configured; floors: {list(self.elevations)}") from None

    def nearest(self, height_m) -> np.ndarray:
        """The floor whose elevation is nearest to each height (no hysteresis)."""
        h = np.asarray(height_m, dtype=np.float64)
        idx = np.abs(h[..., None] - self.heights).argmin(axis=-1)
        return self.floors[idx]


# ------------------------------------------------------------------------------------------
# Floor tracking
# ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class FloorSettings:
    """Every number of the floor tracker, with its unit."""

    switch_margin: float = 0.2  # fraction of the floor gap beyond the midpoint, in [0, 0.5)
    dwell_s: float = 1.0  # s, how long the height must stay past a threshold
    settle_band: float = 0.4  # fraction of the smaller adjacent gap: "close to a floor"
    settle_s: float = 10.0  # s, how long the height must stay close to another floor
    drift_tau_s: float = 120.0  # s, time constant of the drift offset; 0 or inf disables it
    drift_band: float = 0.25  # fraction of the smaller adjacent gap around a floor where drift is learned
    max_dt: float = 5.0  # s, a longer gap between samples counts as this long

    def __post_init__(self) -> None:
        if not 0.0 <= self.switch_margin < 0.5:
            raise ValueError("switch_margin must lie in [0, 0.5)")
        if not 0.0 <= self.settle_band < 0.5 or not 0.0 <= self.drift_band < 0.5:
            raise ValueError("settle_band and drift_band must lie in [0, 0.5)")
        if self.dwell_s < 0 or self.settle_s < 0 or self.drift_tau_s < 0 or self.max_dt <= 0:
            raise ValueError("dwell_s, settle_s, drift_tau_s must not be negative; max_dt positive")


@dataclasses.dataclass(frozen=True)
class FloorChange:
    """The responder's floor changed at ``t`` (device clock, s)."""

    t: float
    floor_from: int
    floor_to: int
    elevation: float  # m, the drift-corrected height when the change was decided
    reason: str = "height"  # "height" (the tracker decided) or "anchor" (a fix said so)


@dataclasses.dataclass(frozen=True)
class FloorTrack:
    """Output of :meth:`FloorTracker.update` for one batch."""

    floor: np.ndarray  # (N,) int, floor after each sample
    elevation: np.ndarray  # (N,) m, drift-corrected height z = h - b at each sample
    changes: list[FloorChange]


@njit(cache=True)
def _track_run(t, h, state, elev, up, down, drift_hw, settle_hw, dwell, settle_s, tau, max_dt):  # pragma: no cover
    """Hysteresis, dwell and drift over one batch; returns (floor index, z) per sample.

    ``state`` (float64[6], in place): floor index, offset b, start of a pending threshold
    switch, last time, start of a pending settle switch, the floor index it settles to
    (times NaN when nothing is pending / before the first sample). ``up[k]`` is the
    height above which floor k is reached from below (``up[0] = -inf``), ``down[k]`` the
    height below which the floor falls to k from above (``down[-1] = +inf``);
    ``drift_hw[k]``/``settle_hw[k]`` are the half-widths of the drift and settle bands.
    """
    n = t.shape[0]
    nf = elev.shape[0]
    out_k = np.empty(n, dtype=np.int64)
    out_z = np.empty(n)
    k, b, pend, t_prev, pend_s, target_s = int(state[0]), state[1], state[2], state[3], state[4], int(state[5])
    for i in range(n):
        dt = 0.0 if math.isnan(t_prev) else min(max(t[i] - t_prev, 0.0), max_dt)
        t_prev = t[i]
        z = h[i] - b
        # threshold path: past the midpoint towards another floor by the margin
        c = k
        while c + 1 < nf and z > up[c + 1]:
            c += 1
        if c == k:
            while c > 0 and z < down[c - 1]:
                c -= 1
        new_k = k
        if c != k:
            if math.isnan(pend):
                pend = t[i]
            if t[i] - pend >= dwell:
                new_k = c
        else:
            pend = math.nan
        # settle path: close to another floor's elevation for settle_s
        j = np.searchsorted(elev, z)
        near = j if j < nf and (j == 0 or elev[j] - z < z - elev[j - 1]) else j - 1
        if near != k and abs(z - elev[near]) < settle_hw[near]:
            if math.isnan(pend_s) or near != target_s:
                pend_s = t[i]
                target_s = near
            if new_k == k and t[i] - pend_s >= settle_s:
                new_k = near
        else:
            pend_s = math.nan
        if new_k != k:
            k = new_k
            pend = math.nan
            pend_s = math.nan
        r = z - elev[k]
        if tau > 0.0 and abs(r) < drift_hw[k]:
            b += (1.0 - math.exp(-dt / tau)) * r
        out_k[i] = k
        out_z[i] = z
    state[0], state[1], state[2], state[3], state[4], state[5] = k, b, pend, t_prev, pend_s, target_s
    return out_k, out_z


class FloorTracker:
    """Streaming floor from height: ``track = tracker.update(t, height_m)``.

    The first height the tracker sees is taken as the elevation of ``start_floor``, so the
    input may be relative to the start (an altimeter with ``start_height_m=0``) or in the
    building's frame. Non-finite heights keep the previous floor.
    """

    def __init__(self, elevations: FloorElevations, start_floor: int, settings: FloorSettings | None = None):
        self.elevations = elevations
        self.settings = settings or FloorSettings()
        s = self.settings
        self._floors = elevations.floors
        e = elevations.heights
        self._elev = e
        gaps = np.diff(e)
        lo = 0.5 + s.switch_margin
        self._up = np.concatenate([[-np.inf], e[:-1] + lo * gaps])
        self._down = np.concatenate([e[1:] - lo * gaps, [np.inf]])
        nearest_gap = np.minimum(np.concatenate([[np.inf], gaps]), np.concatenate([gaps, [np.inf]]))
        self._drift_hw = np.where(np.isfinite(nearest_gap), s.drift_band * nearest_gap, np.inf)  # lone floor: always
        self._settle_hw = np.where(np.isfinite(nearest_gap), s.settle_band * nearest_gap, 0.0)
        self._tau = s.drift_tau_s if math.isfinite(s.drift_tau_s) else 0.0
        self._state = np.array([float(self._index(start_floor)), math.nan, math.nan, math.nan, math.nan, -1.0])
        self._last_h = math.nan
        self._history: deque[FloorChange] = deque(maxlen=256)

    def _index(self, floor: int) -> int:
        idx = np.flatnonzero(self._floors == int(floor))
        if idx.size == 0:
            raise ValueError(f"floor {floor} is not configured; floors: {self._floors.tolist()}")
        return int(idx[0])

    # -- state ------------------------------------------------------------------------
    @property
    def floor(self) -> int:
        """The current floor."""
        return int(self._floors[int(self._state[0])])

    @property
    def offset(self) -> float:
        """The offset b (m) between the input height and the building elevation (NaN before data)."""
        return float(self._state[1])

    def floor_at(self, t: float) -> int:
        """The floor at time ``t`` (the last 256 changes are remembered)."""
        floor = self.floor
        for ch in reversed(self._history):
            if t >= ch.t:
                break
            floor = ch.floor_from
        return floor

    # -- streaming --------------------------------------------------------------------
    def update(self, t, height_m) -> FloorTrack:
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        h = np.ascontiguousarray(height_m, dtype=np.float64).reshape(-1)
        if h.shape != t.shape:
            raise ValueError(f"height has {h.shape[0]} samples, t has {t.shape[0]}")
        n = t.shape[0]
        k0 = int(self._state[0])
        k_out = np.full(n, k0, dtype=np.int64)
        z_out = np.full(n, np.nan)
        good = np.flatnonzero(np.isfinite(h) & np.isfinite(t))
        if good.size:
            if math.isnan(self._state[1]):
                self._state[1] = h[good[0]] - self._elev[k0]
            s = self.settings
            k, z = _track_run(t[good], h[good], self._state, self._elev, self._up, self._down, self._drift_hw,
                              self._settle_hw, s.dwell_s, s.settle_s, self._tau, s.max_dt)
            z_out[good] = z
            if good.size == n:
                k_out = k
            else:  # a sample with a bad height keeps the floor of the sample before it
                last_good = np.maximum.accumulate(np.where(np.isfinite(z_out), np.arange(n), -1))
                k_out = np.where(last_good >= 0, k[np.searchsorted(good, np.maximum(last_good, 0))], k0)
            self._last_h = float(h[good[-1]])
        prev = np.concatenate([[k0], k_out[:-1]])
        changes = [
            FloorChange(float(t[i]), int(self._floors[prev[i]]), int(self._floors[k_out[i]]), float(z_out[i]))
            for i in np.flatnonzero(k_out != prev)
        ]
        self._history.extend(changes)
        return FloorTrack(self._floors[k_out], z_out, changes)

    def anchor(self, floor: int, height_m: float | None = None, t: float | None = None) -> FloorChange | None:
        """A fix says the responder is on ``floor`` now; ``height_m`` is the input height at
        that moment (default: the last one seen; pass the new height if the altimeter was
        re-anchored too). Returns the floor change this makes, if any."""
        k_new = self._index(floor)
        k_old = int(self._state[0])
        h = self._last_h if height_m is None else float(height_m)
        self._state[0] = k_new
        self._state[2] = self._state[4] = math.nan
        if math.isfinite(h):
            self._state[1] = h - self._elev[k_new]
            self._last_h = h
        if k_new == k_old:
            return None
        when = float(self._state[3]) if t is None else float(t)
        change = FloorChange(when, int(self._floors[k_old]), int(self._floors[k_new]), float(self._elev[k_new]), "anchor")
        self._history.append(change)
        return change


# ------------------------------------------------------------------------------------------
# Stairs
# ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StairsSettings:
    """Every number of the stairs detector, with its unit."""

    min_dz_per_step: float = 0.08  # m; half a riser (risers are 0.15-0.19 m)
    window_steps: int = 2  # steps averaged (this one and the ones before it)
    tread_m: float = 0.28  # m, horizontal going of one stair (seed 000: 0.28 m measured)
    riser_m: float = 0.17  # m, rise of one stair
    max_treads_per_step: int = 2

    def __post_init__(self) -> None:
        if self.window_steps < 1 or self.max_treads_per_step < 1:
            raise ValueError("window_steps and max_treads_per_step must be at least 1")
        if self.min_dz_per_step <= 0 or self.tread_m <= 0 or self.riser_m <= 0:
            raise ValueError("min_dz_per_step, tread_m and riser_m must be positive")


def stair_step_length(dz, settings: StairsSettings | None = None) -> np.ndarray:
    """Horizontal length (m) of a step on stairs that rose or fell by ``dz`` (m).

    A step on stairs covers whole treads: ``n = clip(round(|dz| / riser), 1, max)`` of
    them, so ``length = n · tread``. The default tread, 0.28 m, is the real stair step the
    handheld-PDR thesis measured (seed 000 §7: its Weinberg model said 0.80 m up and 0.76 m
    down); building codes put the going of a stair between about 0.25 and 0.30 m.
    """
    s = settings or StairsSettings()
    n = np.clip(np.rint(np.abs(np.asarray(dz, dtype=np.float64)) / s.riser_m), 1, s.max_treads_per_step)
    return n * s.tread_m


@dataclasses.dataclass(frozen=True)
class StairSteps:
    """Output of :meth:`StairsDetector.update` for a batch of M steps."""

    on_stairs: np.ndarray  # (M,) bool
    mean_dz: np.ndarray  # (M,) m, the window mean of dz the decision used
    length: np.ndarray  # (M,) m, horizontal length on stairs (stair_step_length); NaN off stairs


class StairsDetector:
    """Streaming per-step stairs flag: ``steps = det.update(dz)`` for a batch of steps.

    ``dz`` is each step's height change (m, since the previous step, from the altimeter).
    A step is on stairs when the mean ``dz`` of the last ``window_steps`` steps (itself
    included) reaches ``min_dz_per_step`` in magnitude: a signed mean over a few steps
    rather than one step, because the barometer's noise (a few cm per step after the
    low-pass, and the phone moving in the hand) is not much smaller than a riser. The
    pipeline then replaces the step's length by ``steps.length`` where ``on_stairs``.
    """

    def __init__(self, settings: StairsSettings | None = None):
        self.settings = settings or StairsSettings()
        self._tail = np.empty(0)  # the last window_steps - 1 step dz (fewer at the start)

    def _window_mean(self, dz: np.ndarray) -> np.ndarray:
        """Mean of ``dz`` over each step's window, with the steps kept from earlier batches."""
        w = self.settings.window_steps
        known = np.concatenate([self._tail, dz])
        padded = np.concatenate([np.zeros(w - 1 - self._tail.size), known])  # zeros add nothing
        sums = np.lib.stride_tricks.sliding_window_view(padded, w).sum(axis=1)
        count = np.minimum(np.arange(dz.size) + 1 + self._tail.size, w)
        self._tail = known[max(known.size - (w - 1), 0):] if w > 1 else np.empty(0)
        return sums / count

    def update(self, dz) -> StairSteps:
        dz = np.asarray(dz, dtype=np.float64).reshape(-1)
        mean = self._window_mean(dz)
        on = np.abs(mean) >= self.settings.min_dz_per_step
        length = np.where(on, stair_step_length(mean, self.settings), np.nan)
        return StairSteps(on, mean, length)
