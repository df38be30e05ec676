"""Checkpoint fixes: the responder was at a surveyed point (an operator at a door, a tag reader).

Trusted, so no gate: a Gaussian position factor (:func:`.base.position_factor`) on the point of
the step walked at its time, σ = ``max(sigma, checkpoint_sigma_floor_m)`` (on the pose of its
time, σ grown by the slip, when that step has left the window). The seeds reset the position at a
checkpoint (seed 002 §2.10); as a prior in the factor graph it also straightens the history
walked before it. A translation prior leaves the heading free (a ``PriorFactorPose2`` with a
huge θ sigma would leak a made-up heading prior).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from service.fusion.fixes.base import (
    FixContext,
    FixRejected,
    finite,
    position_factor,
    positive,
)


@dataclass(frozen=True)
class CheckpointFix:
    """At ``(x, y)`` (m, local ENU) at ``t`` (s); ``floor`` (when given) anchors the motion
    model's floor (the tracker's business: the graph gets the position only)."""

    t: float
    x: float
    y: float
    floor: int | None = None
    sigma: float = 0.5
    name: str | None = None
    authoritative: bool = False  # placed by a logged-in operator: re-anchors whatever dead reckoning says
    source = "checkpoint"
    display = "snap"

    def __post_init__(self) -> None:
        finite("CheckpointFix", t=self.t, x=self.x, y=self.y)
        positive("CheckpointFix", sigma=self.sigma)
        if self.floor is not None and not isinstance(self.floor, numbers.Integral):
            raise ValueError(f"CheckpointFix.floor must be an int or None, got {self.floor!r}")

    def factors(self, ctx: FixContext):
        import gtsam

        sigma = math.hypot(max(self.sigma, ctx.settings.checkpoint_sigma_floor_m), ctx.position_slip)
        return [position_factor(ctx, (self.x, self.y), gtsam.noiseModel.Isotropic.Sigma(2, sigma))]


def to_local(msg, incident) -> CheckpointFix:
    """A named checkpoint of the incident config, or ``x``, ``y`` as given."""
    from service.protocol.incident import UnknownCheckpointError

    if msg.name is not None:
        try:
            cp = incident.checkpoint(msg.name)
        except UnknownCheckpointError as e:
            raise FixRejected("unknown_reference", str(e)) from None
        floor = msg.floor if msg.floor is not None else cp.floor
        return CheckpointFix(msg.t, cp.x, cp.y, floor, msg.sigma or cp.sigma_m, cp.name)
    return CheckpointFix(msg.t, msg.x, msg.y, msg.floor, msg.sigma or 0.5, None)
