"""What the walk allows: every fix judged against dead reckoning from the last trusted fix.

A fix is evidence only if the responder could have been there. The reference is dead reckoning
alone (:class:`pdr.dead_reckoning.DeadReckoning`: the PDR's steps along its own heading, the
same function as the tracker's baseline) started at the last *trusted* fix, with its position
covariance ``P`` and the distance ``d`` walked since that fix. For a position fix ``z`` (σ_z)
at time t, against the reference ``r`` of that time::

    ν = z − r,        noise radius  ρ = k₂ · √(λ_max(P) + σ_z²) + margin
    held out        if |ν| > ρ + β·d            (reason ``walk_gate``)
    trusted         if |ν| ≤ ρ                  (the reference is corrected, Kalman: r += Kν, P −= KP, d ×= 1−K)
    accepted only   otherwise                   (the graph takes it, the reference does not)

``k₂ = √χ²₂(walk_gate_probability)``, ``β = walk_gate_drift`` (m per m walked: how fast a PDR
can drift that the covariance does not model, a heading bias), ``margin = walk_gate_margin_m``.
A UWB range r_m to an anchor a is judged the same way in one dimension:
``ν = r_m − |r − a|``, ``ρ = k₁ · √(uᵀPu + σ² + σ_a²) + margin`` (u the unit vector a → r).

Why the reference is not the graph: the graph takes every accepted fix, so a chain of fixes each
5 m from the pose the last one made drags it anywhere (issue 32, attack 3: 30.7 m, no flag).
Against dead reckoning from the last fix that agreed with it, the same chain must pay for its
offset with walked distance: a forged offset can grow by at most β per metre walked. A fix
accepted only thanks to the drift allowance becomes trusted when the next position fix agrees
with it (the difference of the two fixes is the difference of the reference between them,
within the noise radius): two consistent landmarks correct a drifted walk; a drag, which is
always one offset further from the last fix, never agrees with it.

The same reference is what a track restarts from when the graph cannot go on
(:meth:`WalkGate.diverged`, :class:`service.fusion.estimators.FusionEstimator`): its pose is
dead reckoning from the last trusted fix, which no refused input has touched.
"""
from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from pdr.dead_reckoning import DeadReckoning


@functools.lru_cache(maxsize=8)
def _k(p: float, dof: int) -> float:
    from scipy.stats import chi2

    return math.sqrt(float(chi2.ppf(p, dof)))


def _lam_max(c) -> float:
    a, d, b = float(c[0][0]), float(c[1][1]), 0.5 * (float(c[0][1]) + float(c[1][0]))
    return 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)


@dataclass(frozen=True)
class GateVerdict:
    """``ok`` (the graph may take it), ``trusted`` (it also corrects the reference); ``reason``
    and ``detail`` say why not; ``info`` what to log (innovation, radius)."""

    ok: bool
    trusted: bool = False
    reason: str = ""
    detail: str = ""
    info: dict | None = None


@dataclass
class _Row:
    t: float
    x: float
    y: float
    cov: np.ndarray
    walked: float  # m since the last trusted fix


def observation(fix) -> tuple | None:
    """What a fix says about the position: ``("position", x, y, σ)``, ``("range", ax, ay, r, σ)``
    or None (a type the gate cannot judge: it passes, its own factors decide)."""
    if all(hasattr(fix, a) for a in ("range", "anchor_x", "anchor_y", "sigma")):
        return "range", float(fix.anchor_x), float(fix.anchor_y), float(fix.range), float(fix.sigma)
    if hasattr(fix, "x") and hasattr(fix, "y"):
        sigma = getattr(fix, "sigma", None)
        if sigma is None:
            sigma = getattr(fix, "accuracy", None)
        if sigma is not None:
            return "position", float(fix.x), float(fix.y), float(sigma)
    return None


class WalkGate:
    """The dead-reckoning reference of one track and the gate it gives (module docstring)."""

    def __init__(self, settings):
        self.s = settings
        self._dr = DeadReckoning()
        self._rows: deque[_Row] = deque()
        self._walked = 0.0
        self._candidate: tuple | None = None  # (ν, row, σ_z) of the last fix accepted but not trusted

    def start(self, t: float, x: float, y: float, sigma: float, floor: int) -> None:
        self._dr.start(t, x, y, floor, sigma)
        self._walked = 0.0
        self._rows.append(_Row(t, x, y, np.asarray(self._dr.point.cov, float), 0.0))

    def add_step(self, ev) -> None:
        p = self._dr.add_step(ev)
        self._walked += max(float(ev.length), 0.0)
        self._rows.append(_Row(p.t, p.x, p.y, np.asarray(p.cov, float), self._walked))
        while len(self._rows) > 1 and self._rows[0].t < p.t - self.s.lag_s - 5.0:
            self._rows.popleft()

    @property
    def point(self):
        """The reference's newest pose (:class:`pdr.events.PoseEstimate`: dead reckoning from the
        last trusted fix) and the distance walked since that fix (m)."""
        return self._dr.point, self._walked

    def allowance(self, walked: float) -> float:
        return self.s.walk_gate_drift * walked

    def judge(self, fix) -> GateVerdict:
        """May the graph take ``fix``? (module docstring)"""
        s = self.s
        obs = observation(fix)
        if s.walk_gate_probability is None or obs is None or not self._rows:
            return GateVerdict(True)
        row = self._at(float(fix.t))
        if not (math.isfinite(row.x) and math.isfinite(row.y) and np.all(np.isfinite(row.cov))):
            return GateVerdict(True, trusted=True)  # no reference to judge against: it restarts at this fix
        allow = self.allowance(row.walked)
        if obs[0] == "range":
            _, ax, ay, rng, sigma = obs
            dx, dy = row.x - ax, row.y - ay
            r_hat = math.hypot(dx, dy)
            u = np.array([dx, dy]) / r_hat if r_hat > 1e-9 else np.zeros(2)
            var = float(u @ row.cov @ u) + max(sigma, s.uwb_sigma_floor_m) ** 2 + s.uwb_anchor_sigma_m ** 2  # blas-ok: 2x2
            nu = rng - r_hat
            rho = _k(s.walk_gate_probability, 1) * math.sqrt(var) + s.walk_gate_margin_m
            info = {"innovation_m": nu, "radius_m": rho + allow}
            if not abs(nu) <= rho + allow:
                return GateVerdict(False, reason="walk_gate", info=info,
                                   detail=f"range {rng:.1f} m is {abs(nu):.1f} m from the walk's {r_hat:.1f} m "
                                          f"(allowed {rho + allow:.1f} m)")
            return GateVerdict(True, info=info)
        _, zx, zy, sigma = obs
        sigma = max(sigma, s.checkpoint_sigma_floor_m)
        nu = np.array([zx - row.x, zy - row.y])
        dist = float(math.hypot(*nu))
        rho = _k(s.walk_gate_probability, 2) * math.sqrt(_lam_max(row.cov) + sigma * sigma) + s.walk_gate_margin_m
        info = {"innovation_m": dist, "radius_m": rho + allow}
        if not dist <= rho + allow:
            return GateVerdict(False, reason="walk_gate", info=info,
                               detail=f"{dist:.1f} m from dead reckoning since the last trusted fix "
                                      f"(allowed {rho + allow:.1f} m after {row.walked:.0f} m walked)")
        trusted = dist <= rho or self._agrees(nu, row, sigma)
        return GateVerdict(True, trusted=trusted, info=info)

    def take(self, fix, verdict: GateVerdict) -> None:
        """The graph took ``fix``: a trusted position fix corrects the reference; one accepted on
        the drift allowance is remembered, to be trusted with the next one that agrees."""
        obs = observation(fix)
        if obs is None or obs[0] != "position" or not self._rows:
            return
        row = self._at(float(fix.t))
        sigma = max(obs[3], self.s.checkpoint_sigma_floor_m)
        nu = np.array([obs[1] - row.x, obs[2] - row.y])
        if not np.all(np.isfinite(nu)) or not np.all(np.isfinite(row.cov)):  # a lost reference restarts here
            self._rows.clear()
            self.start(float(fix.t), obs[1], obs[2], sigma, self._dr.point.floor if self._dr.point else 0)
            return
        if not verdict.trusted:
            self._candidate = (nu, row, sigma)
            return
        self._candidate = None
        cov = row.cov
        gain = cov @ np.linalg.inv(cov + sigma * sigma * np.eye(2))  # blas-ok: 2x2, one fix at a time
        shift = gain @ nu  # blas-ok: 2x2
        post = (np.eye(2) - gain) @ cov  # blas-ok: 2x2
        post = 0.5 * (post + post.T)
        dcov = post - cov
        g = float(np.trace(gain)) / 2.0
        dwalk = -g * row.walked
        at = row.t
        for r in self._rows:
            if r.t >= at:
                r.x, r.y = r.x + float(shift[0]), r.y + float(shift[1])
                r.cov = r.cov + dcov
                r.walked = max(r.walked + dwalk, 0.0)
        p = self._dr.point
        last = self._rows[-1]
        self._dr.point = replace(p, x=last.x, y=last.y, cov=last.cov.copy())
        self._walked = last.walked

    def _agrees(self, nu: np.ndarray, row: _Row, sigma: float) -> bool:
        """Does this fix confirm the last one accepted on the allowance? Both said the reference
        is off by about the same vector (the fixes' difference is the walk's, within noise)."""
        if self._candidate is None:
            return False
        nu0, row0, sigma0 = self._candidate
        if row.t < row0.t:
            return False
        growth = max(_lam_max(row.cov) - _lam_max(row0.cov), 0.0)
        rho = _k(self.s.walk_gate_probability, 2) * math.sqrt(growth + sigma * sigma + sigma0 * sigma0)
        return float(math.hypot(*(nu - nu0))) <= rho + self.s.walk_gate_margin_m

    def _at(self, t: float) -> _Row:
        """The reference row nearest in time to ``t``."""
        rows = self._rows
        best = rows[-1]
        for r in reversed(rows):
            if abs(r.t - t) < abs(best.t - t):
                best = r
            elif r.t < t:
                break
        return best

    def diverged(self, fp) -> str | None:
        """Why the graph's pose ``fp`` (a FusedPose) cannot be right, or None: not finite, a
        covariance beyond ``divergence_sigma_m``, or further from the reference than any walk
        allows (its noise radius, the drift allowance and ``divergence_m``)."""
        s = self.s
        vals = (fp.x, fp.y, fp.heading)
        cov = np.asarray(fp.cov, float)
        if not all(math.isfinite(v) for v in vals) or not np.all(np.isfinite(cov)):
            return "the pose or its covariance is not finite"
        sigma = math.sqrt(max(_lam_max(cov), 0.0))
        if sigma > s.divergence_sigma_m:
            return f"position sigma {sigma:.0f} m > {s.divergence_sigma_m:.0f} m"
        p, walked = self.point
        if p is None or not (math.isfinite(p.x) and math.isfinite(p.y)):
            return None
        dist = math.hypot(fp.x - p.x, fp.y - p.y)
        radius = (_k(0.999, 2) * math.sqrt(max(_lam_max(p.cov), 0.0) + sigma * sigma) + self.allowance(walked)
                  + s.divergence_m)
        if dist > radius:
            return f"{dist:.0f} m from dead reckoning since the last trusted fix (at most {radius:.0f} m)"
        return None
