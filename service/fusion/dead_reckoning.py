"""One step of dead reckoning with its (x, y, θ) covariance: the one function the fusion walks with.

Used by the live pose between graph updates (:class:`service.fusion.estimators.FusionEstimator`),
by the steps a smoothed-track query adds after the graph's newest pose, and by the walk gate's
reference (:mod:`service.fusion.walk_gate`). The tracker's baseline is
:class:`pdr.dead_reckoning.DeadReckoning`: each step along the PDR's absolute heading, a
different model kept as the figure the fusion must beat.
"""
from __future__ import annotations

import math


def dr_propagate(x: float, y: float, th: float, cov: tuple, length: float, length_sigma: float, turn: float,
                 turn_sigma: float, lateral_sigma: float) -> tuple[float, float, float, tuple]:
    """One step of dead reckoning with its covariance (first order): the heading turns by
    ``turn``, the step of ``length`` is walked along the new heading θ' (as the graph's step
    factor, :func:`service.fusion.noise.step_covariance`)::

        x' = x + L cos θ',   y' = y + L sin θ',   θ' = θ + Δθ
        Σ' = F (Σ + diag(0, 0, σ_Δθ²)) Fᵀ + R diag(σ_L², σ_lat²) Rᵀ,   F = [[1, 0, −L sin θ'], [0, 1, L cos θ'], [0, 0, 1]]

    ``cov`` is the symmetric 3x3 of (x, y, θ) as six floats ``(xx, xy, xθ, yy, yθ, θθ)``."""
    xx, xy, xt, yy, yt, tt = cov
    th = th + turn
    tt = tt + turn_sigma * turn_sigma
    c, s = math.cos(th), math.sin(th)
    a, b = -length * s, length * c  # ∂(x, y)/∂θ
    # F Σ Fᵀ with F = [[1, 0, a], [0, 1, b], [0, 0, 1]]
    nxx = xx + 2 * a * xt + a * a * tt
    nxy = xy + a * yt + b * xt + a * b * tt
    nyy = yy + 2 * b * yt + b * b * tt
    nxt = xt + a * tt
    nyt = yt + b * tt
    la, lo = length_sigma * length_sigma, lateral_sigma * lateral_sigma
    nxx += la * c * c + lo * s * s
    nxy += (la - lo) * c * s
    nyy += la * s * s + lo * c * c
    return x + length * c, y + length * s, th, (nxx, nxy, nxt, nyy, nyt, tt)
