"""Relative height from a barometer: :class:`BarometricAltimeter`.

Pipeline per pressure sample ``p_i`` (hPa) at device time ``t_i`` (s):

1. **Reference pressure** ``p_ref``: the mean of the raw samples in the first
   ``reference_s`` seconds (smartphone thesis, seed 002 §2.9: the mean of the first 15
   samples, about 2.7 s at 5.5 Hz). While that window is still filling, the running mean of
   the samples seen so far stands in, so every output depends only on samples up to it.
2. **Causal low-pass**: a first-order exponential smoother on the real time step,

       p̄_i = p̄_{i-1} + (1 - exp(-Δt_i / τ)) · (p_i - p̄_{i-1}),   Δt_i clipped below at 0

   which stays correct when samples come at an irregular rate (phones: 5-25 Hz, jittery)
   or interpolated onto the IMU clock by :meth:`pdr.recording.Recording.imu_samples`
   (100 Hz). Its delay is about τ; white noise of variance σ² sampled every Δt leaves
   about σ²·Δt/(2τ). After a gap much longer than τ the filter simply restarts from the
   new sample. The default τ = 2 s suits both a noisy barometer (0.17 hPa raw in seed 002
   §4.1) and the IPIN 2023 phones (0.005 hPa white noise, 0.015-0.03 hPa of wander while
   walking on one floor): on the latter the height then varies by 0.07-0.17 m (std) on a
   level floor and by about 0.03 m (std) over one step, while a floor change is still
   seen within 2-3 s of arriving.
3. **Height** ``h_i = h_0 + H(p̄_i; p_ref)`` with one of three formulas (``formula``):

   * ``"linear"`` — seed 002 §2.9 eq. 35: ``H = k (p_ref - p)`` with the "barometric step"
     ``k = 8 m/hPa``. That number is the gradient ``R·T/(g·M·p)`` at 0 °C and 1013 hPa
     (7.89 m/hPa); at 15 °C it is 8.32 m/hPa and at 20 °C and 980 hPa 8.76 m/hPa, so the
     linear rule reads heights about 9 % short in a warm building a few hundred metres up.
   * ``"hypsometric"`` (default) — the troposphere layer of the standard atmosphere (U.S.
     Standard Atmosphere 1976 / ISO 2533:1975, constant lapse rate ``L``) between the
     reference level, at temperature ``T``, and the sample::

         H = (T / L) · (1 - (p / p_ref)^(R·L / (g·M)))      R·L/(g·M) = 0.190267

   * ``"isothermal"`` — the same atmosphere with ``L → 0``::

         H = (R·T / (g·M)) · ln(p_ref / p)

   Constants (USSA 1976): ``R = 8.314462618 J/(mol·K)``, ``M = 0.0289644 kg/mol``,
   ``g = 9.80665 m/s²``, ``L = 0.0065 K/m``; ``T`` is ``temperature_k`` (288.15 K, the
   standard sea-level value, by default; set the indoor air temperature when known). The
   hypsometric and isothermal forms differ by about ``L·h²/(2T)``: 1 mm over 10 m, 3 cm
   over 50 m; the temperature matters more (1 % of the height per 3 K).

Drift. Weather moves the pressure by about 1 hPa/hour (up to 13 hPa/day, seed 002 §3), that
is some 8 m/hour, so the height is only good for minutes on its own. Two remedies, kept
separate on purpose:

* :meth:`BarometricAltimeter.anchor` re-references the altimeter: the current filtered
  pressure becomes ``p_ref`` and the current height becomes the given one. The fusion calls
  it when a fix says where the responder is in height (a checkpoint on a known floor).
* :class:`pdr.floors.FloorTracker` estimates the slow offset between this height and the
  elevation of the floor the responder is on, while they are near it (no fix needed).

Streaming: ``update(t, p)`` returns the height at every input sample; the state is the
filter value, the last time and the reference, so a recording fed in batches of any size
gives bit-for-bit the same heights as one batch.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np
from numba import njit

from pdr.constants import GRAVITY

# U.S. Standard Atmosphere 1976 constants
R_GAS = 8.314462618  # J/(mol·K), universal gas constant
M_AIR = 0.0289644  # kg/mol, molar mass of dry air
G0 = GRAVITY  # m/s², standard gravity
LAPSE_RATE = 0.0065  # K/m, troposphere temperature lapse rate
T_STANDARD = 288.15  # K, sea-level standard temperature
P_STANDARD = 1013.25  # hPa, sea-level standard pressure
HYPSOMETRIC_EXPONENT = R_GAS * LAPSE_RATE / (G0 * M_AIR)  # 0.190267, dimensionless

# Seed 002 §2.9: the "barometric step" of the smartphone thesis
METRES_PER_HPA = 8.0

Formula = Literal["hypsometric", "isothermal", "linear"]
FORMULAS: tuple[str, ...] = ("hypsometric", "isothermal", "linear")


@dataclasses.dataclass(frozen=True)
class AltimeterSettings:
    """Every number of the altimeter, with its unit."""

    formula: str = "hypsometric"  # one of FORMULAS
    temperature_k: float = T_STANDARD  # K, air temperature at the reference level
    metres_per_hpa: float = METRES_PER_HPA  # m/hPa, for formula="linear" only
    reference_s: float = 2.5  # s, the first samples averaged into the reference pressure
    tau_s: float = 2.0  # s, time constant of the low-pass
    history_s: float = 30.0  # s, output kept for height_at() (step dz in the pipeline)

    def __post_init__(self) -> None:
        if self.formula not in FORMULAS:
            raise ValueError(f"unknown height formula {self.formula!r}; choose one of {', '.join(FORMULAS)}")
        if self.temperature_k <= 0 or self.metres_per_hpa <= 0:
            raise ValueError("temperature_k and metres_per_hpa must be positive")
        if self.tau_s < 0 or self.reference_s < 0:
            raise ValueError("tau_s and reference_s must not be negative")


def relative_height(p, p_ref, settings: AltimeterSettings | None = None) -> np.ndarray:
    """Height (m) of pressure ``p`` above the level where the pressure is ``p_ref`` (hPa).

    The formula and its constants are those of ``settings`` (see the module docstring).
    """
    s = settings or AltimeterSettings()
    p = np.asarray(p, dtype=np.float64)
    p_ref = np.asarray(p_ref, dtype=np.float64)
    if s.formula == "linear":
        return s.metres_per_hpa * (p_ref - p)
    if s.formula == "isothermal":
        return (R_GAS * s.temperature_k / (G0 * M_AIR)) * np.log(p_ref / p)
    return (s.temperature_k / LAPSE_RATE) * (1.0 - (p / p_ref) ** HYPSOMETRIC_EXPONENT)


def reference_pressure(p, height_m, settings: AltimeterSettings | None = None) -> np.ndarray:
    """The inverse of :func:`relative_height`: ``p_ref`` such that ``p`` lies ``height_m`` above it."""
    s = settings or AltimeterSettings()
    p = np.asarray(p, dtype=np.float64)
    h = np.asarray(height_m, dtype=np.float64)
    if s.formula == "linear":
        return p + h / s.metres_per_hpa
    if s.formula == "isothermal":
        return p * np.exp(h * G0 * M_AIR / (R_GAS * s.temperature_k))
    return p * (1.0 - h * LAPSE_RATE / s.temperature_k) ** (-1.0 / HYPSOMETRIC_EXPONENT)


def pressure_at_height(height_m, p_ref, settings: AltimeterSettings | None = None) -> np.ndarray:
    """The pressure (hPa) ``height_m`` above the level where it is ``p_ref``: the other inverse
    of :func:`relative_height`, for simulators and tests."""
    s = settings or AltimeterSettings()
    h = np.asarray(height_m, dtype=np.float64)
    p_ref = np.asarray(p_ref, dtype=np.float64)
    if s.formula == "linear":
        return p_ref - h / s.metres_per_hpa
    if s.formula == "isothermal":
        return p_ref * np.exp(-h * G0 * M_AIR / (R_GAS * s.temperature_k))
    return p_ref * (1.0 - h * LAPSE_RATE / s.temperature_k) ** (1.0 / HYPSOMETRIC_EXPONENT)


def metres_per_hpa(p, settings: AltimeterSettings | None = None) -> float:
    """Local gradient ``-dH/dp`` (m/hPa) of the chosen formula at pressure ``p`` (hPa)."""
    s = settings or AltimeterSettings()
    if s.formula == "linear":
        return s.metres_per_hpa
    # both atmospheres have dH/dp = -R·T/(g·M·p) at the reference level (the units of p cancel)
    return R_GAS * s.temperature_k / (G0 * M_AIR * float(p))


@njit(cache=True)
def altimeter_run(t, p, state, tau, reference_s):  # pragma: no cover - compiled
    """Low-pass and reference over one batch; returns (filtered p, p_ref) per sample.

    ``state`` (float64[6], updated in place): filtered value, last time, time of the first
    sample, reference sum, reference count, reference frozen flag (1.0 once the window has
    passed or the altimeter was anchored). NaN in state[1] means no sample seen yet.
    """
    n = t.shape[0]
    filt = np.empty(n)
    pref = np.empty(n)
    y, t_prev, t_first, ref_sum, ref_n, frozen = state[0], state[1], state[2], state[3], state[4], state[5]
    for i in range(n):
        x = p[i]
        if math.isnan(t_prev):
            y = x
            t_first = t[i]
        else:
            dt = max(t[i] - t_prev, 0.0)
            if tau > 0.0:
                y += (1.0 - math.exp(-dt / tau)) * (x - y)
            else:
                y = x
        t_prev = t[i]
        if frozen == 0.0:
            if t[i] - t_first < reference_s or ref_n == 0.0:
                ref_sum += x
                ref_n += 1.0
            else:
                frozen = 1.0
        filt[i] = y
        pref[i] = ref_sum / ref_n
    state[0], state[1], state[2], state[3], state[4], state[5] = y, t_prev, t_first, ref_sum, ref_n, frozen
    return filt, pref


# the altimeter's state row before its first sample: filtered p, last t, first t, reference
# sum, reference count, reference frozen (what altimeter_run reads and writes)
ALTIMETER_START = (math.nan, math.nan, math.nan, 0.0, 0.0, 0.0)


def reanchor(state: np.ndarray) -> bool:
    """The altimeter whose state row is ``state`` (:data:`ALTIMETER_START` layout) takes its
    current low-passed pressure as the reference from now on (the height there is whatever
    the caller declares). False, and nothing changed, before the first sample."""
    if math.isnan(state[1]):
        return False
    state[3], state[4], state[5] = state[0], 1.0, 1.0
    return True


class BarometricAltimeter:
    """Streaming barometric height: ``h = alt.update(t, pressure_hpa)`` → (N,) metres.

    ``start_height_m`` is the height given to the reference level (0 for heights relative to
    the start; the start floor's elevation for heights in the building's frame). Samples with
    a non-finite pressure output the previous height (NaN before the first good one) and
    leave the state alone.
    """

    def __init__(self, settings: AltimeterSettings | None = None, start_height_m: float = 0.0):
        self.settings = settings or AltimeterSettings()
        self._h0 = float(start_height_m)
        self._state = np.array(ALTIMETER_START)
        self._height = math.nan
        self._hist_t = np.empty(0)
        self._hist_h = np.empty(0)

    # -- state ------------------------------------------------------------------------
    @property
    def pressure(self) -> float:
        """The low-passed pressure after the last sample (hPa), NaN before the first."""
        return float(self._state[0])

    @property
    def reference(self) -> float:
        """The reference pressure ``p_ref`` (hPa) in use, NaN before the first sample."""
        n = self._state[4]
        return float(self._state[3] / n) if n > 0 else math.nan

    @property
    def reference_fixed(self) -> bool:
        """True once the reference window has passed (or the altimeter was anchored)."""
        return bool(self._state[5])

    @property
    def height(self) -> float:
        """Height after the last sample (m), NaN before the first."""
        return self._height

    # -- streaming --------------------------------------------------------------------
    def update(self, t, pressure) -> np.ndarray:
        """Heights (m) at every sample of the batch; ``pressure`` (N,) or (N, 1) in hPa."""
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        p = np.ascontiguousarray(pressure, dtype=np.float64).reshape(-1)
        if p.shape != t.shape:
            raise ValueError(f"pressure has {p.shape[0]} samples, t has {t.shape[0]}")
        out = np.full(t.shape[0], np.nan)
        good = np.isfinite(p) & np.isfinite(t)
        if good.any():
            s = self.settings
            filt, pref = altimeter_run(t[good], p[good], self._state, s.tau_s, s.reference_s)
            out[good] = self._h0 + relative_height(filt, pref, s)
        if not good.all():
            out = _hold_last(out, self._height)
        if out.shape[0]:
            self._height = float(out[-1])
            self._remember(t, out)
        return out

    def _remember(self, t: np.ndarray, h: np.ndarray) -> None:
        keep_from = t[-1] - self.settings.history_s
        old = self._hist_t >= keep_from
        new = (t >= keep_from) & np.isfinite(h)
        self._hist_t = np.concatenate([self._hist_t[old], t[new]])
        self._hist_h = np.concatenate([self._hist_h[old], h[new]])

    def height_at(self, t) -> np.ndarray:
        """Height (m) at time(s) ``t`` within the last ``history_s`` of output, linearly
        interpolated; ends held; NaN before the first sample. For a step's height change
        ``dz = height_at(t_step) - height_at(t_previous_step)`` when the pressure runs on its
        own clock."""
        if self._hist_t.size == 0:
            return np.full(np.shape(t), np.nan)
        return np.interp(t, self._hist_t, self._hist_h)

    def anchor(self, height_m: float) -> None:
        """Declare that the responder is at ``height_m`` now; later heights count from here.

        The current low-passed pressure becomes the reference, which also ends the initial
        reference window. Before any sample it only sets the height of the reference level.
        Callers that also run a :class:`pdr.floors.FloorTracker` pass the same height to
        :meth:`pdr.floors.FloorTracker.anchor`.
        """
        self._h0 = float(height_m)
        if not reanchor(self._state):
            return
        # shift the kept history onto the new reference so a step's dz spans the anchor
        self._hist_h = self._hist_h + (self._h0 - self._height)
        self._height = self._h0

    @classmethod
    def run(cls, t, pressure, settings: AltimeterSettings | None = None, start_height_m: float = 0.0) -> np.ndarray:
        """Batch form: a fresh altimeter over a whole recording."""
        return cls(settings, start_height_m).update(t, pressure)


def _hold_last(x: np.ndarray, before: float) -> np.ndarray:
    """Replace NaN entries by the last finite value before them (``before`` at the start)."""
    ok = np.isfinite(x)
    idx = np.where(ok, np.arange(x.shape[0]), -1)
    np.maximum.accumulate(idx, out=idx)
    held = np.where(idx >= 0, x[np.maximum(idx, 0)], before)
    return held
