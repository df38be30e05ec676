"""Trailing time windows over a sample stream: mean, standard deviation and maximum.

For each sample ``i`` the window holds the samples ``j <= i`` with ``T[j] > T[i] - window``
(``np.searchsorted(T, T[i] - window, side="right")`` is its first index). Every window is
summed on its own, oldest sample first, with the two-pass variance

    μ = (1/n) Σ x_j,      σ² = (1/n) Σ (x_j − μ)²,

so a sample's statistics depend only on the samples in its window, never on where a batch
began: a stream cut into frames of any size gives bit-identical results (running sums over a
cumulative array would not, and lose precision besides). The cost is O(n · samples per
window), a few hundred operations per sample at 100 Hz and a 1 s window.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def trailing_moments(T, X, start, window):  # pragma: no cover - compiled
    n, k = X.shape
    m = n - start
    mean = np.empty((m, k))
    std = np.empty((m, k))
    mx = np.empty((m, k))
    first = np.empty(m, np.int64)
    j0 = 0
    for i in range(start, n):
        lim = T[i] - window
        while j0 < i and T[j0] <= lim:
            j0 += 1
        cnt = i + 1 - j0
        r = i - start
        first[r] = j0
        for c in range(k):
            s = 0.0
            top = -np.inf
            for j in range(j0, i + 1):
                v = X[j, c]
                s += v
                if v > top:
                    top = v
            mu = s / cnt
            ss = 0.0
            for j in range(j0, i + 1):
                d = X[j, c] - mu
                ss += d * d
            mean[r, c] = mu
            std[r, c] = np.sqrt(ss / cnt)
            mx[r, c] = top
    return mean, std, mx, first


def window_moments(T: np.ndarray, X: np.ndarray, start: int, window: float):
    """Statistics of the trailing ``window`` (s) ending at each sample ``start..n-1``.

    ``T`` (n,) s increasing, ``X`` (n, k). Returns ``mean``, ``std``, ``max`` each
    (n − start, k) and ``first`` (n − start,), the index of each window's oldest sample.
    """
    T = np.ascontiguousarray(T, dtype=np.float64)
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] != T.shape[0]:
        raise ValueError(f"X must be (n, k) with n = len(T) = {T.shape[0]}, got {X.shape}")
    if not 0 <= start <= T.shape[0]:
        raise ValueError(f"start {start} outside [0, {T.shape[0]}]")
    return trailing_moments(T, X, int(start), float(window))


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


__all__ = ["trailing_moments", "window_moments", "norm3", "unwrap_turns"]


def spans_gap(t: np.ndarray, t_prev: float, t_now: float, longest: float) -> bool:
    """Whether the sorted sample times ``t`` leave a hole longer than ``longest`` (s) between
    ``t_prev`` and ``t_now``, counting from the last sample at or before ``t_prev``: a step across
    it turned by what the gyro did not see (a paused sensor service, lost frames)."""
    i0 = max(int(np.searchsorted(t, t_prev, side="right")) - 1, 0)
    i1 = int(np.searchsorted(t, t_now, side="right"))
    return i1 - i0 > 1 and float(np.max(np.diff(t[i0:i1]))) > longest
