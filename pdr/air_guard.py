"""The air, not the walker: pressure changes no motion explains are kept out of the height.

A barometer reads height only while the air stands still. At an incident it does not: a
positive-pressure ventilation fan set in a doorway (a fire service's usual tactic) raises a
building's pressure by tens of pascals in a few seconds, a pressurised stairwell is designed to
stand 12.5-87 Pa above the floors it serves (NFPA 92), and its doors swing it. 12 Pa reads as
a metre, so a fan read as height moves every responder inside down a floor: the robustness
suite's ``ppv_fan`` took the floor accuracy of the IPIN walks from 100 % to 71 %, and
``baro_doors`` to 92 % (docs/robustness.md, round 10).

A walker changes height in three ways only, each of which the IMU sees:

* **stairs**, walking: a riser (0.15-0.19 m) a step, at most about 0.5 m/s (three risers a
  second, a brisk descent);
* **a lift**, standing: the museum's of the IPIN walks runs at up to 0.71 m/s (over 1 s, on the
  barometer), and a car's start and stop accelerate the walker by 0.3-1.2 m/s²;
* **nothing else**: walking or standing on a level, only the hand's sway (up to 0.47 m/s over
  1 s on the IPIN walks, as the phone is raised and lowered).

So the guard limits the rate of the height change it lets through (:func:`guard_run`). On the
barometer's samples, low-passed over ``tau_fast_s`` (0.5 s: the sample noise of phone barometers
stays well under the limits), the change beyond ``step_climb_mps`` (0.5 m/s) · Δt while the
walker walked in the last ``step_grace_s``, or beyond ``stand_climb_mps`` (0.8 m/s: a slow lift)
otherwise, is the air's: it accumulates in an offset subtracted from every raw sample before the
altimeter's own low-pass (:mod:`pdr.height`). Walking is told from the specific force's norm ‖f‖
on the IMU's samples up to each pressure sample: its standard deviation over about
``walk_tau_s`` above ``walk_acc_std`` (walking gives 1-3 m/s², a hand held still 0.05-0.2). A
lift frees the height: ‖f‖ averaged over ``lift_fast_s`` departing by ``lift_acc`` from its own
``lift_slow_s`` average, taken from the level of standing once the walking has stopped, lets
every change through until the height has been steady (under ``lift_steady_mps``) for
``lift_steady_s``, or the walker walks on. (On the IPIN walks of routes 52 and 53 it frees every
ride of the museum's lift.) The evidence is the IMU's samples up to each pressure sample's time,
in one pass over both (:func:`guard_run`), so frames of any size give the same heights.

What passes. A fan's rise of 45 Pa (3.8 m) in 2 s while walking leaves about 1.4 m, under the
floor tracker's switch at 70 % of a floor's height (:mod:`pdr.floors`); standing, about 2 m
(``tests/test_air_guard.py``). A change slower than stairs (the weather, 1 hPa/h; a building's
air handling) passes whole, as before: the floor tracker's drift loop takes it out. On the 40
IPIN walks as logged 24 of the 240 per-walk figures moved, by at most 0.40 m, none worse by
more than 0.31 m, and no floor (docs/robustness.md, round 10).

Not handled: a fan started while a lift rides (the lift frees the height), a rise slower than
0.5 m/s (a fan ramping up over 10 s), and a lift faster than 0.8 m/s whose start the test
misses (a car with gentle acceleration). Responders in the same building see the same rise at
the same moment: a service-side comparison across responders is the next step.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

# the guard's state row: fast low-pass of p (hPa), its last time, the air offset (hPa), the newest
# walking sample, the newest lift evidence, freed by a lift (1/0), since when the height has been
# steady (a freed guard), ‖f‖'s walking mean and variance, its fast and slow averages, the last IMU time
A_PF, A_T, A_AIR, A_WALK_T, A_LIFT_T, A_FREE, A_STEADY, A_M, A_V, A_FAST, A_SLOW, A_IT = range(12)
A_STATE = 12
AIR_START = (math.nan, math.nan, 0.0, -math.inf, -math.inf, 0.0, math.nan, math.nan, 0.0, math.nan, math.nan, math.nan)


@dataclasses.dataclass(frozen=True)
class AirGuardSettings:
    """Every number of the guard, with its unit (module docstring)."""

    enabled: bool = True
    tau_fast_s: float = 0.5  # s, low-pass of the samples the rate is judged on
    step_climb_mps: float = 0.5  # m/s, the fastest climb walking: stairs (three risers a second, a brisk descent)
    stand_climb_mps: float = 0.8  # m/s, the fastest change standing outside a lift seen to start: a slow lift (the IPIN museum's: 0.71 m/s at most over 1 s)
    step_grace_s: float = 2.5  # s after walking that a climb is still the walker's (the low-pass's lag)
    walk_tau_s: float = 0.5  # s, the walking test's averages of ‖f‖ and its variance
    walk_acc_std: float = 0.5  # m/s²
    lift_acc: float = 0.2  # m/s², ‖f‖'s departure from its slow average that marks a lift's start or stop
    lift_fast_s: float = 0.4  # s
    lift_slow_s: float = 8.0  # s
    lift_steady_s: float = 2.0  # s of steady height that ends a lift ride
    lift_steady_mps: float = 0.1  # m/s
    m_per_hpa: float = 8.4  # m of height per hPa near the ground at room temperature (pdr.height)

    def __post_init__(self) -> None:
        for name in ("tau_fast_s", "step_climb_mps", "stand_climb_mps", "walk_tau_s", "walk_acc_std", "lift_acc",
                     "lift_fast_s", "lift_slow_s", "m_per_hpa"):
            if not getattr(self, name) > 0:
                raise ValueError(f"AirGuardSettings.{name} must be positive, got {getattr(self, name)!r}")

    @property
    def kernel_params(self) -> np.ndarray:
        return np.array([self.tau_fast_s, self.step_climb_mps, self.stand_climb_mps, self.step_grace_s,
                         self.lift_steady_s, self.lift_steady_mps, self.m_per_hpa, self.walk_tau_s,
                         self.walk_acc_std, self.lift_acc, self.lift_fast_s, self.lift_slow_s], np.float64)


@njit(cache=True)
def _imu_sample(t, f, state, P):  # pragma: no cover - compiled
    """One IMU sample's ‖f‖ into the walking test and the lift test."""
    grace, walk_tau, walk_std, lift_acc, fast_s, slow_s = P[3], P[7], P[8], P[9], P[10], P[11]
    if math.isnan(state[A_IT]):
        state[A_M], state[A_V], state[A_FAST], state[A_SLOW] = f, 0.0, f, f
    else:
        dt = max(t - state[A_IT], 0.0)
        d = f - state[A_M]
        state[A_M] += (1.0 - math.exp(-dt / walk_tau)) * d
        state[A_V] += (1.0 - math.exp(-dt / walk_tau)) * (d * d - state[A_V])
        state[A_FAST] += (1.0 - math.exp(-dt / fast_s)) * (f - state[A_FAST])
        state[A_SLOW] += (1.0 - math.exp(-dt / slow_s)) * (f - state[A_SLOW])
    state[A_IT] = t
    if state[A_V] > walk_std * walk_std:
        state[A_WALK_T] = t
    if t - state[A_WALK_T] <= grace:
        state[A_SLOW] = state[A_FAST]  # the lift test compares with the level of standing, from the grace's end
    elif abs(state[A_FAST] - state[A_SLOW]) >= lift_acc:
        state[A_LIFT_T] = t


@njit(cache=True)
def _pressure_sample(t, x, state, P):  # pragma: no cover - compiled
    """One raw pressure sample (hPa) through the guard; returns it less the air offset."""
    tau, v_step, v_stand, grace, steady_s, steady_v, k = P[0], P[1], P[2], P[3], P[4], P[5], P[6]
    if math.isnan(state[A_T]):
        state[A_PF] = x
    else:
        dt = max(t - state[A_T], 0.0)
        pf = state[A_PF] + (1.0 - math.exp(-dt / tau)) * (x - state[A_PF])
        dh = -k * (pf - state[A_PF])
        state[A_PF] = pf
        if state[A_LIFT_T] >= t - grace:
            state[A_FREE], state[A_STEADY] = 1.0, math.nan
        if state[A_FREE] == 1.0 and state[A_WALK_T] > state[A_LIFT_T]:
            state[A_FREE] = 0.0  # walked on: out of the lift
        if state[A_FREE] == 1.0:
            if dt > 0.0 and abs(dh) <= steady_v * dt:
                if math.isnan(state[A_STEADY]):
                    state[A_STEADY] = t
                elif t - state[A_STEADY] >= steady_s:
                    state[A_FREE] = 0.0
            else:
                state[A_STEADY] = math.nan
        else:
            v = v_step if t - state[A_WALK_T] <= grace else v_stand
            lim = v * dt
            share = dh - min(max(dh, -lim), lim)
            state[A_AIR] -= share / k
    state[A_T] = t
    return x - state[A_AIR]


@njit(cache=True)
def guard_run(ti, an, tp, p, state, P):  # pragma: no cover - compiled
    """A frame's IMU samples (times ``ti``, ‖f‖ ``an``) and pressure samples (``tp``, ``p`` hPa)
    in time order through the guard; returns the pressures less the air offset. ``state``
    (float64[A_STATE]) is updated in place; ``P`` = :attr:`AirGuardSettings.kernel_params`.

    Per pressure sample: ``p_f ← p_f + (1 − e^(−Δt/τ_f)) (p − p_f)``, the height change
    ``Δh = −k Δp_f``, the limit ``L = v Δt`` (v by the motion, module docstring; none while a lift
    frees it), the air's share ``Δh − clip(Δh, −L, L)`` added to the offset (as pressure, ``−share / k``).
    The IMU samples up to each pressure sample's time are taken first."""
    out = np.empty(tp.shape[0])
    j = 0
    for i in range(tp.shape[0]):
        while j < ti.shape[0] and ti[j] <= tp[i]:
            _imu_sample(ti[j], an[j], state, P)
            j += 1
        out[i] = _pressure_sample(tp[i], p[i], state, P)
    while j < ti.shape[0]:
        _imu_sample(ti[j], an[j], state, P)
        j += 1
    return out


@njit(cache=True)
def air_stage(slots, ioff, TI, AN, poff, PT, PV, air, P):  # pragma: no cover - compiled
    """:func:`guard_run` over every responder of a round: its IMU samples ``TI[ioff[j]:ioff[j+1]]``
    (finite ones) and its pressure samples (finite ones; the others are passed on as they are, for
    the altimeter to skip); returns the guarded pressures."""
    out = PV.copy()
    for j in range(slots.shape[0]):
        r = slots[j]
        a0, a1 = ioff[j], ioff[j + 1]
        m = 0
        for i in range(a0, a1):
            if TI[i] - TI[i] == 0.0 and AN[i] - AN[i] == 0.0:
                m += 1
        ti = np.empty(m)
        an = np.empty(m)
        m = 0
        for i in range(a0, a1):
            if TI[i] - TI[i] == 0.0 and AN[i] - AN[i] == 0.0:
                ti[m], an[m] = TI[i], AN[i]
                m += 1
        b0, b1 = poff[j], poff[j + 1]
        k = 0
        for i in range(b0, b1):
            if PT[i] - PT[i] == 0.0 and PV[i] - PV[i] == 0.0:
                k += 1
        tt = np.empty(k)
        pp = np.empty(k)
        idx = np.empty(k, np.int64)
        k = 0
        for i in range(b0, b1):
            if PT[i] - PT[i] == 0.0 and PV[i] - PV[i] == 0.0:
                tt[k], pp[k], idx[k] = PT[i], PV[i], i
                k += 1
        g = guard_run(ti, an, tt, pp, air[r], P)
        for q in range(k):
            out[idx[q]] = g[q]
    return out


__all__ = ["AirGuardSettings", "guard_run", "air_stage", "A_STATE", "AIR_START"]
