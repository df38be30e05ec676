"""The step factor with a step-length scale: pose k-1 → pose k walked ``s·L`` along the new heading.

A PDR step length comes from a model (Weinberg & co.) fitted to other people, shoes and
floors; for one responder on one day it is off by a nearly constant factor (typically
5-15 %). Dead reckoning accumulates that factor as an along-track error proportional to the
distance walked; two checkpoints a known distance apart measure it. So the graph carries a
scale variable ``s`` (dimensionless, ≈1) that every step's translation is multiplied by:

    Z(s) = (s·L·cos Δθ, s·L·sin Δθ, Δθ),        e = Log( Z(s)⁻¹ · x_{k-1}⁻¹ · x_k )

(the ``BetweenFactorPose2`` error with a measurement that depends on ``s``). Jacobians, with
``E = Z⁻¹ x_{k-1}⁻¹ x_k``, ``J = J_r⁻¹(e)`` (``Pose2.LogmapDerivative``) and ``H₁, H₂`` the
Jacobians of ``between``:

    ∂e/∂x_{k-1} = J·H₁,   ∂e/∂x_k = J·H₂,
    ∂e/∂s = −J · Ad(E⁻¹) · (L, 0, 0)ᵀ

the last because ``Z(s+δ) = Z(s)·Exp((δL, 0, 0))`` (the translation grows along the step's
own direction, which is the x axis of the frame rotated by Δθ), hence
``E(s+δ) = Exp(−ζ)·E = E·Exp(−Ad(E⁻¹) ζ)``.

The scale is a slow random walk (shoes, fatigue, stairs change it): the graph opens a new
scale variable every ``length_scale_interval_s`` seconds, tied to the previous one by
``BetweenFactorDouble`` with σ = q·√Δt, and the first one has a prior around 1.
"""
from __future__ import annotations

import math

import gtsam
import numpy as np

from pdr.angles import wrap


def scaled_step_factor(prev_key: int, key: int, scale_key: int, length: float, turn: float,
                       noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (pose k-1, pose k, scale) for a step of ``length`` m and ``turn`` rad.

    ``noise`` is the step covariance of :func:`service.fusion.noise.step_covariance` (frame
    of the new pose: along, across, rotation).
    """
    cz, sz = math.cos(turn), math.sin(turn)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        # Plain floats: this runs in Python at every (re)linearisation, gtsam objects cost µs each.
        a = values.atPose2(prev_key)
        b = values.atPose2(key)
        scale = values.atDouble(scale_key)
        ta = a.theta()
        ca, sa = math.cos(ta), math.sin(ta)
        dx, dy = b.x() - a.x(), b.y() - a.y()
        hx, hy = ca * dx + sa * dy, -sa * dx + ca * dy  # x_{k-1}⁻¹ x_k, translation
        rx, ry = hx - scale * length * cz, hy - scale * length * sz
        ex, ey = cz * rx + sz * ry, -sz * rx + cz * ry  # E = Z⁻¹ x_{k-1}⁻¹ x_k, translation
        w = wrap(b.theta() - ta - turn)  # E, rotation
        e = _logmap(ex, ey, w)
        if jacobians is not None:
            j = gtsam.Pose2.LogmapDerivative(e)
            # between: H1 = -Ad((x_{k-1}⁻¹ x_k)⁻¹), H2 = I  (Pose2 Ad(R, t) = [[R, (t_y, -t_x)ᵀ], [0, 1]])
            th = b.theta() - ta
            ch, sh = math.cos(th), math.sin(th)
            ix, iy = -(ch * hx + sh * hy), -(-sh * hx + ch * hy)  # translation of (x_{k-1}⁻¹ x_k)⁻¹
            h1 = np.array([[-ch, -sh, -iy], [sh, -ch, ix], [0.0, 0.0, -1.0]])
            jacobians[0] = j @ h1
            jacobians[1] = j
            # ∂e/∂s = -J Ad(E⁻¹) (L, 0, 0)ᵀ = -J L (cos w, -sin w, 0)ᵀ   (first column of Ad(E⁻¹))
            jacobians[2] = (-length * (j[:, 0] * math.cos(w) - j[:, 1] * math.sin(w))).reshape(3, 1)
        return e

    return gtsam.CustomFactor(noise, [prev_key, key, scale_key], error)


def _logmap(x: float, y: float, w: float) -> np.ndarray:
    """Pose2 logarithm of (x, y, w): ``(V(w)⁻¹ (x, y), w)``, V the left Jacobian of SO(2) (as gtsam)."""
    if abs(w) < 1e-10:
        return np.array([x, y, w])
    c1, s = math.cos(w) - 1.0, math.sin(w)
    det = c1 * c1 + s * s
    # gtsam Pose2::Logmap: v = w/det · R(π/2)·(Rᵀt − t)
    ux, uy = math.cos(w) * x + s * y - x, -s * x + math.cos(w) * y - y
    return np.array([-uy * w / det, ux * w / det, w])
