"""UWB ranges: a measured distance from the responder's tag to a surveyed anchor.

The wire range is 3D; :meth:`UwbRange.at_height` turns it into the horizontal distance for the
tag's height (the responder's floor elevation + the incident's ``uwb_tag_height_m``) before
it reaches the graph. There it is gtsam's ``RangeFactor2D`` (Pose2 ↔ Point2: the wrapper has no
unary range-to-a-known-point factor) to an anchor variable held by a tight
``PriorFactorPoint2``, one variable per anchor reused while it stays in the window, behind a
χ²₁ gate on ``(r − r̂)² / (uᵀΣ_p u + σ² + σ_anchor²)`` and a robust kernel (non-line-of-sight
ranges are biased long).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from service.fusion.fixes.base import FixContext, FixRejected, finite, positive


@functools.lru_cache(maxsize=8)
def _chi2(p: float, dof: int) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(p, dof))


@dataclass(frozen=True)
class UwbRange:
    """``range`` (m, 1-sigma ``sigma``) to anchor ``anchor`` at ``(anchor_x, anchor_y)``;
    ``anchor_z`` its height (NaN: the range is already horizontal)."""

    t: float
    anchor_x: float
    anchor_y: float
    range: float
    sigma: float
    anchor: str = ""
    anchor_z: float = math.nan
    source = "uwb"
    display = "snap"

    def __post_init__(self) -> None:
        finite("UwbRange", t=self.t, anchor_x=self.anchor_x, anchor_y=self.anchor_y, range=self.range)
        positive("UwbRange", sigma=self.sigma)
        if self.range < 0.0:
            raise ValueError(f"UwbRange.range must be >= 0, got {self.range!r}")

    def at_height(self, tag_z: float) -> UwbRange:
        """The horizontal distance equivalent to this 3D range, for a tag at height ``tag_z`` (m,
        same datum as ``anchor_z``): ``r_h = √(r² − Δz²)``, ``σ_h = σ·r / r_h`` (first order; a
        range shorter than the height difference, noise, gives ``r_h = 0``). A range that is
        already horizontal (``anchor_z`` NaN) is returned as it is."""
        if not math.isfinite(self.anchor_z):
            return self
        dz = self.anchor_z - tag_z
        r_h = math.sqrt(max(self.range * self.range - dz * dz, 0.0))
        sigma = self.sigma * self.range / max(r_h, self.sigma)
        return dataclasses.replace(self, range=r_h, sigma=max(sigma, self.sigma), anchor_z=math.nan)

    def factors(self, ctx: FixContext):
        import gtsam

        from service.fusion.noise import robust

        s = ctx.settings
        sigma = math.hypot(max(self.sigma, s.uwb_sigma_floor_m), ctx.slip)
        if s.uwb_gate_probability:
            p, cov = ctx.position_marginal()
            d = p - np.array([self.anchor_x, self.anchor_y])
            r_hat = float(np.hypot(*d))
            u = d / r_hat if r_hat > 1e-9 else np.zeros(2)
            var = float(u @ cov @ u) + sigma * sigma + s.uwb_anchor_sigma_m ** 2  # blas-ok: 2x2
            d2 = (self.range - r_hat) ** 2 / var
            ctx.info["mahalanobis2"] = d2
            gate = _chi2(s.uwb_gate_probability, 1)
            if d2 > gate:
                return ctx.reject("uwb_gate", f"Mahalanobis² {d2:.1f} > {gate:.1f}")
        anchor = ctx.anchor(self.anchor, self.anchor_x, self.anchor_y)
        base = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
        return [gtsam.RangeFactor2D(ctx.key, anchor, self.range, robust(s.uwb_kernel, s.uwb_kernel_width, base))]


def to_local(msg, incident) -> UwbRange:
    """The anchor's surveyed position (3D) from the incident config."""
    anchor = next((a for a in incident.uwb_anchors if a.id == msg.anchor), None)
    if anchor is None:
        known = ", ".join(a.id for a in incident.uwb_anchors) or "none configured"
        raise FixRejected("unknown_reference", f"UWB anchor {msg.anchor!r} is not in the incident config (known: {known})")
    return UwbRange(t=msg.t, anchor_x=anchor.x, anchor_y=anchor.y, range=msg.range, sigma=msg.sigma,
                    anchor=anchor.id, anchor_z=anchor.z)
