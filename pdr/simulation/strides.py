"""A walker's strides: what a walker's gait is (:class:`WalkerTraits`, drawn once), and the
step lengths that make a leg of its route a whole number of steps (:func:`solve_scale`,
:func:`step_layout`), which :class:`pdr.simulation.plan.WalkerPlan` lays out leg by leg."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from pdr.simulation.motion import NTR
from pdr.simulation.settings import WalkerSettings


@dataclasses.dataclass(frozen=True)
class WalkerTraits:
    """What makes one walker differ from another: drawn once from its generator."""

    cadence_hz: float
    step_length_m: float
    row: np.ndarray  # (NTR,) oscillation amplitudes (m/s²), phases (rad), gyro bias (rad/s)
    key: int  # noise key (uint64)

    @classmethod
    def draw(cls, rng: np.random.Generator, s: WalkerSettings) -> WalkerTraits:
        g = rng.standard_normal(4)  # always the same draws, whatever the settings
        cadence = s.cadence_hz * float(np.clip(1.0 + s.cadence_jitter * g[0], 0.7, 1.3))
        step = s.step_length_m * float(np.clip(1.0 + s.step_length_jitter * g[1], 0.7, 1.3))
        amp = float(np.clip(1.0 + s.amplitude_jitter * g[2], 0.5, 1.5))
        phases = rng.uniform(0.0, 2.0 * math.pi, 4)  # lateral, pitch, roll, yaw sway
        bias = rng.uniform(-s.gyro_bias, s.gyro_bias, 3)
        key = int(rng.integers(0, 2**63, dtype=np.int64))
        row = np.array([
            s.vertical_acc_amplitude * amp, s.forward_acc_amplitude * amp, s.lateral_acc_amplitude * amp,
            0.5 * math.pi + 0.3 * g[3],  # surge leads the bounce by about a quarter step
            *phases, *bias, cadence,
        ])
        assert row.shape == (NTR,)
        return cls(cadence, step, row, key)


def step_layout(parts, scale: float, lam_in: float | None) -> list[tuple[float, float, float, float]]:
    """Per path row ``(λ0, G, W, steps)``: the step length starts at ``λ0`` (the previous row's
    last) and reaches ``scale`` × nominal after ``W`` steps (at most one, and short enough that
    the row outlasts it); ``steps`` is how many steps the row's length takes:
    ``L = λ0 s + G W (s - W/2)`` with ``G = (λ - λ0)/W``, so ``s = L/λ + (W/2)(1 - λ0/λ)``."""
    out = []
    lam0 = lam_in
    for p in parts:
        length, target = p[0], p[1] * scale
        if lam0 is None or abs(lam0 - target) < 1e-12:
            out.append((target, 0.0, 0.0, length / target))
        else:
            rho = lam0 / target
            w = min(1.0, length / (target * (1.0 + rho)))
            out.append((lam0, (target - lam0) / w, w, length / target + 0.5 * w * (1.0 - rho)))
        lam0 = target
    return out


def solve_scale(parts, lam_in: float | None, n_steps: int) -> float:
    """The factor on the nominal step lengths that makes the rows take exactly ``n_steps`` steps.

    The step count falls smoothly from +∞ to 0 as the factor grows: secant iterations from 1
    (a few suffice), bisection on the logarithm if they stray (legs much shorter than a step)."""
    def excess(k):
        return sum(r[3] for r in step_layout(parts, k, lam_in)) - n_steps

    k0, k1 = 1.0, 1.01
    f0, f1 = excess(k0), excess(k1)
    for _ in range(12):
        if abs(f1) < 1e-12 or f1 == f0:
            break
        k0, k1, f0 = k1, k1 - f1 * (k1 - k0) / (f1 - f0), f1
        if not 1e-3 < k1 < 1e3:
            break
        f1 = excess(k1)
    if 1e-3 < k1 < 1e3 and abs(f1) < 1e-12:
        return k1
    lo, hi = math.log(1e-4), math.log(1e4)
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if excess(math.exp(mid)) > 0:
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))
