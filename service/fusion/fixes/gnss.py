"""GNSS fixes: a satellite position of the responder, converted to local ENU with pymap3d.

Near and inside buildings GNSS suffers multipath, so a fix passes four gates before it is
evidence, each refusal counted by reason:

* ``gnss_accuracy``: the receiver's own 1-sigma is above ``gnss_max_accuracy_m``;
* ``gnss_below_ground``: the responder is on a floor below ``gnss_lowest_floor`` (a basement
  fix claiming 8-20 m was 10-17 m off on the IPIN walks: no sky, no evidence);
* ``gnss_interval``: less than ``gnss_min_interval_s`` after the last GNSS factor (consecutive
  fixes share their multipath error; one per interval keeps them from out-voting the steps);
* ``gnss_gate``: the innovation ν = z − p̂ fails the χ² test ``νᵀ(Σ_p + σ²I)⁻¹ν >
  χ²₂(gnss_gate_probability)`` against the pose's marginal.

What passes is a ``PoseTranslationPrior2D`` with σ = hypot(accuracy, slip) under a robust
kernel (``gnss_kernel``).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from service.fusion.fixes.base import FixContext, finite, positive


@functools.lru_cache(maxsize=8)
def _chi2(p: float, dof: int) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(p, dof))


@dataclass(frozen=True)
class GnssFix:
    """A satellite position in local ENU ``(x, y)`` (m); ``accuracy`` the receiver's horizontal
    1-sigma (m; ``inf`` is allowed and fails the accuracy gate)."""

    t: float
    x: float
    y: float
    accuracy: float
    source = "gnss"
    display = "hold"

    def __post_init__(self) -> None:
        finite("GnssFix", t=self.t, x=self.x, y=self.y)
        positive("GnssFix", accuracy=self.accuracy)

    def factors(self, ctx: FixContext):
        import gtsam

        from service.fusion.noise import robust

        s = ctx.settings
        if not self.accuracy <= s.gnss_max_accuracy_m:
            return ctx.reject("gnss_accuracy", f"accuracy {self.accuracy:.1f} m > {s.gnss_max_accuracy_m} m")
        if s.gnss_lowest_floor is not None and ctx.floor < s.gnss_lowest_floor:
            return ctx.reject("gnss_below_ground", f"floor {ctx.floor} is below ground (lowest with sky view "
                                                   f"{s.gnss_lowest_floor})")
        last = ctx.state.get("last_t", -math.inf)
        if self.t - last < s.gnss_min_interval_s:
            return ctx.reject("gnss_interval", f"{self.t - last:.1f} s after the last GNSS factor")
        sigma = math.hypot(self.accuracy, ctx.slip)
        p, cov = ctx.position_marginal()
        nu = np.array([self.x, self.y]) - p
        s2 = cov + sigma * sigma * np.eye(2)  # blas-ok: 2x2, one fix at a time
        d2 = float(nu @ np.linalg.solve(s2, nu))  # blas-ok: 2x2
        ctx.info["mahalanobis2"] = d2
        gate = _chi2(s.gnss_gate_probability, 2)
        if d2 > gate:
            return ctx.reject("gnss_gate", f"Mahalanobis² {d2:.1f} > {gate:.1f}")
        ctx.state["last_t"] = self.t
        base = gtsam.noiseModel.Isotropic.Sigma(2, sigma)
        return [gtsam.PoseTranslationPrior2D(ctx.key, np.array([self.x, self.y]),
                                             robust(s.gnss_kernel, s.gnss_kernel_width, base))]


def to_local(msg, incident) -> GnssFix:
    x, y, _ = incident.to_enu(msg.lat, msg.lon)
    return GnssFix(t=msg.t, x=float(x), y=float(y), accuracy=msg.accuracy)
