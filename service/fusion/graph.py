"""Per-responder factor-graph fusion of PDR steps with checkpoint, GNSS and UWB fixes (gtsam).

One :class:`TrackFusion` per responder; the live service and the offline evaluation call the
same object, step by step and fix by fix.

The graph (Dellaert & Kaess, "Factor Graphs for Robot Perception", 2017, ch. 2-3)::

    prior(x0) ── x0 ──step── x1 ──step── x2 ── ... ── xk          x_i ∈ SE(2): (x, y, θ), θ = heading of travel
                              │           │             │
                           compass     checkpoint     GNSS / UWB range ── anchor a_j (tight prior)

* **Step** k (a :class:`pdr.events.StepEvent`): a ``BetweenFactorPose2`` x_{k-1} → x_k with
  ``Z = (L cos Δθ, L sin Δθ, Δθ)`` — the step of length L is walked along the *new* heading —
  and the correlated covariance of :func:`service.fusion.noise.step_covariance`. The gyro's
  turn Δθ is relative; the graph never uses the PDR's absolute heading, only:
* **Compass** (optional, ``use_mag_heading``, on by default): a ``PoseRotationPrior2D`` on θ_k
  from ``ev.mag_heading`` when the PDR judged the field undisturbed. Without it nothing in the
  graph bounds the gyro's heading drift between fixes (tests: 0.3°/step drift, ×5 the error
  without it). Its kernel is Cauchy because indoor fields bend by tens of degrees near steel
  (seed 003 §2.2) and the PDR's gate can miss a stretch: 40 steps 50° off (claiming 5°) bend
  the track by ≈3 m with Cauchy, ≈18 m with Huber, ≈21 m with plain least squares. The price:
  after a long compass gap with a large gyro drift Cauchy pulls the heading back more slowly
  (a redescending kernel doubts a compass that disagrees by many sigmas); Tukey, which ignores
  such a compass entirely, never recovers and is not used.
* **Checkpoint**: a ``PoseTranslationPrior2D`` — a prior on the pose's translation in the world
  frame and nothing on its heading. (A ``PriorFactorPose2`` with a huge θ sigma would do nearly
  the same, but leaks a tiny fake heading prior and needs a made-up number; the translation
  prior is exact and in the wheel.) Gaussian: a checkpoint is confirmed by a person.
* **GNSS**: the same translation prior with σ = accuracy, behind two gates (accuracy and a χ²
  test of the innovation against the pose's marginal) and a robust kernel for what passes.
* **UWB**: gtsam's ``RangeFactor2D`` (Pose2 ↔ Point2; the wrapper has no unary range-to-a-known-
  point factor) to an anchor variable held by a tight ``PriorFactorPoint2``; one variable per
  anchor is reused while it stays in the window. Robust kernel (NLOS ranges are long).

**Time.** A fix attaches to the step pose nearest in time; the distance walked between the
fix time and that pose (its share of the step's length) is added in quadrature to the fix's
sigma, so an interpolation error is noise, not bias. A fix newer than the latest step
attaches to the latest pose (the responder is standing or mid-step; no inflation). A fix older
than the window is rejected (``too_old``): the poses it would correct are now a linearised
marginal; attaching it to the oldest pose still in the window would place it at the wrong
point of the track, and faking it into the frozen history would not reach the live estimate.

**Bounded cost.** gtsam's ``IncrementalFixedLagSmoother`` (iSAM2 with marginalisation) keeps
the last ``lag_s`` seconds of poses; older ones are marginalised into a linear prior on the
window and their last smoothed value is frozen in :class:`service.fusion.history.PoseHistory`.
Adding a step is a true incremental iSAM2 update (it re-eliminates only the top of the Bayes
tree), cheap enough per step (≈0.1 ms, see ``firetrack bench fusion``) that no batching of
steps is needed; a fix is followed by up to ``fix_extra_updates`` more iSAM2 iterations
(until the newest pose settles) so a large correction of the past converges.

**Floors.** Each pose carries ``ev.floor`` plus an offset; a checkpoint with a floor sets the
offset so that its pose reads the checkpoint's floor, and the offset holds for later steps
(a barometric floor reference that was off stays off by the same number of floors). A late
floor checkpoint relabels poses up to the next floor checkpoint.

**Covariance.** gtsam's Pose2 marginal is in the pose's body frame (tangent space, retract
``T·Exp(ξ)``); the published 2x2 is rotated into ENU: ``Σ_w = R(θ) Σ_b[:2, :2] R(θ)ᵀ``.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import gtsam
import numpy as np
from scipy.stats import chi2

from pdr.events import StepEvent, bearing_deg
from service.fusion.fixes import CheckpointFix, GnssFix, UwbRange
from service.fusion.history import PoseHistory
from service.fusion.noise import robust, step_covariance
from service.fusion.scaled_step import scaled_step_factor
from service.fusion.settings import FusionSettings


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def X(row: int) -> int:
    """gtsam key of the pose in history row ``row``."""
    return gtsam.symbol("x", row)


def A(n: int) -> int:
    """gtsam key of anchor variable ``n``."""
    return gtsam.symbol("a", n)


def S(n: int) -> int:
    """gtsam key of step-length scale variable ``n``."""
    return gtsam.symbol("s", n)


@dataclass(frozen=True)
class FusedPose:
    """The fused estimate of one pose as published: immutable (``cov`` is read-only)."""

    t: float  # s, device clock of the step (or of start())
    index: int  # StepEvent.index of the step that made this pose (0: the start pose)
    x: float  # m, ENU east
    y: float  # m, ENU north
    heading: float  # rad, ENU yaw of travel (CCW from East)
    cov: np.ndarray  # (2, 2) m², marginal covariance of (x, y) in ENU
    floor: int
    steps: int  # steps fused so far
    source: str  # "pdr" before any accepted fix, "fused" after
    heading_sigma: float = math.nan  # rad, marginal 1-sigma of the heading
    length_scale: float = math.nan  # estimated factor on the PDR's step length (NaN: not estimated)

    @property
    def bearing_deg(self) -> float:
        return bearing_deg(self.heading)

    @property
    def position_sigma(self) -> float:
        """m, square root of the larger eigenvalue of ``cov`` (the worst direction)."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.cov)[-1], 0.0)))


@dataclass(frozen=True)
class FusionEvent:
    """Something the fusion decided about an input: accepted or rejected fix, a step gap."""

    t: float  # s, time of the input
    kind: str  # "accepted", "rejected", "step_gap"
    what: str  # "checkpoint", "gnss", "uwb", "step"
    detail: str = ""  # the rejection reason or a short note
    values: dict = field(default_factory=dict)


@dataclass
class FixContext:
    """What a fix type's ``factors(ctx)`` may use: the key of the pose at the fix's time, the
    distance walked between that pose and the fix (add it to the sigma), the fusion settings,
    the pose's current position estimate and ENU covariance (for a gate), and a way to say
    why a fix is refused."""

    key: int
    slip: float  # m
    settings: FusionSettings
    position_marginal: object  # () -> (position (2,), covariance (2, 2)) in ENU
    rejected: tuple[str, str] | None = None

    def reject(self, reason: str, detail: str = "") -> None:
        self.rejected = (reason, detail)


_FIX_NAMES = {CheckpointFix: "checkpoint", GnssFix: "gnss", UwbRange: "uwb"}


class TrackFusion:
    """Fixed-lag factor-graph smoother of one responder's track (see the module docstring)."""

    def __init__(self, settings: FusionSettings | None = None):
        self.settings = settings or FusionSettings()
        s = self.settings
        self.rejected: Counter[str] = Counter()  # rejection reason -> count
        self.events: deque[FusionEvent] = deque(maxlen=s.max_events)
        self._gnss_gate = float(chi2.ppf(s.gnss_gate_probability, 2))
        self._uwb_gate = float(chi2.ppf(s.uwb_gate_probability, 1)) if s.uwb_gate_probability else math.inf
        self._smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self._hist = PoseHistory()
        self._window_start = 0  # first history row still held by the smoother
        self._anchors: dict[tuple[str, float, float], list] = {}  # id -> [key, timestamp]
        self._n_anchors = 0
        self._live: FusedPose | None = None
        self._live_pose = gtsam.Pose2()
        self._fused = False
        self._steps = 0
        self._last_index = 0
        self._floor_offset = 0
        self._floor_fix_row = -1  # row of the latest checkpoint that set the floor
        self._last_mag_t = -math.inf
        self._scale_n = -1  # index of the current step-length scale variable (-1: not estimated)
        self._scale_t0 = -math.inf  # s, when the current scale variable was opened
        self._scale = 1.0  # its latest estimate

    # ---------------------------------------------------------------- inputs

    def start(self, t: float, x: float, y: float, heading: float, heading_sigma: float,
              position_sigma: float = 0.5, floor: int = 0) -> FusedPose:
        """Put a prior on the first pose (position ±``position_sigma`` m, heading ±``heading_sigma`` rad)."""
        if self._smoother is not None:
            raise RuntimeError("TrackFusion.start() called twice; make a new TrackFusion for a new track")
        for name, v in (("t", t), ("x", x), ("y", y), ("heading", heading)):
            if not math.isfinite(v):
                raise ValueError(f"TrackFusion.start: {name} must be finite, got {v!r}")
        for name, v in (("heading_sigma", heading_sigma), ("position_sigma", position_sigma)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"TrackFusion.start: {name} must be finite and > 0, got {v!r}")
        s = self.settings
        params = gtsam.ISAM2Params()
        thresholds = gtsam.ISAM2ThresholdMap()
        thresholds.insert(("x", np.array([s.relinearize_position_m, s.relinearize_position_m, s.relinearize_heading_rad])))
        thresholds.insert(("a", np.array([s.relinearize_position_m, s.relinearize_position_m])))
        thresholds.insert(("s", np.array([s.relinearize_scale])))
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = int(s.relinearize_skip)
        params.findUnusedFactorSlots = True  # reuse slots of marginalised factors: bounded memory
        self._smoother = gtsam.IncrementalFixedLagSmoother(s.lag_s, params)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pose = gtsam.Pose2(x, y, heading)
        graph.add(gtsam.PriorFactorPose2(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(
            np.array([position_sigma, position_sigma, heading_sigma]))))
        values.insert(X(0), pose)
        stamps = {X(0): float(t)}
        if s.length_scale_sigma is not None:
            self._scale_n, self._scale_t0, self._scale = 0, float(t), 1.0
            values.insert(S(0), 1.0)
            graph.add(gtsam.PriorFactorDouble(S(0), 1.0, gtsam.noiseModel.Isotropic.Sigma(1, s.length_scale_sigma)))
            stamps[S(0)] = float(t)
        self._smoother.update(graph, values, stamps)
        self._hist.append(t=t, index=0, x=math.nan, y=math.nan, heading=math.nan, floor=floor, pdr_floor=floor,
                          length=0.0, duration=0.0)
        return self._publish()

    def add_step(self, ev: StepEvent) -> FusedPose:
        """Add one step; returns the live estimate of the new pose (what the service publishes).

        Raises ``ValueError`` for a step that is not after the previous pose or has non-finite
        length/time/sigmas, ``RuntimeError`` before :meth:`start`.
        """
        self._require_started()
        s = self.settings
        prev = len(self._hist) - 1
        t_prev = float(self._hist.col("t")[prev])
        for name in ("t", "length", "length_sigma"):
            v = getattr(ev, name)
            if not math.isfinite(v):
                raise ValueError(f"StepEvent #{ev.index} at t={ev.t}: {name} must be finite, got {v!r}")
        if ev.t <= t_prev:
            raise ValueError(f"StepEvent #{ev.index} at t={ev.t} s is not after the previous pose (t={t_prev} s)")
        if ev.length < 0:
            raise ValueError(f"StepEvent #{ev.index} at t={ev.t}: length must be >= 0, got {ev.length}")
        if self._last_index and ev.index != self._last_index + 1:
            self.events.append(FusionEvent(ev.t, "step_gap", "step", f"index {self._last_index} -> {ev.index}"))
        turn, turn_sigma = ev.heading_change, ev.heading_change_sigma
        if not (math.isfinite(turn) and math.isfinite(turn_sigma)):
            # no relative turn from the gyro: take it from the absolute heading, loosely
            turn = _wrap(ev.heading - self._live_pose.theta()) if math.isfinite(ev.heading) else 0.0
            turn_sigma = s.unknown_turn_sigma_rad
        turn_sigma = max(turn_sigma, s.turn_sigma_floor_rad)
        length = ev.length
        cov = step_covariance(length, max(ev.length_sigma, s.length_sigma_floor_m), turn_sigma, s.lateral_sigma_m)
        row = prev + 1
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        stamps = {X(row): float(ev.t)}
        step_noise = gtsam.noiseModel.Gaussian.Covariance(cov)
        if self._scale_n >= 0:
            if ev.t - self._scale_t0 >= s.length_scale_interval_s:
                self._open_scale(ev.t, graph, values)
            graph.add(scaled_step_factor(X(prev), X(row), S(self._scale_n), length, turn, step_noise))
            stamps[S(self._scale_n)] = float(ev.t)  # refresh: the scale stays while steps use it
            walked = length * self._scale
        else:
            graph.add(gtsam.BetweenFactorPose2(X(prev), X(row), gtsam.Pose2(length * math.cos(turn), length * math.sin(turn), turn), step_noise))
            walked = length
        values.insert(X(row), self._live_pose.compose(gtsam.Pose2(walked * math.cos(turn), walked * math.sin(turn), turn)))
        if (s.use_mag_heading and math.isfinite(ev.mag_heading) and math.isfinite(ev.mag_heading_sigma)
                and ev.mag_heading_sigma > 0 and ev.t - self._last_mag_t >= s.mag_min_interval_s):
            sigma = max(ev.mag_heading_sigma, s.mag_sigma_floor_rad)
            noise = robust(s.mag_kernel, s.mag_kernel_width, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
            graph.add(gtsam.PoseRotationPrior2D(X(row), gtsam.Rot2(ev.mag_heading), noise))
            self._last_mag_t = ev.t
        self._freeze_before(ev.t - s.lag_s)
        self._smoother.update(graph, values, stamps)
        self._hist.append(t=ev.t, index=ev.index, x=math.nan, y=math.nan, heading=math.nan,
                          floor=ev.floor + self._floor_offset, pdr_floor=ev.floor, length=length,
                          duration=ev.t - t_prev)
        self._steps += 1
        self._last_index = ev.index
        return self._publish()

    def add_fix(self, fix: CheckpointFix | GnssFix | UwbRange) -> FusedPose | None:
        """Attach ``fix`` to the pose of its time; returns the updated live pose, or None if rejected.

        A rejection is counted in :attr:`rejected` by reason (``before_start``, ``too_old``,
        ``gnss_accuracy``, ``gnss_gate``, ``uwb_gate``) and described in :attr:`events`.
        """
        self._require_started()
        if hasattr(fix, "factors"):  # a registered fix type that brings its own factors
            return self._add_own_factors(fix)
        what = _FIX_NAMES.get(type(fix))
        if what is None:
            raise TypeError(f"add_fix expects CheckpointFix, GnssFix or UwbRange, got {type(fix).__name__}")
        s = self.settings
        ts = self._hist.col("t")
        if fix.t < ts[0] - s.fix_before_start_tolerance_s:
            return self._reject(fix, what, "before_start", f"{ts[0] - fix.t:.1f} s before the track started")
        row = self._hist.nearest(fix.t)
        if row < self._window_start:
            return self._reject(fix, what, "too_old", f"{ts[-1] - fix.t:.1f} s old, window {s.lag_s:.0f} s")
        key = X(row)
        slip = self._slip(row, fix.t)
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        info: dict = {"row": row, "slip_m": slip}
        if isinstance(fix, CheckpointFix):
            sigma = math.hypot(max(fix.sigma, s.checkpoint_sigma_floor_m), slip)
            graph.add(gtsam.PoseTranslationPrior2D(key, np.array([fix.x, fix.y]), gtsam.noiseModel.Isotropic.Sigma(2, sigma)))
        elif isinstance(fix, GnssFix):
            if not fix.accuracy <= s.gnss_max_accuracy_m:
                return self._reject(fix, what, "gnss_accuracy", f"accuracy {fix.accuracy:.1f} m > {s.gnss_max_accuracy_m} m")
            sigma = math.hypot(fix.accuracy, slip)
            p, cov = self._position_marginal(key)
            nu = np.array([fix.x, fix.y]) - p
            d2 = float(nu @ np.linalg.solve(cov + sigma * sigma * np.eye(2), nu))
            info["mahalanobis2"] = d2
            if d2 > self._gnss_gate:
                return self._reject(fix, what, "gnss_gate", f"Mahalanobis² {d2:.1f} > {self._gnss_gate:.1f}", info)
            base = gtsam.noiseModel.Isotropic.Sigma(2, sigma)
            graph.add(gtsam.PoseTranslationPrior2D(key, np.array([fix.x, fix.y]),
                                                   robust(s.gnss_kernel, s.gnss_kernel_width, base)))
        else:
            sigma = math.hypot(max(fix.sigma, s.uwb_sigma_floor_m), slip)
            if math.isfinite(self._uwb_gate):
                p, cov = self._position_marginal(key)
                d = p - np.array([fix.anchor_x, fix.anchor_y])
                r_hat = float(np.hypot(*d))
                u = d / r_hat if r_hat > 1e-9 else np.zeros(2)
                var = float(u @ cov @ u) + sigma * sigma + s.uwb_anchor_sigma_m ** 2
                d2 = (fix.range - r_hat) ** 2 / var
                info["mahalanobis2"] = d2
                if d2 > self._uwb_gate:
                    return self._reject(fix, what, "uwb_gate", f"Mahalanobis² {d2:.1f} > {self._uwb_gate:.1f}", info)
            anchor = self._anchor(fix, float(ts[row]), graph, values, stamps)
            base = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
            graph.add(gtsam.RangeFactor2D(key, anchor, fix.range, robust(s.uwb_kernel, s.uwb_kernel_width, base)))
        self._smoother.update(graph, values, stamps)
        self._converge()
        self._fused = True
        if isinstance(fix, CheckpointFix) and fix.floor is not None:
            self._relabel_floor(row, int(fix.floor))
        self.events.append(FusionEvent(fix.t, "accepted", what, "", info))
        return self._publish()

    def _add_own_factors(self, fix) -> FusedPose | None:
        """A fix of a registered type: ``fix.factors(ctx)`` gives its factors on the pose of its
        time (``ctx.key``), or ``None`` to reject it (``ctx.reject(reason, detail)`` says why)."""
        what = getattr(fix, "source", type(fix).__name__)
        ts = self._hist.col("t")
        if fix.t < ts[0] - self.settings.fix_before_start_tolerance_s:
            return self._reject(fix, what, "before_start", f"{ts[0] - fix.t:.1f} s before the track started")
        row = self._hist.nearest(fix.t)
        if row < self._window_start:
            return self._reject(fix, what, "too_old", f"{ts[-1] - fix.t:.1f} s old, window {self.settings.lag_s:.0f} s")
        ctx = FixContext(X(row), self._slip(row, fix.t), self.settings, lambda: self._position_marginal(X(row)))
        factors = fix.factors(ctx)
        if not factors:
            return self._reject(fix, what, ctx.rejected[0] if ctx.rejected else "rejected",
                                ctx.rejected[1] if ctx.rejected else "", {"row": row})
        graph = gtsam.NonlinearFactorGraph()
        for f in factors:
            graph.add(f)
        self._smoother.update(graph, gtsam.Values(), {})
        self._converge()
        self._fused = True
        self.events.append(FusionEvent(fix.t, "accepted", what, "", {"row": row, "slip_m": ctx.slip}))
        return self._publish()

    # ---------------------------------------------------------------- outputs

    @property
    def live(self) -> FusedPose:
        """The latest published estimate (of the newest pose)."""
        self._require_started()
        return self._live

    def smoothed_track(self) -> dict[str, np.ndarray]:
        """Best estimate in hindsight of every pose so far: ``t, x, y, heading, floor, index``.

        Poses in the window come from the smoother now; older ones were frozen when they left it.
        """
        self._require_started()
        out = {k: self._hist.col(k).copy() for k in ("t", "x", "y", "heading", "floor", "index")}
        est = self._smoother.calculateEstimate()
        for row in range(self._window_start, len(self._hist)):
            p = est.atPose2(X(row))
            out["x"][row], out["y"][row], out["heading"][row] = p.x(), p.y(), p.theta()
        return out

    @property
    def window_variables(self) -> int:
        """Number of variables the smoother holds now (poses and anchors in the window)."""
        self._require_started()
        return len(self._smoother.timestamps())

    # ---------------------------------------------------------------- internals

    def _require_started(self) -> None:
        if self._smoother is None:
            raise RuntimeError("TrackFusion: call start() before adding steps or fixes")

    def _publish(self) -> FusedPose:
        row = len(self._hist) - 1
        key = X(row)
        pose = self._smoother.calculateEstimatePose2(key)
        marginal = self._smoother.marginalCovariance(key)
        rot = pose.rotation().matrix()
        cov = rot @ marginal[:2, :2] @ rot.T
        cov = 0.5 * (cov + cov.T)
        cov.setflags(write=False)
        self._live_pose = pose
        if self._scale_n >= 0:
            self._scale = float(self._smoother.calculateEstimateDouble(S(self._scale_n)))
        self._live = FusedPose(
            t=float(self._hist.col("t")[row]), index=int(self._hist.col("index")[row]), x=pose.x(), y=pose.y(),
            heading=_wrap(pose.theta()), cov=cov, floor=int(self._hist.col("floor")[row]), steps=self._steps,
            source="fused" if self._fused else "pdr", heading_sigma=float(math.sqrt(max(marginal[2, 2], 0.0))),
            length_scale=self._scale if self._scale_n >= 0 else math.nan,
        )
        return self._live

    def _converge(self) -> None:
        """More iSAM2 iterations after a fix until the newest pose moves less than ``fix_convergence_m``.

        iSAM2 takes one Gauss-Newton step per update; a fix that rotates the recent track by
        tens of degrees needs a few (measured: a 20° start-heading error corrected 60 m later
        leaves 2 m after one step, 8 cm after two, < 1 cm after four).
        """
        s = self.settings
        key = X(len(self._hist) - 1)
        before = self._smoother.calculateEstimatePose2(key)
        for _ in range(s.fix_extra_updates):
            self._smoother.update()
            now = self._smoother.calculateEstimatePose2(key)
            if math.hypot(now.x() - before.x(), now.y() - before.y()) < s.fix_convergence_m:
                break
            before = now

    def _open_scale(self, t: float, graph, values) -> None:
        """A new step-length scale variable, tied to the current one by a random walk σ = q·√Δt."""
        s = self.settings
        sigma = s.length_scale_walk * math.sqrt(t - self._scale_t0)
        old, new = S(self._scale_n), S(self._scale_n + 1)
        values.insert(new, self._scale)
        graph.add(gtsam.BetweenFactorDouble(old, new, 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma)))
        self._scale_n += 1
        self._scale_t0 = t

    def _position_marginal(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """Estimate and ENU 2x2 marginal covariance of a pose's position."""
        pose = self._smoother.calculateEstimatePose2(key)
        rot = pose.rotation().matrix()
        return np.array([pose.x(), pose.y()]), rot @ self._smoother.marginalCovariance(key)[:2, :2] @ rot.T

    def _freeze_before(self, cutoff: float) -> None:
        """Copy the estimates of poses the next update marginalises (timestamp < cutoff) to the history."""
        ts, n = self._hist.col("t"), len(self._hist)
        xs, ys, hs = self._hist.col("x"), self._hist.col("y"), self._hist.col("heading")
        while self._window_start < n and ts[self._window_start] < cutoff:
            p = self._smoother.calculateEstimatePose2(X(self._window_start))
            xs[self._window_start], ys[self._window_start], hs[self._window_start] = p.x(), p.y(), _wrap(p.theta())
            self._window_start += 1
        for anchor_id in [a for a, (_, stamp) in self._anchors.items() if stamp < cutoff]:
            del self._anchors[anchor_id]

    def _slip(self, row: int, t: float) -> float:
        """Distance (m) walked between time ``t`` and pose ``row``: its share of the step spanning ``t``."""
        ts, n = self._hist.col("t"), len(self._hist)
        if t > ts[row] and row + 1 < n:
            step = row + 1
        elif t < ts[row] and row > 0:
            step = row
        else:
            return 0.0  # before the start or after the latest pose: no step spans t
        length, duration = self._hist.col("length")[step], self._hist.col("duration")[step]
        return float(length * min(abs(t - ts[row]) / duration, 1.0))

    def _anchor(self, fix: UwbRange, stamp: float, graph, values, stamps) -> int:
        """Key of the anchor variable (reused while in the window; new ones get a tight prior)."""
        anchor_id = (fix.anchor, float(fix.anchor_x), float(fix.anchor_y))
        entry = self._anchors.get(anchor_id)
        if entry is None:
            key = A(self._n_anchors)
            self._n_anchors += 1
            point = np.array([fix.anchor_x, fix.anchor_y])
            values.insert(key, point)
            graph.add(gtsam.PriorFactorPoint2(key, point, gtsam.noiseModel.Isotropic.Sigma(2, self.settings.uwb_anchor_sigma_m)))
            entry = self._anchors[anchor_id] = [key, stamp]
        entry[1] = max(entry[1], stamp)
        stamps[entry[0]] = entry[1]  # refresh: the anchor leaves the window with its newest range
        return entry[0]

    def _relabel_floor(self, row: int, floor: int) -> None:
        floors, pdr = self._hist.col("floor"), self._hist.col("pdr_floor")
        offset = floor - int(pdr[row])
        end = len(self._hist) if row >= self._floor_fix_row else self._floor_fix_row
        floors[row:end] = pdr[row:end] + offset
        if row >= self._floor_fix_row:
            self._floor_offset = offset
            self._floor_fix_row = row

    def _reject(self, fix, what: str, reason: str, detail: str, info: dict | None = None) -> None:
        self.rejected[reason] += 1
        self.events.append(FusionEvent(fix.t, "rejected", what, f"{reason}: {detail}", info or {}))
        return None
