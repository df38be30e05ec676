"""What the fusion publishes: the fused pose (a :class:`pdr.events.PoseEstimate`), the decisions it
made, and the display filter.

**Display filter.** The live pose moves by each step and closes a share ``display_gain`` of the
gap to the graph's estimate per step (a complementary filter: the step's motion now, the
graph's correction over the next few steps), so a GNSS factor or a compass correction does not
make the marker jump step by step (the zig-zag of indoor GNSS); a checkpoint, which an operator
confirmed, and a UWB range (decimetres) move it at once. ``display_gain = 1`` shows the graph's
estimate itself. The smoothed track is the graph's own.

**Covariance.** gtsam's Pose2 marginal is in the pose's body frame (tangent space, retract
``T·Exp(ξ)``); the published 2x2 is rotated into ENU: ``Σ_w = R(θ) Σ_b[:2, :2] R(θ)ᵀ``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pdr.events import PoseEstimate


# The fused pose is the one pose type of the whole path (:class:`pdr.events.PoseEstimate`,
# with its ``index`` and ``length_scale``); the old name stays for readers of it, and for
# snapshots that name it.
FusedPose = PoseEstimate


@dataclass(frozen=True)
class FusionEvent:
    """Something the fusion decided about an input: accepted or rejected fix, a step gap."""

    t: float  # s, time of the input
    kind: str  # "accepted", "rejected", "step_gap", "restarted" (on a new heading)
    what: str  # "checkpoint", "gnss", "uwb", "step", "compass"
    detail: str = ""  # the rejection reason or a short note
    values: dict = field(default_factory=dict)


class DisplayFilter:
    """The position shown in the live pose (module docstring, *Display filter*)."""

    def __init__(self, gain: float):
        self.gain = float(gain)
        self.shown: np.ndarray | None = None
        self.row = 0  # history row of the pose published last

    def update(self, how: str, row: int, est: np.ndarray, last_estimate) -> np.ndarray:
        """The position to show for pose ``row`` whose graph estimate is ``est`` (m, ENU). ``how``:
        "snap" (show ``est``), "step" (move by the graph's motion since the pose published last,
        ``last_estimate(row_published_last)``, then close ``gain`` of the gap) or "hold" (keep)."""
        if how == "snap" or self.shown is None or self.gain >= 1.0:
            self.shown = est
        elif how == "step":
            moved = self.shown + (est - last_estimate(self.row))
            self.shown = moved + self.gain * (est - moved)
        self.row = row
        return self.shown


def enu_covariance(pose, marginal: np.ndarray) -> np.ndarray:
    """Read-only 2x2 ENU covariance of a Pose2 ``pose`` from its body-frame 3x3 ``marginal``."""
    rot = pose.rotation().matrix()
    cov = rot @ marginal[:2, :2] @ rot.T
    cov = 0.5 * (cov + cov.T)
    cov.setflags(write=False)
    return cov
