"""Which floor a responder is on, and whether a step is on stairs.

:class:`FloorElevations` is the building's configuration: integer floor numbers and their
elevations (m), uniform or not. :class:`FloorTracker` turns a height stream (for example
from :class:`pdr.height.BarometricAltimeter`) into a floor at every sample plus
:class:`FloorChange` events. :class:`StairsDetector` flags stair steps from their height
change, and :func:`stair_step_length` gives the horizontal length such a step covers.

**The building's real levels are learned, the configuration is only a prior.** A configured
floor height is a guess (the IPIN museum's floor -1 is one, at 3.0 m spacing); real storeys
differ by tens of per cent, and a barometer reads heights a few per cent off (temperature).
So the tracker keeps, per floor, the barometric level ``r_f`` it has *seen* that floor at, and
predicts the levels it has not seen from the ones it has:

* **Dwell.** The walker is on a level when the drift-corrected height ``z = h − b`` stays
  within ``dwell_band_m`` (max − min) for ``dwell_window_s``: walking about a floor, standing
  on it, or a long stop on a stair landing. Stairs (≈0.15-0.3 m/s of climb) and lifts
  (≈0.3-1 m/s) are not.
* **Which floor a new dwell is on.** Its level ``z̄`` (the window mean) is matched to a floor
  already seen if within ``match_fraction`` of the local gap between predicted levels. Else it
  is a floor not seen yet:
  - between two floors already seen, the one whose level, interpolated between them in the
    proportion of the configured elevations, is nearest (a floor visited between two known
    floors);
  - beyond the floors seen, counted from the nearest seen floor ``a``: each candidate ``f`` on
    that side implies a scale ``q_f = (z̄ − r_a) / (e_f − e_a)`` of real to configured spacing,
    and the one nearest the expected scale ``α̂`` in ratio, ``min |ln(q_f / α̂)|``, wins, if
    ``q_f / α̂`` lies in ``scale_range`` (the prior: the configuration may be off by −45 % to
    +50 %). ``α̂`` is 1 until two floors have been seen, then the ratio of their seen to their
    configured separation, and the range narrows to ``learned_scale_range``. No candidate in
    range: the dwell is not on a floor (a half-landing) and nothing changes.
  The level of a newly seen floor is the running mean of its first dwell.
* **Predicted levels** of floors not seen: interpolated between seen floors (configured
  proportions), extrapolated beyond them with ``α̂``, or the configuration itself at the start.
* **Between dwells** (stairs, a lift) the floor follows the height with a Schmitt trigger on
  the predicted levels: up past ``ℓ_k + (½ + m)(ℓ_{k+1} − ℓ_k)``, down likewise, held for
  ``dwell_s`` (``m`` = ``switch_margin``), so floors passed on a staircase are reported while
  the responder passes them; several at once (a lift) are allowed. A dwell's decision
  overrides it.
* **Fixes.** :meth:`FloorTracker.anchor` (a checkpoint that names the floor) sets the floor and
  makes the current height that floor's level; a level the current dwell had taught to
  another floor is forgotten (it was that one, mislabelled). A fix given while the height is
  still changing (pressed on the last stairs) sets the floor only: the height there is not the
  level, so a floor seen before keeps its level and a floor not seen gets a *provisional* one,
  which follows the climb to its end (at most the threshold's reach), sets no scale, and is
  replaced by the first dwell on that floor (``eval floors``,
  scenario ``named_on_arrival``).

What this buys and its limit. A single-floor trip is labelled right for any real spacing
within the scale range of the configured one (the ratio rule puts the boundary between one
and two floors at ``√2``); once two floors have been seen, trips over several floors are
counted with the learned spacing. Still ambiguous, for any method without more evidence: a
*first* trip that skips floors while the configuration is far off (two floors of 2.6 m read as
one of 5.2 m against a configured 3.6 m): a fix with a floor, or a dwell on the floor passed,
settles it.

**Drift.** The tracker keeps a slowly varying offset ``b`` between the input height and the
level frame. Whenever ``z`` lies within ``drift_band`` of the local gap of the current floor's seen
level, the offset and its rate ``ḃ`` follow the residual ``e = z − r_floor`` as a critically
damped second-order loop with time constant ``τ_d`` (``drift_tau_s``)::

    b ← b + ḃ·Δt   (always),      b ← b + 2 (Δt/τ_d) e,      ḃ ← ḃ + (Δt/τ_d²) e

which cancels weather drift of the barometer (about 1 hPa ≈ 8 m per hour) without the lag
``ḃ·τ_d`` a first-order follower leaves on a steady drift. That matters here because a level
learned on a dwell is learned in the drift-corrected frame: a lag would be built into it and
grow with every new floor. ``|ḃ|`` is kept below :data:`MAX_DRIFT_RATE`.

Streaming: the state is the floor, the offset, the learned levels, the open dwell and the
samples of the dwell window; batches of any size give the same output as one batch (the
recursion is compiled with numba, like the AHRS kernels, because it is sequential by nature).
"""
from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Mapping

import numpy as np
from pdr.floor_kernels import (
    F_B, F_COUNT, F_DCNT, F_DFLOOR, F_DSUM, F_DWELL_ID, F_HEAD, F_IN_DWELL, F_K, F_PEND, F_PEND_TO, F_PROV_FROM, F_RATE, F_RING,
    F_STATE, F_TPREV, KNOWN_PROVISIONAL, MAX_DRIFT_RATE, REASONS, predict, track_run,
)


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
    """Every number of the floor tracker, with its unit (see the module docstring)."""

    switch_margin: float = 0.2  # fraction of the predicted gap beyond the midpoint, in [0, 0.5)
    dwell_s: float = 0.5  # s, how long the height must stay past a threshold between dwells (1.0 until
    # issue 27's floors: T52r02 at K = 2 reached floor 0 0.1 s after a landmark at the stairs' top)
    dwell_window_s: float = 6.0  # s, the height is steady over this long: the walker is on a level
    dwell_max_rate: float = 0.05  # m/s, largest least-squares climb rate over the window that is still "steady"
    dwell_band_m: float = 1.0  # m, and largest range (max − min) over the window
    match_fraction: float = 0.3  # a dwell within this fraction of the local gap of a seen floor's level is on it
    learn_s: float = 15.0  # s, a dwell on no floor seen yet teaches a new level only once it has lasted this long
    scale_range: tuple[float, float] = (0.55, 1.5)  # plausible real/configured spacing, relative to the expected
    drift_tau_s: float = 120.0  # s, time constant of the drift offset; 0 or inf disables it
    drift_band: float = 0.25  # fraction of the local gap around a seen floor's level where the drift is learned
    max_dt: float = 5.0  # s, a longer gap between samples counts as this long

    def __post_init__(self) -> None:
        if not 0.0 <= self.switch_margin < 0.5:
            raise ValueError("switch_margin must lie in [0, 0.5)")
        if not 0.0 < self.match_fraction < 0.5 or not 0.0 <= self.drift_band < 0.5:
            raise ValueError("match_fraction must lie in (0, 0.5) and drift_band in [0, 0.5)")
        lo, hi = self.scale_range
        if not 0.0 < lo < 1.0 < hi:
            raise ValueError(f"scale_range must be (lo, hi) with 0 < lo < 1 < hi, got {self.scale_range}")
        if self.dwell_s < 0 or self.drift_tau_s < 0 or self.max_dt <= 0:
            raise ValueError("dwell_s and drift_tau_s must not be negative; max_dt positive")
        if not (self.dwell_window_s > 0 and self.dwell_max_rate > 0 and self.dwell_band_m > 0 and self.learn_s >= 0):
            raise ValueError("dwell_window_s, dwell_max_rate and dwell_band_m must be positive, learn_s not negative")


@dataclasses.dataclass(frozen=True)
class FloorChange:
    """The responder's floor changed at ``t`` (device clock, s)."""

    t: float
    floor_from: int
    floor_to: int
    elevation: float  # m, the drift-corrected height when the change was decided
    reason: str = "height"  # "height" (passed a threshold), "dwell" (a dwell's level), "anchor" (a fix said so)


@dataclasses.dataclass(frozen=True)
class FloorTrack:
    """Output of :meth:`FloorTracker.update` for one batch."""

    floor: np.ndarray  # (N,) int, floor after each sample
    elevation: np.ndarray  # (N,) m, drift-corrected height z = h - b at each sample
    changes: list[FloorChange]


class FloorTracker:
    """Streaming floor from height: ``track = tracker.update(t, height_m)`` (module docstring).

    The first height the tracker sees is taken as the level of ``start_floor``, so the
    input may be relative to the start (an altimeter with ``start_height_m=0``) or in the
    building's frame. Non-finite heights keep the previous floor.
    """

    def __init__(self, elevations: FloorElevations, start_floor: int, settings: FloorSettings | None = None):
        self.elevations = elevations
        self.settings = s = settings or FloorSettings()
        self._floors = elevations.floors
        self._elev = elevations.heights
        nf = self._elev.shape[0]
        k0 = self._index(start_floor)
        self._state = np.full(F_STATE, np.nan)
        self._state[[F_K, F_PEND_TO, F_IN_DWELL, F_DWELL_ID, F_DSUM, F_DCNT, F_DFLOOR, F_HEAD, F_COUNT, F_RATE]] = [
            k0, -1, 0, 0, 0, 0, -1, 0, 0, 0.0]
        self._ring_t = np.zeros(F_RING)
        self._ring_z = np.zeros(F_RING)
        self._r = self._elev.copy()  # learned levels (z frame: the start floor at its configured elevation)
        self._known = np.zeros(nf, dtype=np.int64)
        self._known[k0] = 2
        self._learned_in = np.zeros(nf)
        self._pred = self._elev.copy()
        tau = s.drift_tau_s if math.isfinite(s.drift_tau_s) else 0.0
        self._params = np.array([s.switch_margin, s.dwell_s, s.dwell_window_s, s.dwell_max_rate, s.dwell_band_m,
                                 s.match_fraction, s.scale_range[0], s.scale_range[1], tau, s.max_dt, s.learn_s,
                                 s.drift_band])
        self._last_h = math.nan
        self._history: deque[FloorChange] = deque(maxlen=256)

    # -- the state a columnar engine keeps in rows of its own arrays (pdr.fleet) -------------
    ROW_NAMES = ("state", "ring_t", "ring_z", "levels", "known", "learned_in", "predicted")

    def rows(self) -> tuple[np.ndarray, ...]:
        """The arrays :func:`pdr.floor_kernels.track_run` updates, in :attr:`ROW_NAMES` order."""
        return self._state, self._ring_t, self._ring_z, self._r, self._known, self._learned_in, self._pred

    def attach(self, rows: tuple[np.ndarray, ...]) -> None:
        """Work on ``rows`` (same shapes as :meth:`rows`; e.g. views of a fleet's row) from now on."""
        self._state, self._ring_t, self._ring_z, self._r, self._known, self._learned_in, self._pred = rows

    @property
    def kernel_params(self) -> np.ndarray:
        """The settings packed for :func:`pdr.floor_kernels.track_run`."""
        return self._params

    def record(self, change: FloorChange) -> None:
        """A change decided for this tracker's state elsewhere (a columnar round): remembered for :meth:`floor_at`."""
        self._history.append(change)

    def _index(self, floor: int) -> int:
        idx = np.flatnonzero(self._floors == int(floor))
        if idx.size == 0:
            raise ValueError(f"floor {floor} is not configured; floors: {self._floors.tolist()}")
        return int(idx[0])

    # -- state ------------------------------------------------------------------------
    @property
    def floor(self) -> int:
        """The current floor."""
        return int(self._floors[int(self._state[F_K])])

    @property
    def offset(self) -> float:
        """The offset b (m) between the input height and the level frame (NaN before data)."""
        return float(self._state[F_B])

    @property
    def levels(self) -> dict[int, float]:
        """The levels (m, level frame) of the floors seen so far: on a dwell, at the start or from a fix."""
        return {int(self._floors[f]): float(self._r[f]) for f in np.flatnonzero(self._known > 0)}

    @property
    def predicted_levels(self) -> dict[int, float]:
        """The level (m, level frame) every configured floor is expected at now."""
        predict(self._r, self._known, self._elev, self._pred)
        return {int(f): float(v) for f, v in zip(self._floors, self._pred)}

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
        k0 = int(self._state[F_K])
        k_out = np.full(n, k0, dtype=np.int64)
        z_out = np.full(n, np.nan)
        why_out = np.zeros(n, dtype=np.int64)
        good = np.flatnonzero(np.isfinite(h) & np.isfinite(t))
        if good.size:
            if math.isnan(self._state[F_B]):
                self._state[F_B] = h[good[0]] - self._r[k0]
            k, z, why = track_run(t[good], h[good], self._state, self._ring_t, self._ring_z, self._r, self._known,
                                   self._learned_in, self._pred, self._elev, self._params)
            z_out[good] = z
            why_out[good] = why
            if good.size == n:
                k_out = k
            else:  # a sample with a bad height keeps the floor of the sample before it
                last_good = np.maximum.accumulate(np.where(np.isfinite(z_out), np.arange(n), -1))
                k_out = np.where(last_good >= 0, k[np.searchsorted(good, np.maximum(last_good, 0))], k0)
            self._last_h = float(h[good[-1]])
        prev = np.concatenate([[k0], k_out[:-1]])
        changes = [
            FloorChange(float(t[i]), int(self._floors[prev[i]]), int(self._floors[k_out[i]]), float(z_out[i]),
                        REASONS[int(why_out[i])] or "height")
            for i in np.flatnonzero(k_out != prev)
        ]
        self._history.extend(changes)
        return FloorTrack(self._floors[k_out], z_out, changes)

    CLIMB_WINDOW_S = 3.0  # s of heights :meth:`climbing` judges

    def climbing(self) -> bool:
        """Whether the height is changing like stairs or a lift now: the least-squares rate of the
        last :attr:`CLIMB_WINDOW_S` of the dwell window beyond twice ``dwell_max_rate`` (stairs climb
        0.15-0.3 m/s, a floor's walk stays within 0.05 m/s). Too few heights (a window just begun) say no."""
        S = self._state
        count, head = int(S[F_COUNT]), int(S[F_HEAD])
        if count < 3:
            return False
        idx = (head + np.arange(count)) % F_RING
        t, z = self._ring_t[idx], self._ring_z[idx]
        recent = t >= t[-1] - self.CLIMB_WINDOW_S
        t, z = t[recent], z[recent]
        if t.size < 3 or t[-1] - t[0] < 0.5 * self.CLIMB_WINDOW_S:
            return False
        dt = t - t.mean()
        rate = float(np.sum(dt * (z - z.mean())) / np.sum(dt * dt))  # elementwise sums: no BLAS order
        return abs(rate) > 2.0 * self.settings.dwell_max_rate

    def anchor(self, floor: int, height_m: float | None = None, t: float | None = None,
               shift: float = 0.0) -> FloorChange | None:
        """A fix says the responder is on ``floor`` now; ``height_m`` is the input height at
        that moment (default: the last one seen). ``shift`` (m) is how far the input height
        jumped at this moment without the responder moving (an altimeter re-referenced to the
        configured elevation): the level frame is kept continuous across it. The current height
        becomes that floor's level; a level the open dwell taught another floor is forgotten.
        While the height is :meth:`climbing` (a landmark pressed on the last stairs) it is not a
        level: a floor seen before keeps its level, one not seen gets a provisional level
        (:data:`~pdr.floor_kernels.KNOWN_PROVISIONAL`) that the first dwell near it replaces.
        Returns the floor change this makes, if any."""
        k_new = self._index(floor)
        k_old = int(self._state[F_K])
        h = self._last_h if height_m is None else float(height_m)
        S = self._state
        if math.isfinite(shift) and not math.isnan(S[F_B]):
            S[F_B] += shift
        S[F_K] = k_new
        S[F_PEND] = S[F_PROV_FROM] = math.nan
        wrong = (self._known == 1) & (self._learned_in == S[F_DWELL_ID]) & (np.arange(self._known.size) != k_new)
        self._known[wrong] = 0
        sure = 2
        if math.isfinite(h):
            climbing = self.climbing()
            if math.isnan(S[F_B]) or (self._known[k_new] > 0 and not climbing):
                S[F_B] = h - self._r[k_new]
                S[F_COUNT] = 0.0  # the window's heights were in the old frame: start it again
                S[F_IN_DWELL] = 0.0
            elif self._known[k_new] > 0:
                # a floor seen before, named while not on a steady level (on the stairs): the floor
                # is set and its level kept; re-referencing here put the height of the stairs at the
                # floor's level (0.8 m off with a fix 3 s early) and the next dwell then matched no floor
                sure = int(self._known[k_new]) if self._known[k_new] == KNOWN_PROVISIONAL else 2
            elif climbing:
                # not on a steady level (a landmark pressed on the last stairs): the height is a
                # provisional level, which the first dwell near it replaces; it sets no scale and
                # forgets nothing (a fix 3 s early, 0.8 m off, had made the scale 0.6 and mislabelled
                # the next floor)
                self._r[k_new] = S[F_PROV_FROM] = h - S[F_B]
                sure = KNOWN_PROVISIONAL
            else:
                self._r[k_new] = h - S[F_B]
                # levels that cannot lie where they are with this floor here were assumptions or
                # mislabels (a start floor that was not): forget them
                lo = self.settings.scale_range[0]
                sep = (self._r - self._r[k_new]) * np.sign(self._elev - self._elev[k_new])
                self._known[(sep < lo * np.abs(self._elev - self._elev[k_new])) & (np.arange(self._known.size) != k_new)] = 0
            self._last_h = h
        self._known[k_new] = sure
        if S[F_IN_DWELL] != 0.0:
            S[F_DFLOOR] = k_new
        predict(self._r, self._known, self._elev, self._pred)
        if k_new == k_old:
            return None
        when = float(S[F_TPREV]) if t is None else float(t)
        change = FloorChange(when, int(self._floors[k_old]), int(self._floors[k_new]), float(self._r[k_new]), "anchor")
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
    # the barometer's own noise per step: the threshold is at least noise_sigmas x its standard
    # deviation (from the last noise_steps steps, robustly: a flight of stairs is a steady dz, noise
    # is not) over √window_steps
    noise_sigmas: float = 1.5
    noise_steps: int = 16

    def __post_init__(self) -> None:
        if self.window_steps < 1 or self.max_treads_per_step < 1 or self.noise_steps < 2 or self.noise_sigmas < 0:
            raise ValueError("window_steps and max_treads_per_step must be at least 1, noise_steps at least 2, "
                             "noise_sigmas not negative")
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

    **A noisy barometer raises the threshold.** A phone whose barometer reads 0.05 hPa of noise
    at 1 Hz (0.4 m; seed 002 §4.1 names 0.17 hPa) gives steps dz of 0.17 m (std) on a level walk:
    ``min_dz_per_step`` then put half the steps of a walk on stairs, each 0.28 m long (the
    robustness suite's ``baro_cheap``: pooled p75 3.50 -> 5.64 m). The threshold is
    ``max(min_dz_per_step, noise_sigmas · σ / √window_steps)`` with σ the noise of dz from the
    last ``noise_steps`` steps, ``1.4826 · median|dz_k − dz_{k−1}| / √2`` (a flight is a steady
    dz, so its differences are small; the noise's are not).
    """

    _diffs: tuple = ()  # the last noise_steps |dz_k - dz_k-1| (a detector restored from before the noise test: none)
    _last_dz = float("nan")

    def __init__(self, settings: StairsSettings | None = None):
        self.settings = settings or StairsSettings()
        self._tail = np.empty(0)  # the last window_steps - 1 step dz (fewer at the start)
        self._diffs = ()
        self._last_dz = float("nan")

    def _thresholds(self, dz: np.ndarray) -> np.ndarray:
        """Each step's threshold: ``min_dz_per_step``, or the noise test's if higher (class docstring);
        the steps up to it."""
        s = self.settings
        out = np.full(dz.size, s.min_dz_per_step)
        diffs, last = list(self._diffs), self._last_dz
        scale = s.noise_sigmas * 1.4826 / (np.sqrt(2.0) * np.sqrt(s.window_steps))
        for i, d in enumerate(dz.tolist()):
            if d - d == 0.0:
                if last - last == 0.0:
                    diffs.append(abs(d - last))
                    if len(diffs) > s.noise_steps:
                        del diffs[0]
                last = d
            if len(diffs) >= 4:  # the median of at most noise_steps numbers, per step: sorted, not numpy's
                ranked, mid = sorted(diffs), len(diffs) // 2
                median = ranked[mid] if len(ranked) % 2 else (ranked[mid - 1] + ranked[mid]) / 2.0
                out[i] = max(s.min_dz_per_step, scale * median)
        self._diffs, self._last_dz = tuple(diffs), last
        return out

    def _window_mean(self, dz: np.ndarray) -> np.ndarray:
        """Mean of ``dz`` over each step's window, with the steps kept from earlier batches.

        Each window is summed left to right from 0.0 in Python floats (IEEE doubles, as numpy
        sums fewer than 8 numbers): a step or two at a time, the numpy calls cost more than the sums."""
        w = self.settings.window_steps
        if w >= 8:  # numpy sums 8 or more numbers pairwise
            known = np.concatenate([self._tail, dz])
            padded = np.concatenate([np.zeros(w - 1 - self._tail.size), known])
            sums = np.lib.stride_tricks.sliding_window_view(padded, w).sum(axis=1)
            count = np.minimum(np.arange(dz.size) + 1 + self._tail.size, w)
            self._tail = known[max(known.size - (w - 1), 0):]
            return sums / count
        tail = self._tail.tolist()
        known = tail + dz.tolist()
        padded = [0.0] * (w - 1 - len(tail)) + known  # zeros add nothing
        means = []
        for i in range(dz.size):
            acc = 0.0  # numpy's sum starts from its identity (so -0.0 + -0.0 is 0.0 there too)
            for j in range(i, i + w):
                acc += padded[j]
            means.append(acc / min(i + 1 + len(tail), w))
        self._tail = np.array(known[max(len(known) - (w - 1), 0):] if w > 1 else [], np.float64)
        return np.array(means, np.float64)

    def update(self, dz) -> StairSteps:
        dz = np.asarray(dz, dtype=np.float64).reshape(-1)
        mean = self._window_mean(dz)
        on = np.abs(mean) >= self._thresholds(dz)
        length = np.full(mean.shape, np.nan)
        if on.any():  # each element alone: the same lengths as over the whole batch
            length[on] = stair_step_length(mean[on], self.settings)
        return StairSteps(on, mean, length)
