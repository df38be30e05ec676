"""Per-sample helpers whose value for a sample never depends on how the stream was cut into
frames: row norms, and whole turns of an unwrapped angle. (The trailing windows' statistics
are compiled in :mod:`pdr.window_kernels`.)
"""
from __future__ import annotations

import numpy as np


def norm3(a: np.ndarray) -> np.ndarray:
    """Row norms of an (n, 3) array, written out so each row's value never depends on the
    others (reductions may group sums by the array's size)."""
    a = np.asarray(a, float)
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])


def unwrap_turns(angle: np.ndarray, last_angle: float | None, last_turns: int) -> tuple[np.ndarray, int]:
    """Whole turns to add to each wrapped angle so the sequence has no jump over π.

    Returns integer turns ``K`` (continuing from the previous batch's ``last_angle`` and
    ``last_turns``) so that ``angle + 2π·K`` is continuous. Counting turns as integers, and
    multiplying once, keeps the unwrapped value of a sample the same however the stream was
    cut into batches (``np.unwrap`` accumulates 2π in floating point).
    """
    a = np.asarray(angle, float)
    prev = np.concatenate(([a[0] if last_angle is None else last_angle], a[:-1]))
    step = -np.round((a - prev) / (2 * np.pi)).astype(np.int64)
    return last_turns + np.cumsum(step), int(last_turns + step.sum())


def spans_gap(t: np.ndarray, t_prev: float, t_now: float, longest: float) -> bool:
    """Whether the sorted sample times ``t`` leave a hole longer than ``longest`` (s) between
    ``t_prev`` and ``t_now``, counting from the last sample at or before ``t_prev``: a step across
    it turned by what the gyro did not see (a paused sensor service, lost frames)."""
    i0 = max(int(np.searchsorted(t, t_prev, side="right")) - 1, 0)
    i1 = int(np.searchsorted(t, t_now, side="right"))
    return i1 - i0 > 1 and float((t[i0 + 1:i1] - t[i0:i1 - 1]).max()) > longest  # np.diff, without its wrapper


__all__ = ["norm3", "spans_gap", "unwrap_turns"]
