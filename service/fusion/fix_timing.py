"""Where on the track a fix of time t belongs: between which poses, and how far from the nearest.

The poses are the step times ``ts`` (s, increasing) of :class:`service.fusion.history.PoseHistory`.
A fix rarely falls on a pose: either the factor constrains the point of the step walked at its
time (:func:`step_share`, used by :func:`service.fusion.fixes.base.position_factor`) or it
attaches to the nearest pose with the distance walked in between as extra noise (:func:`slip`).
"""
from __future__ import annotations

import numpy as np


def step_share(ts: np.ndarray, window_start: int, t: float, step_motion_s: float) -> tuple[int, int, float] | None:
    """(row a, row b, α) of the step that holds time ``t``: the walker was at
    ``(1−α)·p_a + α·p_b`` then (the step a straight line). Inside a step (a before ``t``, b
    after), α is the share of the step walked by ``t``, the step taking at most ``step_motion_s``
    before its pose (after a stop the walker stood first). After the newest pose, mid-step, the
    walker is taken to carry on as in the last step: α = 1 + the share of a step like it walked
    since (at most one step). None when those poses are not in the window (rows below
    ``window_start``) or there is no step yet."""
    n = len(ts)
    b = int(np.searchsorted(ts, t, side="right"))
    if b >= n:
        b = n - 1
        if b - 1 < window_start or b < 1:
            return None
        d = min(float(ts[b] - ts[b - 1]), step_motion_s)
        return b - 1, b, 1.0 + min(max((t - ts[b]) / d, 0.0), 1.0)
    if b <= window_start:
        return None
    d = min(float(ts[b] - ts[b - 1]), step_motion_s)
    return b - 1, b, min(max((t - (ts[b] - d)) / d, 0.0), 1.0)


def slip(ts: np.ndarray, lengths: np.ndarray, durations: np.ndarray, row: int, t: float) -> float:
    """Distance (m) walked between time ``t`` and pose ``row``: its share of the step spanning ``t``
    (``lengths``/``durations``: each pose's step length, m, and time since the pose before, s)."""
    n = len(ts)
    if t > ts[row] and row + 1 < n:
        step = row + 1
    elif t < ts[row] and row > 0:
        step = row
    else:
        return 0.0  # before the start or after the latest pose: no step spans t
    return float(lengths[step] * min(abs(t - ts[row]) / durations[step], 1.0))
