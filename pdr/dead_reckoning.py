"""Dead reckoning alone: positions from step events, the baseline the fusion must beat.

Each step moves the walker by its length along its heading (seed 000 eq. 2.1; seed 002
eq. 30):

    x_k = x_{k-1} + L_k cos ψ_k,    y_k = y_{k-1} + L_k sin ψ_k

with ψ the ENU yaw (counter-clockwise from East). The position uncertainty grows by the
step's own: along track σ_L, across track L·σ_ψ, added as a 2x2 covariance rotated into
ENU — a first-order propagation that ignores the correlation of heading errors between
steps (so it is optimistic on long straight legs; the factor graph does better).
"""
from __future__ import annotations

import math

import numpy as np

from pdr.events import PoseEstimate, StepEvent


class DeadReckoning:
    """``dr.start(t, x, y, floor)`` once, then ``dr.add_step(ev) -> PoseEstimate``."""

    def __init__(self, position_sigma: float = 0.5):
        self._sigma0 = position_sigma
        self.point: PoseEstimate | None = None

    def start(self, t: float, x: float, y: float, floor: int = 0, position_sigma: float | None = None) -> PoseEstimate:
        s = self._sigma0 if position_sigma is None else position_sigma
        self.point = PoseEstimate(t, x, y, math.nan, np.eye(2) * s * s, floor, 0)
        return self.point

    def add_step(self, ev: StepEvent) -> PoseEstimate:
        p = self.point
        if p is None:
            raise RuntimeError("start() the track before adding steps")
        c, s = math.cos(ev.heading), math.sin(ev.heading)
        R = np.array([[c, -s], [s, c]])
        sig_h = ev.heading_sigma if math.isfinite(ev.heading_sigma) else math.pi
        Q = R @ np.diag([ev.length_sigma**2, (ev.length * sig_h) ** 2]) @ R.T  # blas-ok: 2x2, one step at a time
        self.point = PoseEstimate(ev.t, p.x + ev.length * c, p.y + ev.length * s, ev.heading, p.cov + Q, ev.floor,
                                  p.steps + 1, p.source, ev.heading_sigma)
        return self.point

    def move_to(self, x: float, y: float, sigma: float) -> PoseEstimate:
        """A checkpoint: the walker is at (x, y) now (dead reckoning has no history to fix)."""
        p = self.point
        self.point = PoseEstimate(p.t, x, y, p.heading, np.eye(2) * sigma * sigma, p.floor, p.steps, "fused",
                                  p.heading_sigma)
        return self.point

