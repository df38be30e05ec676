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
* **Fixes** bring their own factors, one module per type in :mod:`service.fusion.fixes`:
  a checkpoint is a Gaussian ``PoseTranslationPrior2D``, GNSS the same behind four gates and a
  robust kernel, UWB a ``RangeFactor2D`` to an anchor variable; a registered type of one's own
  the same way (``fix.factors(ctx)``, see :class:`service.fusion.fixes.FixContext`).

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

**Floors.** Each pose carries its step's floor: the motion model owns the floor (a checkpoint's
floor anchors the model, not the graph); :meth:`TrackFusion.set_floor` records a floor change
without a step (a lift).

**Published pose.** The live pose moves by each step and closes a share ``display_gain`` of
the gap to the graph's estimate per step (a complementary filter: the step's motion now, the
graph's correction over the next few steps), so a GNSS factor or a compass correction does not
make the marker jump step by step (the zig-zag of indoor GNSS); a checkpoint, which an
operator confirmed, and a UWB range (decimetres) move it at once. ``display_gain = 1`` shows the graph's estimate itself.
The smoothed track is the graph's own.

**Gaps.** :meth:`TrackFusion.add_gap` (no samples for a while: an outage, lost frames, a new
stream): the next step's factor gets an isotropic position sigma more (the walk the gap may
hide), so the next fix re-anchors the track instead of being gated away.

**Snapshots.** gtsam's smoother cannot be pickled; a pickled :class:`TrackFusion` keeps
everything else and restarts its graph from the newest pose: a prior with that pose's full
marginal covariance (and the step-length scale's marginal), the window's poses frozen at their
current estimates. The live pose goes on from exactly where it was; what is lost is the
window's correlations (a later fix corrects the pose it attaches to and what follows, not the
poses before the snapshot).

**Covariance.** gtsam's Pose2 marginal is in the pose's body frame (tangent space, retract
``T·Exp(ξ)``); the published 2x2 is rotated into ENU: ``Σ_w = R(θ) Σ_b[:2, :2] R(θ)ᵀ``.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import gtsam
import numpy as np

from pdr.angles import wrap
from pdr.events import StepEvent, bearing_deg
from service.fusion.fixes import FixContext
from service.fusion.history import PoseHistory
from service.fusion.noise import robust, step_covariance
from service.fusion.scaled_step import scaled_step_factor
from service.fusion.settings import FusionSettings


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


class TrackFusion:
    """Fixed-lag factor-graph smoother of one responder's track (see the module docstring)."""

    def __init__(self, settings: FusionSettings | None = None):
        self.settings = settings or FusionSettings()
        s = self.settings
        self.rejected: Counter[str] = Counter()  # rejection reason -> count
        self.events: deque[FusionEvent] = deque(maxlen=s.max_events)
        self._fix_state: dict[str, dict] = {}  # per fix source: what its factors keep between fixes
        self._smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self._hist = PoseHistory()
        self._window_start = 0  # first history row still held by the smoother
        self._anchors: dict[tuple[str, float, float], list] = {}  # id -> [key, timestamp]
        self._n_anchors = 0
        self._live: FusedPose | None = None
        self._live_pose = gtsam.Pose2()
        self._shown: np.ndarray | None = None  # position shown in the live pose (display filter)
        self._shown_row = 0  # history row of the pose published last
        self._fused = False
        self._steps = 0
        self._last_index = 0
        self._live_floor: int | None = None  # floor set by set_floor() since the newest pose
        self._floor_marks: list[tuple[float, int, int]] = []  # (t, row, floor) of set_floor() calls
        self._last_mag_t = -math.inf
        self._chain = 0.0  # rad, the gyro's heading chain: the sum of the steps' turns
        self._mag_window: deque[tuple[float, float, float]] = deque()  # (t, cos, sin) of compass - chain offsets
        self._scale_n = -1  # index of the current step-length scale variable (-1: not estimated)
        self._scale_t0 = -math.inf  # s, when the current scale variable was opened
        self._scale = 1.0  # its latest estimate
        self._gap_sigma = 0.0  # m, position sigma the next step adds for a gap before it (add_gap)

    # ---------------------------------------------------------------- snapshots

    def __getstate__(self) -> dict:
        """Everything but the smoother, which :meth:`__setstate__` restarts from the newest pose
        (see the module docstring, *Snapshots*). The object itself is not changed."""
        state = self.__dict__.copy()
        sm = state.pop("_smoother")
        state["_live_pose"] = (self._live_pose.x(), self._live_pose.y(), self._live_pose.theta())
        state["_restart"] = None
        if sm is None:
            return state
        row = len(self._hist) - 1
        est = sm.calculateEstimate()
        hist = PoseHistory(max(len(self._hist), 1))
        for k in range(len(self._hist)):
            hist.append(**{c: self._hist.col(c)[k] for c in self._hist.columns})
        xs, ys, hs = hist.col("x"), hist.col("y"), hist.col("heading")
        for r in range(self._window_start, row + 1):  # the window's poses, frozen at their current estimates
            p = est.atPose2(X(r))
            xs[r], ys[r], hs[r] = p.x(), p.y(), wrap(p.theta())
        p = est.atPose2(X(row))
        restart = {"row": row, "t": float(self._hist.col("t")[row]), "pose": (p.x(), p.y(), p.theta()),
                   "cov": np.array(sm.marginalCovariance(X(row)), float), "scale": None}
        if self._scale_n >= 0:
            restart["scale"] = (self._scale_n, float(est.atDouble(S(self._scale_n))),
                                float(sm.marginalCovariance(S(self._scale_n))[0, 0]))
        state.update(_hist=hist, _window_start=row, _anchors={}, _restart=restart)
        return state

    def __setstate__(self, state: dict) -> None:
        restart = state.pop("_restart")
        self.__dict__.update(state)
        self._live_pose = gtsam.Pose2(*state["_live_pose"])
        self._smoother = None
        if restart is None:
            return
        self._smoother = gtsam.IncrementalFixedLagSmoother(self.settings.lag_s, self._isam_params())
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        key, pose = X(restart["row"]), gtsam.Pose2(*restart["pose"])
        cov = 0.5 * (restart["cov"] + restart["cov"].T)
        graph.add(gtsam.PriorFactorPose2(key, pose, gtsam.noiseModel.Gaussian.Covariance(cov)))
        values.insert(key, pose)
        stamps = {key: restart["t"]}
        if restart["scale"] is not None:
            n, value, var = restart["scale"]
            values.insert(S(n), value)
            graph.add(gtsam.PriorFactorDouble(S(n), value, gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(max(var, 1e-12)))))
            stamps[S(n)] = restart["t"]
        self._smoother.update(graph, values, stamps)

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
        self._smoother = gtsam.IncrementalFixedLagSmoother(s.lag_s, self._isam_params())
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
        return self._publish("snap")

    def _isam_params(self) -> gtsam.ISAM2Params:
        s = self.settings
        params = gtsam.ISAM2Params()
        thresholds = gtsam.ISAM2ThresholdMap()
        thresholds.insert(("x", np.array([s.relinearize_position_m, s.relinearize_position_m, s.relinearize_heading_rad])))
        thresholds.insert(("a", np.array([s.relinearize_position_m, s.relinearize_position_m])))
        thresholds.insert(("s", np.array([s.relinearize_scale])))
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = int(s.relinearize_skip)
        params.findUnusedFactorSlots = True  # reuse slots of marginalised factors: bounded memory
        return params

    def add_gap(self, sigma_m: float) -> None:
        """No samples for a while before the next step: that step adds an isotropic position
        sigma of ``sigma_m`` (m; the walk the gap may hide), so the next fix can re-anchor."""
        if not (math.isfinite(sigma_m) and sigma_m >= 0):
            raise ValueError(f"add_gap: sigma_m must be finite and >= 0, got {sigma_m!r}")
        self._gap_sigma = math.hypot(self._gap_sigma, sigma_m)

    def add_step(self, ev: StepEvent) -> FusedPose:
        """Add one step; returns the live estimate of the new pose (what the service publishes).

        Raises ``ValueError`` for a step that is not after the previous pose or has non-finite
        length/time/sigmas, ``RuntimeError`` before :meth:`start`.
        """
        return self.add_steps([ev])

    def add_steps(self, events: list[StepEvent]) -> FusedPose:
        """Several steps in one iSAM2 update (the same factors as one :meth:`add_step` each);
        returns the live estimate of the newest pose. One update per second of walking instead of
        one per step is what :class:`service.fusion.estimators.FusionEstimator` does (issue 15)."""
        self._require_started()
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        try:
            for ev in events:
                self._stage_step(ev, graph, values, stamps)
        finally:  # the steps staged before a bad one stay consistent with the history
            if stamps:
                self._smoother.update(graph, values, stamps)
        return self._publish("step")

    def _stage_step(self, ev: StepEvent, graph, values, stamps) -> None:
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
            turn = wrap(ev.heading - self._live_pose.theta()) if math.isfinite(ev.heading) else 0.0
            turn_sigma = s.unknown_turn_sigma_rad
        turn_sigma = math.hypot(turn_sigma, s.turn_walk * math.sqrt(max(ev.t - t_prev, 0.0)))
        if ev.on_stairs:
            turn_sigma = math.hypot(turn_sigma, s.stairs_turn_sigma_rad)
        turn_sigma = max(turn_sigma, s.turn_sigma_floor_rad)
        length = ev.length
        cov = step_covariance(length, max(ev.length_sigma, s.length_sigma_floor_m), turn_sigma, s.lateral_sigma_m)
        if self._gap_sigma > 0:  # a gap before this step: the position may have moved anywhere near (add_gap)
            cov = cov + np.diag([self._gap_sigma ** 2, self._gap_sigma ** 2, 0.0])
            self.events.append(FusionEvent(ev.t, "gap", "step", f"position sigma +{self._gap_sigma:.1f} m"))
            self._gap_sigma = 0.0
        row = prev + 1
        stamps[X(row)] = float(ev.t)
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
        self._live_pose = values.atPose2(X(row))  # the next staged step starts here
        self._chain += turn
        if (s.use_mag_heading and math.isfinite(ev.mag_heading) and math.isfinite(ev.mag_heading_sigma)
                and ev.mag_heading_sigma > 0 and ev.t - self._last_mag_t >= s.mag_min_interval_s
                and self._compass_agrees(ev)):
            sigma = max(ev.mag_heading_sigma, s.mag_sigma_floor_rad)
            noise = robust(s.mag_kernel, s.mag_kernel_width, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
            graph.add(gtsam.PoseRotationPrior2D(X(row), gtsam.Rot2(ev.mag_heading), noise))
            self._last_mag_t = ev.t
        self._freeze_before(ev.t - s.lag_s)
        self._hist.append(t=ev.t, index=ev.index, x=math.nan, y=math.nan, heading=math.nan,
                          floor=ev.floor, pdr_floor=ev.floor, length=length,
                          duration=ev.t - t_prev)
        self._steps += 1
        self._last_index = ev.index
        self._live_floor = None

    def _compass_agrees(self, ev: StepEvent) -> bool:
        """Does the compass turn with the gyro over the last ``mag_window_s``? The offset between
        the compass heading and the gyro chain is constant in a uniform field, whatever the
        walker does; walking through a disturbance bends the field from metre to metre, which the
        0.5 s epochs of the PDR cannot see. A step whose window's offsets spread more than
        ``mag_window_gate_rad`` (circular standard deviation) gives no compass factor; each such
        step is a ``compass_window`` event."""
        s = self.settings
        offset = wrap(ev.mag_heading - self._chain)
        w = self._mag_window
        w.append((ev.t, math.cos(offset), math.sin(offset)))
        while w and w[0][0] < ev.t - s.mag_window_s:
            w.popleft()
        if not math.isfinite(s.mag_window_gate_rad) or len(w) < s.mag_window_min_steps:
            return True
        c = sum(x[1] for x in w) / len(w)
        sn = sum(x[2] for x in w) / len(w)
        spread = math.sqrt(-2.0 * math.log(min(max(math.hypot(c, sn), 1e-12), 1.0)))
        if spread <= s.mag_window_gate_rad:
            return True
        self.rejected["compass_window"] += 1
        self.events.append(FusionEvent(ev.t, "rejected", "compass", f"compass_window: spread {math.degrees(spread):.1f}°",
                                       {"spread_rad": spread}))
        return False

    def set_floor(self, t: float, floor: int) -> FusedPose:
        """The responder changed floor at ``t`` without a step (a lift): the newest pose is
        published again on ``floor``, and the smoothed track gets a point there at ``t``."""
        self._require_started()
        self._live_floor = int(floor)
        self._floor_marks.append((float(t), len(self._hist) - 1, int(floor)))
        return self._publish("hold")

    def add_fix(self, fix) -> FusedPose | None:
        """Attach ``fix`` to the pose of its time; returns the updated live pose, or None if rejected.

        The fix gives its own factors (``fix.factors(ctx)``, :mod:`service.fusion.fixes`): a
        checkpoint, a GNSS position, a UWB range or a registered type of one's own. A rejection
        is counted in :attr:`rejected` by reason (``before_start``, ``too_old``, and the fix's
        own: ``gnss_accuracy``, ``gnss_gate``, ``uwb_gate``, ...) and described in :attr:`events`.
        """
        self._require_started()
        if not callable(getattr(fix, "factors", None)):
            raise TypeError(f"add_fix expects a fix with factors(ctx), got {type(fix).__name__}")
        what = getattr(fix, "source", type(fix).__name__)
        s = self.settings
        ts = self._hist.col("t")
        if fix.t < ts[0] - s.fix_before_start_tolerance_s:
            return self._reject(fix, what, "before_start", f"{ts[0] - fix.t:.1f} s before the track started")
        row = self._hist.nearest(fix.t)
        if row < self._window_start:
            return self._reject(fix, what, "too_old", f"{ts[-1] - fix.t:.1f} s old, window {s.lag_s:.0f} s")
        key = X(row)
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        floor = int(self._hist.col("floor")[row])
        if self._live_floor is not None and row == len(self._hist) - 1:
            floor = self._live_floor  # moved floor since the newest step (a lift)
        ctx = FixContext(key=key, floor=floor, slip=self._slip(row, fix.t), settings=s,
                         position_marginal=lambda: self._position_marginal(key),
                         anchor=lambda name, x, y: self._anchor(name, x, y, float(ts[row]), graph, values, stamps),
                         state=self._fix_state.setdefault(what, {}), info={"row": row})
        ctx.info["slip_m"] = ctx.slip
        factors = fix.factors(ctx)
        if not factors:
            reason, detail = ctx.rejected or ("rejected", "the fix gave no factor")
            return self._reject(fix, what, reason, detail, ctx.info)
        for f in factors:
            graph.add(f)
        self._smoother.update(graph, values, stamps)
        self._converge()
        self._fused = True
        self.events.append(FusionEvent(fix.t, "accepted", what, "", ctx.info))
        return self._publish(getattr(fix, "display", "hold"))

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
        if self._floor_marks:  # a floor change without a step: the pose before it again, on the new floor
            rows = np.array([m[1] for m in self._floor_marks])
            at = np.searchsorted(np.arange(len(self._hist)), rows, side="right")
            for k in ("x", "y", "heading", "index"):
                out[k] = np.insert(out[k], at, out[k][rows])
            out["t"] = np.insert(out["t"], at, [max(m[0], out["t"][r]) for m, r in zip(self._floor_marks, rows)])
            out["floor"] = np.insert(out["floor"], at, [m[2] for m in self._floor_marks])
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

    def _publish(self, how: str) -> FusedPose:
        """The live pose of the newest pose. Its position is the graph's estimate passed through
        the display filter (module docstring, *Published pose*): ``how`` is "snap" (start, a
        checkpoint, UWB: show the estimate), "step" (move by the step, close a share of the gap) or
        "hold" (GNSS, a floor change: the position shown does not jump)."""
        row = len(self._hist) - 1
        key = X(row)
        pose = self._smoother.calculateEstimatePose2(key)
        est = np.array([pose.x(), pose.y()])
        if how == "snap" or self._shown is None or self.settings.display_gain >= 1.0:
            self._shown = est
        elif how == "step":
            last = self._shown_row  # the pose published last: the step before, or before a batch of steps
            if last >= self._window_start:
                prev = self._smoother.calculateEstimatePose2(X(last))
                prev_xy = np.array([prev.x(), prev.y()])
            else:  # a long stop: the previous pose has left the window, its last estimate is frozen
                prev_xy = np.array([self._hist.col("x")[last], self._hist.col("y")[last]])
            moved = self._shown + (est - prev_xy)
            self._shown = moved + self.settings.display_gain * (est - moved)
        self._shown_row = row
        marginal = self._smoother.marginalCovariance(key)
        rot = pose.rotation().matrix()
        cov = rot @ marginal[:2, :2] @ rot.T
        cov = 0.5 * (cov + cov.T)
        cov.setflags(write=False)
        self._live_pose = pose
        if self._scale_n >= 0:
            self._scale = float(self._smoother.calculateEstimateDouble(S(self._scale_n)))
        self._live = FusedPose(
            t=float(self._hist.col("t")[row]), index=int(self._hist.col("index")[row]),
            x=float(self._shown[0]), y=float(self._shown[1]),
            heading=wrap(pose.theta()), cov=cov,
            floor=int(self._hist.col("floor")[row]) if self._live_floor is None else self._live_floor, steps=self._steps,
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
            xs[self._window_start], ys[self._window_start], hs[self._window_start] = p.x(), p.y(), wrap(p.theta())
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

    def _anchor(self, name: str, x: float, y: float, stamp: float, graph, values, stamps) -> int:
        """Key of a surveyed point's variable (reused while in the window; new ones get a tight prior)."""
        anchor_id = (name, float(x), float(y))
        entry = self._anchors.get(anchor_id)
        if entry is None:
            key = A(self._n_anchors)
            self._n_anchors += 1
            point = np.array([x, y])
            values.insert(key, point)
            graph.add(gtsam.PriorFactorPoint2(key, point, gtsam.noiseModel.Isotropic.Sigma(2, self.settings.uwb_anchor_sigma_m)))
            entry = self._anchors[anchor_id] = [key, stamp]
        entry[1] = max(entry[1], stamp)
        stamps[entry[0]] = entry[1]  # refresh: the anchor leaves the window with its newest range
        return entry[0]

    def _reject(self, fix, what: str, reason: str, detail: str, info: dict | None = None) -> None:
        self.rejected[reason] += 1
        self.events.append(FusionEvent(fix.t, "rejected", what, f"{reason}: {detail}", info or {}))
        return None
