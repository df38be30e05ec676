"""What the walk allows: every fix judged against dead reckoning from the last trusted fix.

A fix is evidence only if the responder could have been there. The reference is dead reckoning
alone (:func:`service.fusion.dead_reckoning.dr_propagate`, the function the live pose is walked
with between graph updates: each step along the live heading, whose turns' sigmas grow the
heading variance and, through it, the position covariance of a long leg) started at the last
*trusted* fix, with its position covariance ``P`` and the distance ``d`` walked since that fix.
For a position fix ``z`` (σ_z) at time t, against the reference ``r`` of that time::

    ν = z − r,   D²(a) = ν_aᵀ (P + σ_z² I)⁻¹ ν_a,   ν_a = ν · max(0, 1 − a/|ν|)  (ν shortened by a metres)
    held out        if D²(margin + β·d) > χ²₂(p)     (reason ``walk_gate``)
    trusted         if D²(margin) ≤ χ²₂(p)           (the reference is corrected, Kalman with
                                                      P + (β·d)²I: r += Kν, d ×= 1−K)
    accepted only   otherwise                        (the graph takes it, the reference does not)

``p = walk_gate_probability``, ``β = walk_gate_drift`` (m per m walked: how fast a PDR
can drift that the covariance does not model, a heading bias), ``margin = walk_gate_margin_m``.
The Mahalanobis distance weighs the innovation by the reference's covariance in its direction:
across a long leg (heading uncertainty) far more than along it. A UWB range r_m to an anchor a is
judged the same way in one dimension: ``ν = r_m − |r − a|`` against
``√χ²₁(p) · √(uᵀPu + σ² + σ_a²) + margin + β·d`` (u the unit vector a → r).

Why the reference is not the graph: the graph takes every accepted fix, so a chain of fixes each
5 m from the pose the last one made drags it anywhere (issue 32, attack 3: 30.7 m, no flag).
Against dead reckoning from the last fix that agreed with it, the same chain must pay for its
offset with walked distance. Two fixes that agree with each other are not trusted for that: a drag
whose fixes are all one offset from a pose that did not move agrees with itself. A drifted
reference comes back as its covariance grows with the walk (the heading's uncertainty across a
long leg), so a true landmark across the track is trusted again within the noise.

What it does not stop: the same growth lets a patient drag through. On IPIN Trial01 rep01
(tests/test_fix_attacks.py) ten checkpoints 5 m from the live pose, one every 3 s, move the track
10.8 m (26.2 m without the gate). Tighter gates do not buy a clear bound (p = 0.99: 15.8 m,
p = 0.95: 8.4 m; a reference reset by a trusted drag changes what follows) and refuse true
landmarks (K = 3 live p75 1.925 → 1.955 / 1.971 m, Trial03 rep04 +0.89 m). Who may send
checkpoints is the other half of that defence (issue 32, deliverable 2). Counting the allowance
as a 1-σ drift when trust is judged lets the reference follow a step-length error, but lets the
same drag reach 20.6 m. And the other way round: along the track the covariance grows slowly,
so a step-length error above ``walk_gate_drift`` (5 %) over landmarks that are never trusted is,
after a few hundred metres, held out (tests/test_walk_gate.py); not seen on the 40 IPIN walks (K = 3).

**A heading error revealed by two fixes** (issue 27, point 5). The reference walks along the
live heading with the graph's heading sigma, so when that heading is wrong by more than the
graph admits (a grip the PDR did not notice, a compass bent for a whole corridor: the unseen walk
route 25 rep 03 went 100° off) every landmark falls outside the reference's covariance and is
held out, and the checkpoints that should pull the track back never reach it (a synthetic square
walk 30° off with a landmark every 16 m: live p75 27.8 m before, 0.02 m now;
tests/test_walk_gate.py). So the last precise position fix held out (σ at most
``walk_gate_margin_m``: a checkpoint, not GNSS) is kept, and the next precise fix that the gate
would hold out or let through untrusted is compared with it: the leg between the two fixes
``w_z = z_B − z_A`` against what the reference walked between their times ``w_r = r_B − r_A``.

* a **shift** (``|w_z − w_r|² ≤ χ²₂(p)·(σ_A² + σ_B²)``): both fixes one offset from the walk, a
  drag's signature (attack 3): nothing is revealed, B is judged alone;
* a **turn**: the legs have the same length within ``τ = margin + β·d_AB + √χ²₂(p)·√(σ_A² + σ_B²)``
  and the reference's leg is at least ``2τ`` long (shorter, a turn and a shift cannot be told
  apart within τ): the walk turned by the angle from w_r to w_z. B is let in and trusted (it
  restarts the reference), and A goes to the graph first, so the graph's newest heading is
  corrected at once by the two fixes (the live track turns at B, not at the fix after).

Weak evidence (GNSS, beacons: σ above the margin) neither is kept nor reveals a turn. The rule
lets a drag through only as a consistent rotation of the walk over legs at least 2τ long; with
it, attack 3 (ten fixes 5 m from the live pose every 3 s) moves the track as far as before
(the 3 s legs are too short to show a turn).

The same reference is what a track restarts from when the graph cannot go on
(:meth:`WalkGate.diverged`, :class:`service.fusion.estimators.FusionEstimator`): its pose is
dead reckoning from the last trusted fix, which no refused input has touched.
"""
from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from pdr.angles import wrap
from pdr.events import PoseEstimate
from service.fusion.dead_reckoning import dr_propagate


@functools.lru_cache(maxsize=8)
def _k(p: float, dof: int) -> float:
    from scipy.stats import chi2

    return math.sqrt(float(chi2.ppf(p, dof)))


def _mahalanobis2(nu: np.ndarray, cov: np.ndarray, slack: float) -> float:
    """``ν'ᵀ Σ⁻¹ ν'`` of the innovation ``ν`` shortened by ``slack`` metres (what drift and survey
    error may explain without noise): ``ν' = ν · max(0, 1 − slack/|ν|)``."""
    n = math.hypot(*nu)
    if n <= slack:
        return 0.0
    v = nu * (1.0 - slack / n)
    return float(v @ np.linalg.solve(cov, v))  # blas-ok: 2x2, one fix at a time


def _lam_max(c) -> float:
    a, d, b = float(c[0][0]), float(c[1][1]), 0.5 * (float(c[0][1]) + float(c[1][0]))
    return 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)


def _psd(c: np.ndarray) -> np.ndarray:
    """The nearest symmetric positive semi-definite 2x2 matrix (eigenvalues clipped at 0)."""
    c = 0.5 * (np.asarray(c, float) + np.asarray(c, float).T)
    w, v = np.linalg.eigh(c)
    if w[0] >= 0.0:
        return c
    return (v * np.clip(w, 0.0, None)) @ v.T  # blas-ok: 2x2


def _tighter_heading(cov: tuple, tt: float) -> tuple:
    """The reference's (x, y, θ) covariance (six floats, as :func:`dr_propagate`) with its heading
    variance lowered to ``tt`` (the graph knows the heading better), the position-heading
    correlation kept: ``Σ' = D Σ D``, ``D = diag(1, 1, √(tt/θθ))``, which is positive
    semi-definite whenever ``Σ`` is (a congruence). Replacing θθ alone while xθ and yθ stayed made
    the 3x3 indefinite: a walk east at σθ = 1 rad, then west at 0.001 rad, gave yy = −196 m², and a
    UWB range judged against it took the square root of a negative variance (a ValueError that
    cost a responder 20 s of track in CI run 1 at 157588d)."""
    xx, xy, xt, yy, yt, t0 = cov
    k = math.sqrt(tt / t0) if t0 > 0.0 else 0.0
    return xx, xy, xt * k, yy, yt * k, tt


@dataclass(frozen=True)
class GateVerdict:
    """``ok`` (the graph may take it), ``trusted`` (it also corrects the reference); ``reason``
    and ``detail`` say why not; ``info`` what to log (innovation, radius)."""

    ok: bool
    trusted: bool = False
    reason: str = ""
    detail: str = ""
    info: dict | None = None
    earlier: object | None = None  # a fix held out before that this one shows was right (a turn): the graph takes it first


@dataclass(frozen=True)
class _Held:
    """The last precise position fix held out: with the next one it may reveal a heading error."""

    fix: object
    t: float
    x: float
    y: float
    sigma: float


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

    _held: _Held | None = None  # (class default: snapshots pickled before it existed)
    precise_taken = 0  # precise position fixes the graph took (σ at most walk_gate_margin_m; class default: as above)

    def __init__(self, settings):
        self.s = settings
        self._state: tuple | None = None  # (t, x, y, θ, Σ as 6 floats (xx, xy, xθ, yy, yθ, θθ), floor)
        self._rows: deque[_Row] = deque()
        self._walked = 0.0
        self._held = None

    def start(self, t: float, x: float, y: float, sigma: float, floor: int, heading: float = math.nan,
              heading_sigma: float = math.nan) -> None:
        hv = heading_sigma * heading_sigma if math.isfinite(heading_sigma) else 0.0
        self._state = (t, x, y, heading, (sigma * sigma, 0.0, 0.0, sigma * sigma, 0.0, hv), floor)
        self._walked = 0.0
        self._rows.append(_Row(t, x, y, np.diag([sigma * sigma, sigma * sigma]), 0.0))

    def add_step(self, ev, heading: float, heading_sigma: float) -> None:
        """Step ``ev`` walked along ``heading`` (rad, the live one), from a pose whose heading sigma is
        ``heading_sigma`` (rad; the reference's grows by the step's turn sigma from there)."""
        s = self.s
        t, x, y, th, cov, _ = self._state
        if not math.isfinite(th):
            th = heading
        turn = wrap(heading - th)
        turn_sigma = ev.heading_change_sigma if math.isfinite(ev.heading_change_sigma) else s.unknown_turn_sigma_rad
        if math.isfinite(heading_sigma) and heading_sigma * heading_sigma < cov[5]:  # the graph knows the heading better
            cov = _tighter_heading(cov, heading_sigma * heading_sigma)
        length = max(float(ev.length), 0.0)
        x, y, th, cov = dr_propagate(x, y, th, cov, length, max(ev.length_sigma, s.length_sigma_floor_m),
                                     turn, max(turn_sigma, s.turn_sigma_floor_rad), s.lateral_sigma_m)
        self._state = (ev.t, x, y, th, cov, ev.floor)
        self._walked += length
        self._rows.append(_Row(ev.t, x, y, np.array([[cov[0], cov[1]], [cov[1], cov[3]]]), self._walked))
        while len(self._rows) > 1 and self._rows[0].t < ev.t - self.s.lag_s - 5.0:
            self._rows.popleft()

    def add_gap(self, sigma_m: float) -> None:
        """No samples for a while: the walker may be anywhere within ``sigma_m`` (m) more, as the
        graph's own gap factor says, so the reference's position widens the same way and a fix
        after the gap can re-anchor the track. Its heading is not widened (the graph's gap factor
        does not either): the PDR's heading after the gap is absolute again."""
        if self._state is None or not sigma_m > 0.0:
            return
        t, x, y, th, c, floor = self._state
        sv = sigma_m * sigma_m
        c = (c[0] + sv, c[1], c[2], c[3] + sv, c[4], c[5])
        self._state = (t, x, y, th, c, floor)
        self._rows.append(_Row(t, x, y, np.array([[c[0], c[1]], [c[1], c[3]]]), self._walked))

    @property
    def point(self) -> tuple[PoseEstimate | None, float]:
        """The reference's newest pose (dead reckoning from the last trusted fix) and the distance
        walked since that fix (m)."""
        if self._state is None:
            return None, self._walked
        t, x, y, th, c, floor = self._state
        cov = np.array([[c[0], c[1]], [c[1], c[3]]])
        return PoseEstimate(t, x, y, th, cov, floor, 0, "pdr", math.sqrt(max(c[5], 0.0))), self._walked

    def allowance(self, walked: float) -> float:
        return self.s.walk_gate_drift * walked

    def judge(self, fix) -> GateVerdict:
        """May the graph take ``fix``? (module docstring)"""
        s = self.s
        obs = observation(fix)
        if s.walk_gate_probability is None or obs is None or not self._rows:
            return GateVerdict(True)
        if getattr(fix, "authoritative", False):  # a logged-in operator who sees the responder: a new start
            return GateVerdict(True, trusted=True)
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
            rho = _k(s.walk_gate_probability, 1) * math.sqrt(max(var, 0.0)) + s.walk_gate_margin_m
            info = {"innovation_m": nu, "radius_m": rho + allow}
            if not abs(nu) <= rho + allow:
                return GateVerdict(False, reason="walk_gate", info=info,
                                   detail=f"range {rng:.1f} m is {abs(nu):.1f} m from the walk's {r_hat:.1f} m "
                                          f"(allowed {rho + allow:.1f} m)")
            return GateVerdict(True, trusted=abs(nu) <= rho, info=info)
        _, zx, zy, sigma = obs
        sigma = max(sigma, s.checkpoint_sigma_floor_m)
        nu = np.array([zx - row.x, zy - row.y])
        dist = float(math.hypot(*nu))
        chi2 = _k(s.walk_gate_probability, 2) ** 2
        cov = row.cov + sigma * sigma * np.eye(2)
        d2 = _mahalanobis2(nu, cov, allow + s.walk_gate_margin_m)
        info = {"innovation_m": dist, "mahalanobis2": d2}
        if not d2 <= chi2:
            turned = self._turned(fix, zx, zy, sigma, row, chi2, info)
            if turned is not None:
                return turned
            if sigma <= s.walk_gate_margin_m:
                self._held = _Held(fix, float(fix.t), zx, zy, sigma)
            return GateVerdict(False, reason="walk_gate", info=info,
                               detail=f"{dist:.1f} m from dead reckoning since the last trusted fix, "
                                      f"Mahalanobis² {d2:.1f} > {chi2:.1f} beyond {allow + s.walk_gate_margin_m:.1f} m "
                                      f"of drift after {row.walked:.0f} m walked")
        trusted = _mahalanobis2(nu, cov, s.walk_gate_margin_m) <= chi2
        if not trusted:  # let through on the drift allowance: with a fix held out before, it may show a turn
            turned = self._turned(fix, zx, zy, sigma, row, chi2, info)
            if turned is not None:
                return turned
        return GateVerdict(True, trusted=trusted, info=info)

    def _turned(self, fix, zx: float, zy: float, sigma: float, row: _Row, chi2: float, info: dict) -> GateVerdict | None:
        """A fix held out that, with the precise fix held out before it, shows the walk turned by a
        heading error (module docstring, *A heading error revealed by two fixes*), or None."""
        s, held = self.s, self._held
        if held is None or sigma > s.walk_gate_margin_m or not (self._rows[0].t <= held.t < fix.t):
            return None
        a = self._at(held.t)
        w_ref = np.array([row.x - a.x, row.y - a.y])  # what dead reckoning walked from A to B
        w_fix = np.array([zx - held.x, zy - held.y])  # what the fixes say
        var = held.sigma * held.sigma + sigma * sigma
        if float((w_fix - w_ref) @ (w_fix - w_ref)) / var <= chi2:  # blas-ok: 2-vectors
            return None  # a shift, not a turn: both fixes one offset from the walk (a drag's signature)
        slack = s.walk_gate_margin_m + s.walk_gate_drift * max(row.walked - a.walked, 0.0)
        tolerance = slack + math.sqrt(chi2 * var)  # m, how much the two legs' lengths may differ
        if math.hypot(*w_ref) < 2.0 * tolerance:
            return None  # a leg this short cannot tell a turn from a shift within that tolerance
        if abs(math.hypot(*w_fix) - math.hypot(*w_ref)) > tolerance:
            return None  # the legs differ in length: no turn explains it
        turn = math.atan2(w_ref[0] * w_fix[1] - w_ref[1] * w_fix[0], float(w_ref @ w_fix))  # blas-ok: 2-vectors
        self._held = None
        info.update(turn_deg=math.degrees(turn), turn_from_t=held.t)
        return GateVerdict(True, trusted=True, info=info, earlier=held.fix)

    def take(self, fix, verdict: GateVerdict) -> None:
        """The graph took ``fix``: a trusted position fix corrects the reference."""
        obs = observation(fix)
        if obs is None or obs[0] != "position" or not self._rows:
            return
        if obs[3] <= self.s.walk_gate_margin_m:
            self.precise_taken += 1
        if verdict.trusted:
            self._held = None  # a new start: a fix held out before it no longer tells a turn
        row = self._at(float(fix.t))
        sigma = max(obs[3], self.s.checkpoint_sigma_floor_m)
        nu = np.array([obs[1] - row.x, obs[2] - row.y])
        if not np.all(np.isfinite(nu)) or not np.all(np.isfinite(row.cov)):  # a lost reference restarts here
            self._rows.clear()
            st = self._state
            self.start(float(fix.t), obs[1], obs[2], sigma, st[5] if st else 0, st[3] if st else math.nan)
            return
        if not verdict.trusted:
            return
        # the drift the covariance leaves out; made positive semi-definite first: rows corrected by
        # earlier fixes can drift out of it, and an indefinite cov + σ²I inverted to a gain that
        # moved the reference 440 m for a fix 12 m away (the robustness suite's hold_z, T04r03)
        cov = _psd(row.cov) + self.allowance(row.walked) ** 2 * np.eye(2)
        gain = cov @ np.linalg.inv(cov + sigma * sigma * np.eye(2))  # blas-ok: 2x2, one fix at a time
        shift = gain @ nu  # blas-ok: 2x2
        post = (np.eye(2) - gain) @ cov  # blas-ok: 2x2
        post = 0.5 * (post + post.T)
        dcov = post - row.cov
        g = float(np.trace(gain)) / 2.0
        dwalk = -g * row.walked
        at = row.t
        for r in self._rows:
            if r.t >= at:
                r.x, r.y = r.x + float(shift[0]), r.y + float(shift[1])
                r.cov = _psd(r.cov + dcov)
                r.walked = max(r.walked + dwalk, 0.0)
        t, _, _, th, c, floor = self._state
        last = self._rows[-1]
        k = 1.0 - g
        self._state = (t, last.x, last.y, th, (last.cov[0, 0], last.cov[0, 1], c[2] * k, last.cov[1, 1], c[4] * k, c[5]),
                       floor)
        self._walked = last.walked

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
