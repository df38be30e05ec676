"""Fuse one IPIN walk's PDR steps with checkpoints in a gtsam factor graph, and plot both tracks.

    python examples/fuse_a_walk.py [WALK] [--every 3] [--out fused.png]

The graph, in plain view (the service's is service/fusion/graph.py, with more evidence and a
fixed-lag smoother; this one is solved once, as a batch):

    prior ── x0 ──step── x1 ──step── x2 ── ... ── xn   x_k ∈ SE(2): (x, y, θ), θ the heading
                          │                        │
                      checkpoint               checkpoint

* a step k of length L_k turning by Δθ_k (the gyro's turn) is a BetweenFactorPose2 with
  Z = (L_k cos Δθ_k, L_k sin Δθ_k, Δθ_k): the step is walked along the new heading;
* every ``every``-th landmark is a checkpoint: a position factor on the pose of the last step
  before it; the other landmarks score the tracks.
"""
import argparse
import math
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from track_a_walk import WALK, plot, walk_steps

LATERAL_SIGMA_M = 0.1  # m, sideways slip of one step
CHECKPOINT_SIGMA_M = 0.5  # m, how well a walker stands on a surveyed landmark


def fuse_a_walk(walk: Path, out: Path, every: int = 3) -> dict:
    steps, lm_t, lx, ly = walk_steps(walk)
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()

    first = steps[0]  # the walk starts on landmark 1, facing its first step's compass heading
    x0 = gtsam.Pose2(lx[0], ly[0], first.heading)
    graph.add(gtsam.PriorFactorPose2(X(0), x0, gtsam.noiseModel.Diagonal.Sigmas([0.3, 0.3, first.heading_sigma])))
    initial.insert(X(0), x0)
    for k, s in enumerate(steps, start=1):
        turn = s.heading_change if k > 1 else 0.0
        turn_sigma = s.heading_change_sigma if k > 1 else 1e-3
        z = gtsam.Pose2(s.length * math.cos(turn), s.length * math.sin(turn), turn)
        noise = gtsam.noiseModel.Diagonal.Sigmas([s.length_sigma, LATERAL_SIGMA_M, turn_sigma])
        graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), z, noise))
        initial.insert(X(k), initial.atPose2(X(k - 1)).compose(z))  # dead reckoning: where the solver starts

    t = np.array([s.t for s in steps])
    at = np.searchsorted(t, lm_t, side="right")  # pose k = after step k: the last one before the landmark
    checkpoints = np.arange(every, len(lm_t), every) if every > 0 else np.array([], int)
    for i in checkpoints:
        graph.add(gtsam.PoseTranslationPrior2D(X(int(at[i])), gtsam.Pose2(lx[i], ly[i], 0.0),
                                               gtsam.noiseModel.Isotropic.Sigma(2, CHECKPOINT_SIGMA_M)))

    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    xy = {name: np.array([[v.atPose2(X(k)).x(), v.atPose2(X(k)).y()] for k in range(len(steps) + 1)])
          for name, v in (("pdr", initial), ("fused", result))}
    scored = np.setdiff1d(np.arange(1, len(lm_t)), checkpoints)
    error = {name: np.hypot(p[at[scored], 0] - lx[scored], p[at[scored], 1] - ly[scored]) for name, p in xy.items()}
    plot(out, f"{walk.name}: {len(checkpoints)} checkpoints", lx, ly,
         {f"steps and turns alone, median {np.median(error['pdr']):.1f} m": xy["pdr"].T,
          f"fused, median {np.median(error['fused']):.1f} m": xy["fused"].T}, checkpoints)
    return {"steps": len(steps), "poses": result.size(), "xy": xy, "error": error, "checkpoints": checkpoints,
            "checkpoint_poses": at[checkpoints], "landmarks": np.column_stack([lx, ly])}


if __name__ == "__main__":
    cli = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_argument("walk", nargs="?", type=Path, default=WALK)
    cli.add_argument("--every", type=int, default=3, help="every K-th landmark is a checkpoint (0: none)")
    cli.add_argument("--out", type=Path, default=Path("fused.png"))
    args = cli.parse_args()
    r = fuse_a_walk(args.walk, args.out, args.every)
    for name, e in r["error"].items():
        print(f"{name:6s} error at {len(e)} scored landmarks: median {np.median(e):.1f} m, max {e.max():.1f} m")
    print(f"{r['steps']} steps, {len(r['checkpoints'])} checkpoints; plot in {args.out}")
