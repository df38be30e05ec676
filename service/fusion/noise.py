"""Noise models of the fusion graph: a step's turn and covariance, and robust kernels."""
from __future__ import annotations

import math

import gtsam
import numpy as np

from pdr.angles import wrap

KERNELS = ("gaussian", "huber", "cauchy", "tukey")


def step_turn(ev, dt: float, heading: float, s) -> tuple[float, float]:
    """(turn Δθ, its sigma) of step ``ev`` (rad), ``dt`` (s) after the pose before, whose heading
    is ``heading`` (rad). The gyro's turn and sigma, grown in quadrature by: a random walk
    ``turn_walk·√dt``; ``stairs_turn_sigma_rad`` on stairs (the phone pitches, its forward axis's
    yaw is poorly defined); ``stop_turn_sigma_rad`` after a stop of ``stop_turn_s`` or more (the
    grip may change while standing, and the PDR's heading of travel restarts); at least
    ``turn_sigma_floor_rad``. Without a gyro turn: from the PDR's absolute heading, loosely
    (``unknown_turn_sigma_rad``)."""
    turn, sigma = ev.heading_change, ev.heading_change_sigma
    if not (math.isfinite(turn) and math.isfinite(sigma)):
        turn = wrap(ev.heading - heading) if math.isfinite(ev.heading) else 0.0
        sigma = s.unknown_turn_sigma_rad
    sigma = math.hypot(sigma, s.turn_walk * math.sqrt(max(dt, 0.0)))
    if ev.on_stairs:
        sigma = math.hypot(sigma, s.stairs_turn_sigma_rad)
    if dt >= s.stop_turn_s:
        sigma = math.hypot(sigma, s.stop_turn_sigma_rad)
    return turn, max(sigma, s.turn_sigma_floor_rad)


def step_covariance(length: float, length_sigma: float, turn_sigma: float, lateral_sigma: float) -> np.ndarray:
    """Covariance (3x3, in the frame of the new pose: along, across, rotation) of one step.

    The step of length ``L`` is walked along the new heading, so pose k seen from pose k-1 is
    ``(L cos Δθ, L sin Δθ, Δθ)``. gtsam's Pose2 between error is ``Log(Z⁻¹ T_{k-1}⁻¹ T_k)``,
    expressed in pose k's frame; to first order a length error δL, a turn error δθ and a
    sideways sway n of the foot give

        e ≈ (δL,  L·δθ + n,  δθ)

    hence (σ_L, σ_θ, σ_n the 1-sigma of δL, δθ, n)

        Σ = [[σ_L²,      0,            0    ],
             [0,    L²σ_θ² + σ_n²,   L σ_θ² ],
             [0,       L σ_θ²,        σ_θ²  ]].

    The across/rotation correlation matters: a diagonal ``(σ_L, L σ_θ, σ_θ)`` would count the
    same gyro error twice and make the track twice as confident in its heading as the gyro is.
    The determinant of the lower block is σ_n² σ_θ², so ``lateral_sigma > 0`` keeps Σ positive
    definite for any turn sigma.
    """
    a = length * turn_sigma * turn_sigma
    return np.array([
        [length_sigma * length_sigma, 0.0, 0.0],
        [0.0, length * a + lateral_sigma * lateral_sigma, a],
        [0.0, a, turn_sigma * turn_sigma],
    ])


def robust(kernel: str, width: float, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    """``base`` wrapped in an M-estimator ``kernel`` whose ``width`` is in whitened units (sigmas).

    * ``huber``: quadratic inside ``width`` sigmas, linear outside — convex, so one bad fix
      cannot move the optimum to a different basin, but its pull is bounded.
    * ``cauchy``: ρ = w²/2 · log(1 + (r/w)²) — influence decays for gross errors (stronger
      rejection, non-convex).
    * ``tukey``: zero influence beyond ``width`` (rejects, but can lock onto a wrong basin).
    * ``gaussian``: no kernel (plain least squares), for comparison.
    """
    est = gtsam.noiseModel.mEstimator
    if kernel == "gaussian":
        return base
    if kernel == "huber":
        m = est.Huber.Create(width)
    elif kernel == "cauchy":
        m = est.Cauchy.Create(width)
    elif kernel == "tukey":
        m = est.Tukey.Create(width)
    else:
        raise ValueError(f"robust kernel must be one of {KERNELS}, got {kernel!r}")
    return gtsam.noiseModel.Robust.Create(m, base)
