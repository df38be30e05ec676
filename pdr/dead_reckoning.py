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
from dataclasses import dataclass

import numpy as np

from pdr.events import StepEvent


@dataclass(frozen=True)
class TrackPoint:
    t: float
    x: float
    y: float
    heading: float  # rad, ENU yaw
    floor: int
    steps: int
    cov: np.ndarray  # (2, 2) m²


class DeadReckoning:
    """``dr.start(t, x, y, floor)`` once, then ``dr.add_step(ev) -> TrackPoint``."""

    def __init__(self, position_sigma: float = 0.5):
        self._sigma0 = position_sigma
        self.point: TrackPoint | None = None

    def start(self, t: float, x: float, y: float, floor: int = 0, position_sigma: float | None = None) -> TrackPoint:
        s = self._sigma0 if position_sigma is None else position_sigma
        self.point = TrackPoint(t, x, y, math.nan, floor, 0, np.eye(2) * s * s)
        return self.point

    def add_step(self, ev: StepEvent) -> TrackPoint:
        p = self.point
        if p is None:
            raise RuntimeError("start() the track before adding steps")
        c, s = math.cos(ev.heading), math.sin(ev.heading)
        R = np.array([[c, -s], [s, c]])
        sig_h = ev.heading_sigma if math.isfinite(ev.heading_sigma) else math.pi
        Q = R @ np.diag([ev.length_sigma**2, (ev.length * sig_h) ** 2]) @ R.T  # blas-ok: 2x2, one step at a time
        self.point = TrackPoint(ev.t, p.x + ev.length * c, p.y + ev.length * s, ev.heading, ev.floor,
                                p.steps + 1, p.cov + Q)
        return self.point

    def move_to(self, x: float, y: float, sigma: float) -> TrackPoint:
        """A checkpoint: the walker is at (x, y) now (dead reckoning has no history to fix)."""
        p = self.point
        self.point = TrackPoint(p.t, x, y, p.heading, p.floor, p.steps, np.eye(2) * sigma * sigma)
        return self.point

