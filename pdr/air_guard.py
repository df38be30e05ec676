"""The air, not the walker: pressure changes the walker's own gait cannot explain stay out of the height.

A barometer reads height only while the air stands still. At an incident it does not: a
positive-pressure ventilation fan set in a doorway (a fire service's usual tactic) raises a
building's pressure by tens of pascals in a few seconds, a pressurised stairwell is designed to
stand 12.5-87 Pa above the floors it serves (NFPA 92), and its doors swing it. 12 Pa reads as
a metre, so a fan read as height moves every responder inside down a floor: the robustness
suite's ``ppv_fan`` took the floor accuracy of the IPIN walks from 100 % to 71 %, and
``baro_doors`` to 92 % (docs/robustness.md, round 10).

**What a walking body can do.** A walker's height changes on stairs by a riser (0.15-0.19 m) a
step, at most about 0.5 m/s (three risers a second, a brisk descent); on a level, the hand's sway
moves the phone by up to 0.47 m/s over 1 s (the IPIN walks). So *while the walker walks*, the
barometer's height (the median of its last three samples, so that a lone spike is not taken for
air, low-passed over ``tau_fast_s``, 0.5 s) may change by at most
``step_climb_mps`` · Δt from one sample to the next (0.6 m/s: stairs with room to spare, because
the ‖f‖ test below takes a walker shifting in a moving lift for walking; at 0.5 m/s the guard
took 0.20 m out of a lift ride on T52r01 as logged, at 0.6 m/s 0.09 m; with 0.25 m taken out,
the first guard's, that walk broke under ``baro_drift``); the change beyond it is the air's and
accumulates in an offset subtracted from every later raw sample, before the altimeter's own
low-pass (:mod:`pdr.height`):

    p_f ← p_f + (1 − e^(−Δt/τ_f)) (med(p_k, p_{k−1}, p_{k−2}) − p_f),   Δh = −k Δp_f,
    L = max(v_step Δt, n_σ · √2 · (1 − e^(−Δt/τ_f)) · k σ_p),
    offset ← offset − (Δh − clip(Δh, −L, L)) / k.

**A noisy barometer widens the limit.** ``σ_p`` is the barometer's own sample noise, from the
second differences of the raw samples (white noise of σ gives E|p_k − 2p_{k−1} + p_{k−2}| =
√6 · √(2/π) · σ; a steady climb gives none), averaged over ``noise_tau_s``. A 1 Hz barometer
with 0.05 hPa of noise moves its low-passed height by 0.5 m a sample on its own; a limit of
0.5 m/s would take its tails for air, and the offset would wander (the first guard broke three
lift walks under ``baro_cheap`` so). With ``n_σ`` = 3 such a barometer is barely guarded at all:
it cannot tell a fan from its own noise.

**Standing, the height is free.** Standing still, a walker may be in a lift, and lifts run from
0.5 m/s (the IPIN museum's: up to 0.71 m/s over 1 s) to several metres a second in tall
buildings; no rate tells a lift from a fan. The first guard limited a standing walker to 0.8 m/s
unless a lift's start was felt in ‖f‖; it left the museum's lift 0.09 m/s of margin, and lift
rides under the suite's barometer perturbations lost their floors (docs/robustness.md, round 10).
So the guard acts only while the walker walks, or within ``step_grace_s`` of the last walking
sample (the low-pass's lag at a flight's end). Walking is told from the specific force's norm ‖f‖
on the IMU's samples up to each pressure sample: its standard deviation over about
``walk_tau_s`` above ``walk_acc_std`` (walking gives 1-3 m/s², a hand held still 0.05-0.2). The
evidence is taken in one pass over both streams (:func:`guard_run`), so frames of any size give
the same heights.

**The air comes back.** A door is a pulse: opened while the walker walks, its pressure is kept
out; shut while the walker stands, the height was free, so the shutting passed and the height
stayed off by the door's pressure (1.56 m and 1.75 m on T02r04 and T04r02 under ``baro_doors``,
docs/robustness.md, round 11). So for ``release_s`` (30 s) after the guard last kept air out, a
standing walker's *fast* change (beyond ``still_mps``, 0.2 m/s, or the noise as above) that goes
*against* the offset is the air returning, and comes off the offset, never past zero:

    f = Δh − clip(Δh, −L_s, L_s),   L_s = max(v_still Δt, n_σ · √2 · (1 − e^(−Δt/τ_f)) · k σ_p),
    offset ← offset + clip(−f / k, −|offset|, |offset|)   when −f/k and the offset differ in sign.

A first form released any standing change against the offset; the barometer's noise drained the
offset that way (``ppv_fan`` at seed 27: 4.65 m pooled, 10 broken walks). The cost: a lift ridden
within 30 s of a fan kept out, in the direction opposite to the fan, loses up to the fan's
height.

What passes. A fan's rise of 45 Pa (3.8 m) in 2 s while walking leaves about 1.6 m, under the
floor tracker's switch at 70 % of a floor's height (:mod:`pdr.floors`). A change slower than
stairs (the weather, 1 hPa/h; a building's air handling) passes whole, as before: the floor
tracker's drift loop takes it out.

Not handled: a fan that starts while the walker stands (or rides), and a rise slower than
0.5 m/s (a fan ramping up over 10 s). Responders in the same building see the same rise at the
same moment: a service-side comparison across responders is the next step.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from pdr.detector_kernels import finite_pairs

# the guard's state row: fast low-pass of p (hPa), its last time, the air offset (hPa), the newest
# walking sample, ‖f‖'s walking mean and variance, the last IMU time, the last two raw pressures,
# the mean |second difference| of the raw pressures (hPa) and how many went into it, the last time
# the guard kept air out
A_PF, A_T, A_AIR, A_WALK_T, A_M, A_V, A_IT, A_X1, A_X2, A_D2, A_ND2, A_LAST = range(12)
A_STATE = 12
AIR_START = (math.nan, math.nan, 0.0, -math.inf, math.nan, 0.0, math.nan, math.nan, math.nan, 0.0, 0.0, -math.inf)
_D2_PER_SIGMA = math.sqrt(6.0) * math.sqrt(2.0 / math.pi)  # E|p_k − 2p_{k−1} + p_{k−2}| / σ for white noise


@dataclasses.dataclass(frozen=True)
class AirGuardSettings:
    """Every number of the guard, with its unit (module docstring)."""

    enabled: bool = True
    tau_fast_s: float = 0.5  # s, low-pass of the samples the rate is judged on
    step_climb_mps: float = 0.6  # m/s, the fastest climb walking: stairs (three risers a second, a brisk descent: 0.5), with room for a lift ride the ‖f‖ test takes for walking
    noise_sigmas: float = 3.0  # n_σ: the limit is at least this many of the low-passed height's own sample noise
    noise_tau_s: float = 10.0  # s, average of the barometer's noise (second differences)
    step_grace_s: float = 2.5  # s after walking that a climb is still the walker's (the low-pass's lag)
    walk_tau_s: float = 0.5  # s, the walking test's averages of ‖f‖ and its variance
    walk_acc_std: float = 0.5  # m/s²
    m_per_hpa: float = 8.4  # m of height per hPa near the ground at room temperature (pdr.height)
    release_s: float = 30.0  # s after the guard last kept air out that a standing walker's fast change against the offset is the air coming back
    still_mps: float = 0.2  # m/s, what a standing walker's phone moves by itself (sway), beyond which a change is fast

    def __post_init__(self) -> None:
        for name in ("tau_fast_s", "step_climb_mps", "noise_sigmas", "noise_tau_s", "walk_tau_s", "walk_acc_std",
                     "m_per_hpa", "still_mps"):
            if not getattr(self, name) > 0:
                raise ValueError(f"AirGuardSettings.{name} must be positive, got {getattr(self, name)!r}")
        if not self.release_s >= 0:
            raise ValueError(f"AirGuardSettings.release_s must be >= 0, got {self.release_s!r}")

    @property
    def kernel_params(self) -> np.ndarray:
        return np.array([self.tau_fast_s, self.step_climb_mps, self.noise_sigmas, self.step_grace_s,
                         self.noise_tau_s, self.m_per_hpa, self.walk_tau_s, self.walk_acc_std, self.release_s,
                         self.still_mps], np.float64)


@njit(cache=True)
def _imu_sample(t, f, state, P):  # pragma: no cover - compiled
    """One IMU sample's ‖f‖ into the walking test."""
    walk_tau, walk_std = P[6], P[7]
    if math.isnan(state[A_IT]):
        state[A_M], state[A_V] = f, 0.0
    else:
        g = 1.0 - math.exp(-max(t - state[A_IT], 0.0) / walk_tau)
        d = f - state[A_M]
        state[A_M] += g * d
        state[A_V] += g * (d * d - state[A_V])
    state[A_IT] = t
    if state[A_V] > walk_std * walk_std:
        state[A_WALK_T] = t


@njit(cache=True)
def _pressure_sample(t, x, state, P):  # pragma: no cover - compiled
    """One raw pressure sample (hPa) through the guard; returns it less the air offset."""
    tau, v_step, n_sig, grace, noise_tau, k = P[0], P[1], P[2], P[3], P[4], P[5]
    if math.isnan(state[A_T]):
        state[A_PF] = x
    else:
        dt = max(t - state[A_T], 0.0)
        if not math.isnan(state[A_X2]):  # the barometer's own noise, from second differences
            d2 = abs(x - 2.0 * state[A_X1] + state[A_X2])
            state[A_ND2] += 1.0
            g = max(1.0 - math.exp(-dt / noise_tau), 1.0 / state[A_ND2])  # a plain mean until noise_tau is filled
            state[A_D2] += g * (d2 - state[A_D2])
        m = x  # the median of the last three samples: a lone spike is the sensor's, not the air's
        if not math.isnan(state[A_X2]):
            m = max(min(x, state[A_X1]), min(max(x, state[A_X1]), state[A_X2]))
        a = 1.0 - math.exp(-dt / tau)
        pf = state[A_PF] + a * (m - state[A_PF])
        dh = -k * (pf - state[A_PF])
        state[A_PF] = pf
        if t - state[A_WALK_T] <= grace and state[A_ND2] >= 8.0:  # walking (or just stopped): the gait bounds the climb
            sigma = state[A_D2] / _D2_PER_SIGMA
            lim = max(v_step * dt, n_sig * math.sqrt(2.0) * a * k * sigma)
            share = dh - min(max(dh, -lim), lim)
            state[A_AIR] -= share / k
            if share != 0.0:
                state[A_LAST] = t
        elif t - state[A_LAST] <= P[8] and state[A_AIR] != 0.0:  # standing: the air kept out may come back
            sigma = state[A_D2] / _D2_PER_SIGMA
            lim = max(P[9] * dt, n_sig * math.sqrt(2.0) * a * k * sigma)  # m: sway and noise stay put
            fast = dh - min(max(dh, -lim), lim)
            dp = -fast / k  # the fast part of the low-passed pressure change (hPa)
            if dp * state[A_AIR] < 0.0:  # the change goes against the offset: the air returning
                back = max(-abs(state[A_AIR]), min(abs(state[A_AIR]), dp))
                state[A_AIR] += back
    state[A_X2], state[A_X1] = state[A_X1], x
    state[A_T] = t
    return x - state[A_AIR]


@njit(cache=True)
def guard_run(ti, an, tp, p, state, P):  # pragma: no cover - compiled
    """A frame's IMU samples (times ``ti``, ‖f‖ ``an``) and pressure samples (``tp``, ``p`` hPa)
    in time order through the guard; returns the pressures less the air offset. ``state``
    (float64[A_STATE]) is updated in place; ``P`` = :attr:`AirGuardSettings.kernel_params`.

    Per pressure sample the equations of the module docstring (a limit only while the walker
    walks).
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
        ti, an, _ = finite_pairs(TI, AN, ioff[j], ioff[j + 1])
        tt, pp, idx = finite_pairs(PT, PV, poff[j], poff[j + 1])
        k = tt.shape[0]
        r = slots[j]
        g = guard_run(ti, an, tt, pp, air[r], P)
        for q in range(k):
            out[idx[q]] = g[q]
    return out


__all__ = ["AirGuardSettings", "guard_run", "air_stage", "A_STATE", "AIR_START"]
