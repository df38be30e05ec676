"""Is a checkpoint fix plausible? A person cannot be further from where they were than they can walk.

A checkpoint fix puts the responder at ``B`` (σ_B) at device time ``t_B``. It is compared with
two references, and flagged ``implausible_jump`` when it fails either:

* the responder's **last checkpoint** ``A`` (σ_A) at ``t_A``: between the two fixes a person
  covers at most ``v_max · (t_B − t_A)``, so
  ``|B − A| > v_max · |t_B − t_A| + k · hypot(σ_A, σ_B) + margin`` is too far;
* the **current estimate** ``P`` at ``t_P`` with its covariance (largest standard deviation
  σ_P, the semi-major axis of the 1-σ ellipse):
  ``|B − P| > v_max · |t_B − t_P| + k · hypot(σ_P, σ_B) + margin``. This catches the forged
  fix of issue 19 (86 m in 2 s) that the first test alone would let through after a long walk.

An unplaced responder (no checkpoint yet, the wide entry σ) is never flagged: its first
placement is not a jump. The check flags; it does not refuse (an authorised operator may know
better than the estimate, and the console and the recording say so).

``v_max`` is a firefighter's sustained running speed in gear (breathing apparatus and turnout
gear: 3 m/s is a brisk run; sustained sprints are not possible inside a burning building);
``margin_m`` covers a checkpoint's survey and the slip between the fix's time and its step.
Neither is fitted to data: they bound physics, and a flag costs a glance, not a track.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlausibilitySettings:
    max_speed_mps: float = 3.0  # m/s: the fastest a responder in gear keeps up
    n_sigma: float = 3.0  # the positions' uncertainty allowed, in standard deviations
    margin_m: float = 5.0  # m: survey error of a checkpoint and the fix-to-step slip


@dataclass(frozen=True)
class Reference:
    """Where the responder was: ``t`` (s, device clock), ``x``, ``y`` (m, ENU), ``sigma`` (m)."""

    t: float
    x: float
    y: float
    sigma: float


@dataclass(frozen=True)
class Verdict:
    jump_m: float  # m: distance from the reference that failed (or the larger one)
    walkable_m: float  # m: what was allowed against that reference
    against: str  # "last_fix" or "estimate"

    @property
    def implausible(self) -> bool:
        return self.jump_m > self.walkable_m


def semi_major(cov) -> float:
    """m: the largest standard deviation of a 2x2 covariance (√ of its largest eigenvalue,
    closed form for a symmetric 2x2: λ = (a+d)/2 + √(((a−d)/2)² + b²))."""
    c = np.asarray(cov, float)
    a, d, b = c[0, 0], c[1, 1], 0.5 * (c[0, 1] + c[1, 0])
    lam = 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    return math.sqrt(max(lam, 0.0))


def judge(t: float, x: float, y: float, sigma: float, references: list[tuple[str, Reference]],
          settings: PlausibilitySettings = PlausibilitySettings()) -> Verdict | None:
    """The fix (t, x, y, σ) against each named reference (``("last_fix", ref)``,
    ``("estimate", ref)``): the first that fails, else the one with the largest jump; None
    without a reference."""
    worst = None
    for name, ref in references:
        jump = math.hypot(x - ref.x, y - ref.y)
        allowed = (settings.max_speed_mps * abs(t - ref.t) + settings.n_sigma * math.hypot(ref.sigma, sigma)
                   + settings.margin_m)
        v = Verdict(jump, allowed, name)
        if v.implausible:
            return v
        if worst is None or jump > worst.jump_m:
            worst = v
    return worst
