"""Track estimators: steps and fixes in, a :class:`pdr.events.PoseEstimate` out, behind one protocol.

=========  ====================================================================  ==============
name       what                                                                  fixes it uses
=========  ====================================================================  ==============
``fusion`` gtsam fixed-lag factor graph (:class:`service.fusion.graph.TrackFusion`) all
``dr``     dead reckoning alone (:class:`pdr.dead_reckoning.DeadReckoning`): the   checkpoints
           baseline the fusion must beat; a checkpoint moves it
=========  ====================================================================  ==============

A new estimator (a particle filter on the floor plan, say) is one class with these methods and
one :func:`register_estimator` call; the tracker picks it by ``TrackerSettings.engine``.
"""
from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from pdr.angles import wrap
from pdr.dead_reckoning import DeadReckoning
from pdr.events import PoseEstimate, StepEvent
from service.fusion.dead_reckoning import dr_propagate
from service.fusion.fixes import CheckpointFix
from service.fusion.published import FusionEvent


class FixOutcome(NamedTuple):
    """What an estimator did with a fix: ``verdict`` is ``applied`` (``pose`` is the new live
    estimate), ``rejected`` (a gate refused it: ``reason``) or ``unused`` (nothing in this
    estimator can use it, e.g. GNSS in dead reckoning). ``earlier``: a fix refused before
    (``walk_gate``) that this one showed was right, taken into the graph first (a turn:
    :mod:`service.fusion.walk_gate`); its refusal is withdrawn."""

    verdict: str
    pose: PoseEstimate | None = None
    reason: str = ""
    earlier: object | None = None


class TrackEstimator(Protocol):
    """One responder's track from the moment it is placed."""

    def start(self, t: float, x: float, y: float, heading: float, heading_sigma: float, position_sigma: float,
              floor: int) -> None: ...

    def add_step(self, ev: StepEvent) -> PoseEstimate: ...

    def add_fix(self, fix) -> FixOutcome: ...

    def add_gap(self, sigma_m: float) -> None:
        """No samples for a while before the next step: widen that step's position by
        ``sigma_m`` (m), so a fix after the gap re-anchors the track."""
        ...

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        """The responder changed floor at ``t`` without a step (a lift): the newest pose again,
        on ``floor``."""
        ...

    def smoothed_track(self) -> dict[str, np.ndarray] | None:
        """The best estimate in hindsight of every pose so far (columns ``t, x, y, heading,
        floor``), or None when the estimator keeps no history."""
        ...


class DeadReckoningEstimator:
    """Dead reckoning alone; a checkpoint moves the walker, other fixes are unused."""

    def __init__(self, settings=None):
        self._dr = DeadReckoning()

    def start(self, t, x, y, heading, heading_sigma, position_sigma, floor) -> None:
        self._dr.start(t, x, y, floor, position_sigma)

    def add_step(self, ev: StepEvent) -> PoseEstimate:
        return self._dr.add_step(ev)

    def add_gap(self, sigma_m: float) -> None:
        """Dead reckoning keeps no uncertainty to widen: a checkpoint moves it whatever it is."""

    def add_fix(self, fix) -> FixOutcome:
        if isinstance(fix, CheckpointFix):
            return FixOutcome("applied", self._dr.move_to(fix.x, fix.y, fix.sigma))
        return FixOutcome("unused", reason=f"{type(fix).__name__} is not used by dead reckoning")

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        p = self._dr.point
        self._dr.point = dataclasses.replace(p, t=max(p.t, t), floor=floor)
        return self._dr.point

    def smoothed_track(self) -> None:
        return None


class FusionEstimator:
    """The gtsam factor graph (:class:`service.fusion.graph.TrackFusion`) behind the protocol,
    its updates paid per second of walking, not per step (issue 15).

    Steps wait in a batch until one is ``update_interval_s`` after the last update (or a fix,
    a floor change or the end of the stream arrives); the batch then goes into the graph in one
    iSAM2 update (:meth:`TrackFusion.add_steps`: the same factors as one update per step). In
    between, the live pose is the last fused pose propagated by dead reckoning — each step
    walked along its heading change, scaled by the graph's step-length factor — with the
    covariance of ``(x, y, θ)`` grown by each step's noise (:func:`dr_propagate`). The batches
    depend on the steps' device times only, so the poses are the same whatever the rounds.

    **Cannot crash, cannot hide** (issue 32). Every fix is first judged against what the walk
    allows (:class:`service.fusion.walk_gate.WalkGate`); one held out never reaches the graph
    (``rejected``, reason ``walk_gate``). Any exception from the graph, or a pose that
    :meth:`WalkGate.diverged` calls impossible, restarts the track: a new graph from the
    reference (dead reckoning since the last trusted fix), the history so far kept for
    :meth:`smoothed_track`, the event counted in ``degraded`` with its time (``degraded_at``,
    device clock) and reason, which the core turns into the ``track_degraded`` alarm.
    """

    def __init__(self, settings=None):
        from service.fusion.graph import (
            TrackFusion,  # gtsam: loaded when a track starts
        )
        from service.fusion.walk_gate import WalkGate

        self._make = TrackFusion
        self.fusion = TrackFusion(settings)
        self.gate = WalkGate(self.fusion.settings)
        self._every = self.fusion.settings.update_interval_s
        self._steps = 0
        self._pending: list[StepEvent] = []
        self._last_update_t = -math.inf
        self._dr: tuple | None = None  # (t, x, y, θ, Σ as 6 floats, scale, source, floor) of the live pose
        self._past: dict[str, np.ndarray] | None = None  # smoothed track of the graphs before a restart
        self.degraded = 0  # restarts of the graph (an exception, a diverged pose)
        self.degraded_at = math.nan  # s, device time of the last one
        self.degraded_reason = ""

    def start(self, t, x, y, heading, heading_sigma, position_sigma, floor) -> None:
        self._precise_at_start = self.gate.precise_taken
        self.gate.start(t, x, y, position_sigma, floor, heading, heading_sigma)
        self._base(self.fusion.start(t, x, y, heading, heading_sigma, position_sigma, floor))

    def add_step(self, ev: StepEvent) -> PoseEstimate:
        self._steps = ev.index
        jumped = self._pdr_heading_jumped(ev)
        if jumped is not None:
            self._flush()
            fp = self._restart(jumped, self._dr[0], self._dr[7], failure=False,
                               heading=(wrap(ev.heading - ev.heading_change),
                                        max(ev.heading_sigma, self.fusion.settings.restart_heading_sigma_rad)))
            self._last_update_t = fp.t
            self._base(fp)
        self._prev_pdr_heading = ev.heading
        self.gate.add_step(ev, *self._heading_after(ev))
        self._pending.append(ev)
        if ev.t - self._last_update_t >= self._every:
            return self._pose(self._flush())
        return self._propagate(ev)

    _prev_pdr_heading = math.nan  # (class defaults: estimators pickled before them read as none)
    _precise_at_start = 0  # the walk gate's count of precise fixes taken when the graph (re)started

    def _pdr_heading_jumped(self, ev: StepEvent) -> str | None:
        """Why the graph should restart on the PDR's heading at step ``ev``, or None.

        The PDR's absolute heading moved by more than ``pdr_heading_jump_rad`` beyond the gyro's
        turn: its compass offset restarted, on a run of epochs that proved itself (pdr/heading.py,
        across a 45° turn or after 20 s). A graph that started on the PDR's earlier heading, or
        followed it, is then as far off, and its compass and PDR-heading factors, all that far
        from it, are what the Cauchy kernel ignores: it cannot turn by itself. Measured: T21r02
        under the robustness suite's phone50_steel draw, a start on steel (PDR heading σ 15°, then
        166° off), live p75 22.0 m against 3.0 m dead reckoning."""
        s = self.fusion.settings
        limit = s.pdr_heading_jump_rad
        prev = self._prev_pdr_heading
        if limit is None or not (math.isfinite(prev) and math.isfinite(ev.heading) and math.isfinite(ev.heading_change)
                                 and math.isfinite(ev.heading_change_sigma)):
            return None
        if not ev.heading_sigma < s.pdr_heading_max_sigma_rad or self.gate.precise_taken > self._precise_at_start:
            return None  # a graph with two precise positions knows its heading from them (K = 3: T53r02 +1.1 m)
        jump = wrap(ev.heading - prev - ev.heading_change)
        apart = wrap(ev.heading - self._heading_after(ev)[0])
        if abs(jump) > limit and abs(apart) > limit:
            return (f"the PDR's heading jumped {math.degrees(jump):.0f}° (its compass offset restarted); "
                    f"the graph's was {math.degrees(apart):.0f}° from it")
        return None

    def _heading_after(self, ev: StepEvent) -> tuple[float, float]:
        """(heading, sigma) (rad) the live pose walks step ``ev`` along (the graph's, turned by the
        gyro): the walk gate's dead reckoning follows it, as the PDR's own absolute heading drifts
        where the graph's compass and fixes do not."""
        th, cov = self._dr[3], self._dr[4]
        turn = ev.heading_change if math.isfinite(ev.heading_change) else (
            wrap(ev.heading - th) if math.isfinite(ev.heading) else 0.0)
        return wrap(th + turn), math.sqrt(cov[5]) if cov[5] > 0 else math.nan

    def flush(self) -> PoseEstimate | None:
        """The steps waiting for an update go into the graph now (end of the stream)."""
        return self._pose(self._flush()) if self._pending else None

    def _flush(self):
        events, self._pending = self._pending, []
        if not events:
            fp = self.fusion.live
            self._last_update_t = fp.t
            self._base(fp)
            return fp
        return self._guarded(lambda: self.fusion.add_steps(events), events[-1].t, events[-1].floor)

    def _guarded(self, update, t: float, floor: int):
        """``update()`` of the graph, its pose checked; on an exception or a diverged pose the
        track restarts from the reference (class docstring). Returns the graph's new pose."""
        try:
            fp = update()
            why = self.gate.diverged(fp)
        except Exception as e:  # gtsam's IndeterminateSystemException, a missing variable, ...
            why = f"{type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else ''}"
        if why is not None:
            fp = self._restart(why, t, floor)
        self._last_update_t = fp.t
        self._base(fp)
        return fp

    def _restart(self, why: str, t: float, floor: int, failure: bool = True,
                 heading: tuple[float, float] | None = None):
        """A new graph from dead reckoning since the last trusted fix; the old one's track kept.
        It starts on the reference's heading, or ``heading`` = (rad, sigma). A ``failure`` is
        counted in ``degraded`` (the track_degraded alarm); otherwise a ``restarted`` event."""
        old = self.fusion
        try:
            past = old.smoothed_track()
        except Exception:
            past = None
        if past is not None:
            ok = np.isfinite(past["x"]) & np.isfinite(past["y"])
            past = {k: v[ok] for k, v in past.items()}
            self._past = past if self._past is None else joined_tracks(self._past, past)
        p, walked = self.gate.point
        if heading is None:
            heading = (p.heading if math.isfinite(p.heading) else (self._dr[3] if self._dr else 0.0),
                       old.settings.restart_heading_sigma_rad)
        sigma = math.sqrt(max(float(np.linalg.eigvalsh(np.asarray(p.cov, float))[-1]), 0.0)) + self.gate.allowance(walked)
        s = old.settings
        self._precise_at_start = self.gate.precise_taken
        self.fusion = self._make(s)
        self.fusion.events.extend(old.events)
        self.fusion.rejected.update(old.rejected)
        if failure:
            self.degraded += 1
            self.degraded_at = max(t, p.t)
            self.degraded_reason = why
        else:
            self.fusion.events.append(FusionEvent(max(t, p.t), "restarted", "heading", why, {}))
        return self.fusion.start(max(t, p.t), p.x, p.y, wrap(heading[0]), heading[1],
                                 max(sigma, s.checkpoint_sigma_floor_m), floor)

    def _base(self, fp) -> None:
        c = np.asarray(fp.cov)
        hs = fp.heading_sigma if math.isfinite(fp.heading_sigma) else 0.0
        scale = fp.length_scale if math.isfinite(fp.length_scale) else 1.0
        self._dr = (fp.t, fp.x, fp.y, fp.heading, (float(c[0, 0]), float(c[0, 1]), 0.0, float(c[1, 1]), 0.0, hs * hs),
                    scale, fp.source, fp.floor)

    def _propagate(self, ev: StepEvent) -> PoseEstimate:
        t, x, y, th, cov, scale, source, _ = self._dr
        s = self.fusion.settings
        turn, turn_sigma = ev.heading_change, ev.heading_change_sigma
        if not (math.isfinite(turn) and math.isfinite(turn_sigma)):
            turn = wrap(ev.heading - th) if math.isfinite(ev.heading) else 0.0
            turn_sigma = s.unknown_turn_sigma_rad
        turn_sigma = max(turn_sigma, s.turn_sigma_floor_rad)
        length = ev.length * scale
        x, y, th, cov = dr_propagate(x, y, th, cov, length, max(ev.length_sigma, s.length_sigma_floor_m) * scale,
                                     turn, turn_sigma, s.lateral_sigma_m)
        self._dr = (ev.t, x, y, th, cov, scale, source, ev.floor)
        return self._live()

    def _live(self) -> PoseEstimate:
        t, x, y, th, c, _, source, floor = self._dr
        cov = np.array([[c[0], c[1]], [c[1], c[3]]])
        cov.setflags(write=False)
        return PoseEstimate(t, x, y, wrap(th), cov, floor, self._steps, source, math.sqrt(max(c[5], 0.0)))

    def add_gap(self, sigma_m: float) -> None:
        self.fusion.add_gap(sigma_m)
        self.gate.add_gap(sigma_m)

    def add_fix(self, fix) -> FixOutcome:
        if not callable(getattr(fix, "factors", None)):
            raise TypeError(f"add_fix expects a fix with factors(ctx), got {type(fix).__name__}")
        self._flush()
        verdict = self.gate.judge(fix)
        if not verdict.ok:
            self.fusion.rejected[verdict.reason] += 1
            self.fusion.events.append(FusionEvent(fix.t, "rejected", getattr(fix, "source", type(fix).__name__),
                                                  f"{verdict.reason}: {verdict.detail}", verdict.info or {}))
            return FixOutcome("rejected", reason=verdict.reason)
        earlier = verdict.earlier
        before = Counter(self.fusion.rejected)
        if earlier is not None:  # a fix held out before, which this one shows was right: the graph takes it first
            self._guarded(lambda: self.fusion.add_fix(earlier) or self.fusion.live, earlier.t, self._dr[7])
            after = Counter(self.fusion.rejected)
            if after != before:
                earlier = None  # the graph refused it after all: its refusal stands
            before = after
        degraded = self.degraded
        fp = self._guarded(lambda: self.fusion.add_fix(fix) or self.fusion.live, fix.t, self._dr[7])
        if self.degraded != degraded:  # the graph could not take it: held out, the track restarted
            self.fusion.rejected["estimator_error"] += 1
            return FixOutcome("rejected", reason="estimator_error")
        rejected = Counter(self.fusion.rejected) - before
        if rejected:
            return FixOutcome("rejected", reason=next(iter(rejected)))
        self.gate.take(fix, verdict)
        return FixOutcome("applied", self._pose(fp), earlier=earlier)

    def set_floor(self, t: float, floor: int) -> PoseEstimate:
        self._flush()
        return self._pose(self._guarded(lambda: self.fusion.set_floor(t, floor), t, floor))

    def smoothed_track(self) -> dict[str, np.ndarray]:
        """The graph's smoothed track (after the tracks of graphs that were restarted), and the
        steps waiting for the next update as dead reckoning from its newest pose (a query must not
        change when the graph updates)."""
        try:
            out = self.fusion.smoothed_track()
        except Exception:  # the graph failed since its last update: its newest pose is the live one
            out = {k: np.array([v], dtype=float if k not in ("floor", "index") else np.int64)
                   for k, v in zip(("t", "x", "y", "heading", "floor", "index"), (self._dr[0], self._dr[1], self._dr[2],
                                                                                  self._dr[3], self._dr[7], self._steps))}
        if self._past is not None:
            out = joined_tracks(self._past, out)
        if not self._pending:
            return out
        x, y, th = float(out["x"][-1]), float(out["y"][-1]), float(out["heading"][-1])
        scale = self._dr[5]
        rows = []
        for ev in self._pending:
            turn = ev.heading_change if math.isfinite(ev.heading_change) else 0.0
            x, y, th, _ = dr_propagate(x, y, th, _NO_COV, ev.length * scale, 0.0, turn, 0.0, 0.0)
            rows.append((ev.t, x, y, wrap(th), ev.floor, ev.index))
        extra = np.array(rows, float)
        for i, k in enumerate(("t", "x", "y", "heading", "floor", "index")):
            out[k] = np.concatenate([out[k], extra[:, i].astype(out[k].dtype)])
        return out

    def _pose(self, fp: PoseEstimate) -> PoseEstimate:
        """The graph's pose with the steps this estimator has taken (the graph counts its own)."""
        return dataclasses.replace(fp, steps=self._steps)


_NO_COV = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def joined_tracks(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Track ``a`` then the rows of ``b`` after its last time (a restarted graph's track after the old one's)."""
    keep = b["t"] > a["t"][-1] if len(a["t"]) else np.ones(len(b["t"]), bool)
    return {k: np.concatenate([a[k], np.asarray(b[k])[keep].astype(a[k].dtype)]) for k in a}


_ESTIMATORS: dict[str, Callable[..., TrackEstimator]] = {}


def register_estimator(name: str, factory: Callable[..., TrackEstimator]) -> None:
    """``factory(fusion_settings) -> TrackEstimator``, chosen by ``TrackerSettings.engine``."""
    _ESTIMATORS[name] = factory


def estimator_names() -> tuple[str, ...]:
    return tuple(_ESTIMATORS)


def make_estimator(name: str, settings=None) -> TrackEstimator:
    try:
        factory = _ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown track estimator {name!r}; choose one of {', '.join(_ESTIMATORS)}") from None
    return factory(settings)


register_estimator("fusion", FusionEstimator)
register_estimator("dr", DeadReckoningEstimator)
