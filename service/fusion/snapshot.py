"""Snapshots of a :class:`service.fusion.graph.TrackFusion` (pickling; issue 20).

gtsam's smoother cannot be pickled. A snapshot keeps everything else and restarts the graph
from the newest pose: a prior with that pose's full marginal covariance, the step-length
scale's and the PDR-heading offset's marginals, and the window's poses frozen at their current
estimates. The live pose goes on from exactly where it was; what is lost is the window's
correlations (a later fix corrects the pose it attaches to and what follows, not the poses
before the snapshot).
"""
from __future__ import annotations

import math

import gtsam
import numpy as np

from pdr.angles import wrap
from service.fusion.keys import S, X
from service.fusion.smoother import new_smoother


def fusion_state(self) -> dict:
    """``self``'s (a TrackFusion's) pickled state: everything but the smoother, which
    :func:`restore_fusion` restarts from the newest pose. ``self`` itself is not changed."""
    state = self.__dict__.copy()
    sm = state.pop("_smoother")
    state["_live_pose"] = (self._live_pose.x(), self._live_pose.y(), self._live_pose.theta())
    state["_restart"] = None
    if sm is None:
        return state
    row = len(self._hist) - 1
    est = sm.calculateEstimate()
    hist = self._hist.copy()
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
    off = self._heading.offset  # the newest PDR-heading offset, if it is still in the window
    restart["offset"] = None
    if off is not None and est.exists(off[0]):
        restart["offset"] = (off[0], off[1], float(est.atDouble(off[0])), float(sm.marginalCovariance(off[0])[0, 0]))
    state.update(_hist=hist, _window_start=row, _anchors={}, _restart=restart)
    return state


def restore_fusion(self, state: dict) -> None:
    """Make ``self`` (a new TrackFusion) from :func:`fusion_state`'s output; a new smoother."""
    restart = state.pop("_restart")
    self.__dict__.update(state)
    self._live_pose = gtsam.Pose2(*state["_live_pose"])
    self._smoother = None
    if restart is None:
        return
    self._smoother = new_smoother(self.settings)
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
    if restart.get("offset") is not None:  # the heading offset chain goes on from its newest state
        key, t, value, var = restart["offset"]
        values.insert(key, value)
        graph.add(gtsam.PriorFactorDouble(key, value, gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(max(var, 1e-12)))))
        stamps[key] = t
    self._smoother.update(graph, values, stamps)
