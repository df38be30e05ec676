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
  turn Δθ is relative; absolute heading enters only as:
* **Heading** (optional, ``use_mag_heading``, on by default): the compass and the PDR's own
  heading as absolute evidence on θ_k, each kept from bending the track when it disagrees with
  the gyro (:mod:`service.fusion.heading_evidence`: a window gate on compass-minus-gyro, a
  wandering offset state on the PDR heading, a Cauchy kernel). Without it nothing in the graph
  bounds the gyro's heading drift between fixes (tests: 0.3°/step drift, ×5 the error without it).
* **Fixes** bring their own factors, one module per type in :mod:`service.fusion.fixes`:
  a checkpoint is a Gaussian position factor, GNSS the same behind four gates and a
  robust kernel, UWB a ``RangeFactor2D`` to an anchor variable; a registered type of one's own
  the same way (``fix.factors(ctx)``, see :class:`service.fusion.fixes.FixContext`).

**Time.** A fix inside a step whose two poses are in the window constrains the point of that
step walked at its time (``fix_interpolate``; :mod:`service.fusion.fix_timing`), so it does not
drag the nearer pose to where the walker was not. Otherwise (and for fix types that attach to a
pose, like UWB) it attaches to the step pose nearest in time, and the distance walked between
the fix time and that pose is added in quadrature to its sigma, so an interpolation error is
noise, not bias. A fix older than the window is rejected (``too_old``): the poses it would
correct are now a linearised marginal; attaching it to the oldest pose still in the window
would place it at the wrong point of the track, and faking it into the frozen history would not
reach the live estimate.

**Bounded cost.** gtsam's ``IncrementalFixedLagSmoother`` (iSAM2 with marginalisation) keeps
the last ``lag_s`` seconds of poses; older ones are marginalised into a linear prior on the
window and their last smoothed value is frozen in :class:`service.fusion.history.PoseHistory`.
Adding steps is a true incremental iSAM2 update (it re-eliminates only the top of the Bayes
tree); :meth:`TrackFusion.add_steps` puts several steps (their step and heading factors) in one
update, which the estimator does once per ``update_interval_s`` of walking; a fix is followed by up to ``fix_extra_updates`` more iSAM2 iterations
(until the newest pose settles) so a large correction of the past converges.

**Floors.** Each pose carries its step's floor: the motion model owns the floor (a checkpoint's
floor anchors the model, not the graph); :meth:`TrackFusion.set_floor` records a floor change
without a step (a lift).

**Published pose** (:mod:`service.fusion.published`): the graph's estimate of the newest pose
through a display filter that moves with each step and closes part of the gap to the graph, so
corrections do not make the marker zig-zag; its covariance rotated into ENU.

**Gaps** (:meth:`TrackFusion.add_gap`: an outage, lost frames, a new stream): the next step
gets an isotropic position sigma more, so the next fix re-anchors the track. **Snapshots**
(pickling, for restart recovery): :mod:`service.fusion.snapshot`.
"""
from __future__ import annotations

import math
from collections import Counter, deque

import gtsam
import numpy as np

from pdr.angles import wrap
from pdr.events import PoseEstimate, StepEvent
from service.fusion.fix_timing import slip, step_share
from service.fusion.fixes import FixContext
from service.fusion.heading_evidence import HeadingEvidence
from service.fusion.history import PoseHistory, smoothed_columns
from service.fusion.keys import A, S, X
from service.fusion.noise import step_covariance, step_turn
from service.fusion.published import (
    DisplayFilter,
    FusedPose,
    FusionEvent,
    enu_covariance,
)
from service.fusion.scaled_step import scaled_step_factor
from service.fusion.settings import FusionSettings
from service.fusion.smoother import new_smoother
from service.fusion.snapshot import fusion_state, restore_fusion

__all__ = ["FusedPose", "FusionEvent", "FusionSettings", "TrackFusion"]


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
        self._display = DisplayFilter(self.settings.display_gain)
        self._fused = False
        self._steps = 0
        self._last_index = 0
        self._live_floor: int | None = None  # floor set by set_floor() since the newest pose
        self._floor_marks: list[tuple[float, int, int]] = []  # (t, row, floor) of set_floor() calls
        self._heading = HeadingEvidence(self.settings)
        self._scale_n = -1  # index of the current step-length scale variable (-1: not estimated)
        self._scale_t0 = -math.inf  # s, when the current scale variable was opened
        self._scale = 1.0  # its latest estimate
        self._gap_sigma = 0.0  # m, position sigma the next step adds for a gap before it (add_gap)

    # pickling (restart recovery): everything but the smoother, which restarts from the newest pose
    __getstate__ = fusion_state
    __setstate__ = restore_fusion

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
        self._smoother = new_smoother(s)
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
        turn, turn_sigma = step_turn(ev, ev.t - t_prev, self._live_pose.theta(), s)
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
        if s.use_mag_heading:
            refused = self._heading.add(ev, turn, row, graph, values, stamps)
            if refused is not None:
                self.rejected["compass_window"] += 1
                self.events.append(FusionEvent(ev.t, "rejected", "compass", refused,
                                               {"spread_rad": self._heading.gate.last_spread}))
        self._freeze_before(ev.t - s.lag_s)
        self._hist.append(t=ev.t, index=ev.index, x=math.nan, y=math.nan, heading=math.nan,
                          floor=ev.floor, pdr_floor=ev.floor, length=length,
                          duration=ev.t - t_prev)
        self._steps += 1
        self._last_index = ev.index
        self._live_floor = None

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
        share = step_share(ts, self._window_start, fix.t, s.step_motion_s) if s.fix_interpolate else None
        ctx = FixContext(key=key, floor=floor, settings=s,
                         slip=slip(ts, self._hist.col("length"), self._hist.col("duration"), row, fix.t),
                         between=None if share is None else (X(share[0]), X(share[1]), share[2]),
                         position_marginal=lambda: self._position_marginal(key),
                         anchor=lambda name, x, y: self._anchor(name, x, y, float(ts[row]), graph, values, stamps),
                         state=self._fix_state.setdefault(what, {}), info={"row": row})
        ctx.info["slip_m"] = ctx.slip
        if share is not None:
            ctx.info["step_share"] = share[2]
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
        """Best estimate in hindsight of every pose so far (:func:`service.fusion.history.smoothed_columns`)."""
        self._require_started()
        return smoothed_columns(self._hist, self._smoother.calculateEstimate(), self._window_start, self._floor_marks)

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
        """The live pose of the newest pose: the graph's estimate through the display filter
        (:class:`service.fusion.published.DisplayFilter`); ``how`` is "snap" (start, a
        checkpoint, UWB: show the estimate), "step" (move by the steps, close a share of the gap)
        or "hold" (GNSS, a floor change: the position shown does not jump)."""
        row = len(self._hist) - 1
        key = X(row)
        pose = self._smoother.calculateEstimatePose2(key)
        shown = self._display.update(how, row, np.array([pose.x(), pose.y()]), self._position_of)
        marginal = self._smoother.marginalCovariance(key)
        self._live_pose = pose
        if self._scale_n >= 0:
            self._scale = float(self._smoother.calculateEstimateDouble(S(self._scale_n)))
        if how == "step":
            self._heading.refresh(self._smoother)
        self._live = PoseEstimate(
            t=float(self._hist.col("t")[row]), index=int(self._hist.col("index")[row]),
            x=float(shown[0]), y=float(shown[1]),
            heading=wrap(pose.theta()), cov=enu_covariance(pose, marginal),
            floor=int(self._hist.col("floor")[row]) if self._live_floor is None else self._live_floor, steps=self._steps,
            source="fused" if self._fused else "pdr", heading_sigma=float(math.sqrt(max(marginal[2, 2], 0.0))),
            length_scale=self._scale if self._scale_n >= 0 else math.nan,
        )
        return self._live

    def _position_of(self, row: int) -> np.ndarray:
        """(x, y) of pose ``row``: the smoother's estimate, or its frozen value once it left the window."""
        if row >= self._window_start:
            p = self._smoother.calculateEstimatePose2(X(row))
            return np.array([p.x(), p.y()])
        return np.array([self._hist.col("x")[row], self._hist.col("y")[row]])

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
