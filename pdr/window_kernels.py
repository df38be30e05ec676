"""Trailing-window stillness tests, compiled: the gyro bias at standstill
(:func:`still_bias`, for :class:`pdr.heading.HeadingEstimator` and the engine's heading stage)
and the motionless windows of the motion state (:func:`motionless_windows`).

For each sample ``i`` the window holds the samples ``j <= i`` with ``T[j] > T[i] - window``.
A window that is tested is summed on its own, oldest sample first, with the two-pass variance

    μ = (1/n) Σ x_j,      σ² = (1/n) Σ (x_j − μ)²,

so a sample's decision depends only on the samples in its window, never on where a batch
began: a stream cut into frames of any size gives bit-identical results (running sums over
a cumulative array would not, and lose precision besides).

A window's standard deviation is needed only where it could pass: a window whose range is at
least √(2n)·σ_max cannot have σ < σ_max (σ ≥ range/√(2n) for any n samples), and a window
whose maximum passes a limit fails whatever its σ. Those are decided from exact sliding minima
and maxima (monotone deques, O(1) per sample), so the sums are paid only while the device is
nearly still. Conversely σ ≤ range/2 for any samples (Popoviciu's inequality), so a window
whose range is below 2·0.999·σ_max passes without its σ (the margin dwarfs the rounding of
the two-pass sums): only the means that are used are summed.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_RANGE_MARGIN = 1.01  # the bound's safety factor against rounding (relative errors of ~1e-13)
MOVING, MOTIONLESS, UNKNOWN = 0, 1, 2  # a window's verdict (motionless_windows)
_SURE_RANGE = 2.0 * 0.999  # a range below this many σ_max: σ < σ_max certainly, rounding included


@njit(cache=True, inline="always")
def _push(dq, head, tail, X, c, i, sign):
    """Monotone deque of indices for the max (sign 1) or min (sign -1) of column c."""
    while tail > head and sign * X[dq[tail - 1], c] <= sign * X[i, c]:
        tail -= 1
    dq[tail] = i
    return tail + 1


@njit(cache=True)
def _first_in_window(T, i, window):  # pragma: no cover - compiled
    lim = T[i] - window
    j = 0
    while j < i and T[j] <= lim:
        j += 1
    return j


@njit(cache=True)
def _all_moving(T, X, start, window, gyr_std, acc_std):  # pragma: no cover - compiled
    """True when no window ending at samples ``start..n-1`` can be still: the samples every one
    of them holds, ``[j0(n−1), start]``, already spread too far in some column for any window of
    at most ``n − j0(start)`` samples (σ ≥ range/√(2n))."""
    n = T.shape[0]
    a = _first_in_window(T, n - 1, window)
    if a > start:
        return False
    cnt = n - _first_in_window(T, start, window)
    bound = _RANGE_MARGIN * math.sqrt(2.0 * cnt)
    for c in range(X.shape[1]):
        lo = X[a, c]
        hi = X[a, c]
        for j in range(a + 1, start + 1):
            v = X[j, c]
            if v < lo:
                lo = v
            if v > hi:
                hi = v
        if hi - lo >= bound * (gyr_std if c < 3 else acc_std):
            return True
    return False


SUMS_MAX_SAMPLES = 300_000  # a call of more samples (50 min at 100 Hz in one batch) pays the two passes


@njit(cache=True)
def _sigma_verdict(s1, s2, t1, t2, cnt, limits):  # pragma: no cover - compiled
    """Rule on the window's σ per column from running sums, where they certainly agree with the
    two-pass σ: -1 some σ ≥ its limit, 1 every σ < its limit, 0 undecided (the sums decide).

    ``s1``, ``s2``: Σ y, Σ y² over the window, ``y = x − shift`` (a constant per column), kept
    by adding each sample as it enters and subtracting it as it leaves; ``t1``, ``t2``: Σ |y|,
    Σ y² over every sample of the call, which bound the magnitude of every partial sum. Each of
    those additions errs by at most ε = 2⁻⁵³ of such a magnitude, so after k of them
    ``|s2 − Σ y²| ≤ (k + 4) ε t2`` and likewise for ``s1``; for any window of a call (k below
    10⁶) that is far below ``1e-9 (t2 / n + (t1 / n)²)``, the tolerance used here on
    ``σ² ≈ s2/n − (s1/n)²``. The two-pass σ itself is within a relative ~n ε of the true one, so
    a margin of 1e-9 of the limit² covers it: an answer here is the two-pass answer."""
    verdict = 1
    for c in range(limits.shape[0]):
        var = s2[c] / cnt - (s1[c] / cnt) ** 2
        tol = 1e-9 * (t2[c] / cnt + (t1[c] / cnt) ** 2) + 1e-300
        lim2 = limits[c] * limits[c]
        if var - tol > lim2 * (1.0 + 1e-9):
            return -1
        if not var + tol < lim2 * (1.0 - 1e-9):
            verdict = 0
    return verdict


@njit(cache=True)
def still_bias(T, X, start, window, gyr_std, gyr_max, acc_std, bias0):  # pragma: no cover - compiled
    """Gyro bias for each sample ``start..n-1`` (:class:`pdr.heading.HeadingEstimator`, 1).

    ``X`` (n, 4) holds the gyro axes and the specific-force norm. A sample is *still* when its
    trailing ``window`` (s) is at least 90 % full and, over it, every gyro axis varies less
    than ``gyr_std``, the gyro mean is shorter than ``gyr_max`` and the force norm varies less
    than ``acc_std``. Each sample uses the gyro mean of the latest still sample before it,
    else ``bias0``. Returns the biases (n − start, 3), the still flags, the bias after the
    last sample."""
    n = T.shape[0]
    m = n - start
    out = np.empty((m, 3))
    still = np.zeros(m, np.bool_)
    cur = bias0.copy()
    if m > 0 and _all_moving(T, X, start, window, gyr_std, acc_std):
        for r in range(m):
            out[r, 0], out[r, 1], out[r, 2] = cur[0], cur[1], cur[2]
        return out, still, cur
    dqmax = np.empty((4, n), np.int64)
    dqmin = np.empty((4, n), np.int64)
    hmax = np.zeros(4, np.int64)
    tmax = np.zeros(4, np.int64)
    hmin = np.zeros(4, np.int64)
    tmin = np.zeros(4, np.int64)
    j0 = 0
    full_s = 0.9 * window
    g = np.empty(4)
    sd = np.empty(4)
    limits = np.array([gyr_std, gyr_std, gyr_std, acc_std])
    # running sums of the window, only to rule on σ far from its limit (_sigma_verdict)
    shift, t1, t2 = X[0].copy(), np.zeros(4), np.zeros(4)
    for i in range(n):
        for c in range(4):
            y = X[i, c] - shift[c]
            t1[c] += abs(y)
            t2[c] += y * y
    w1, w2 = np.zeros(4), np.zeros(4)  # Σ y, Σ y² over the window
    sums_hold = n < SUMS_MAX_SAMPLES  # the bound of _sigma_verdict holds (fewer than 10⁶ additions per sum)
    for i in range(n):
        for c in range(4):
            tmax[c] = _push(dqmax[c], hmax[c], tmax[c], X, c, i, 1.0)
            tmin[c] = _push(dqmin[c], hmin[c], tmin[c], X, c, i, -1.0)
            y = X[i, c] - shift[c]
            w1[c] += y
            w2[c] += y * y
        lim = T[i] - window
        while j0 < i and T[j0] <= lim:
            for c in range(4):
                y = X[j0, c] - shift[c]
                w1[c] -= y
                w2[c] -= y * y
            j0 += 1
        if i < start:
            continue
        r = i - start
        out[r, 0], out[r, 1], out[r, 2] = cur[0], cur[1], cur[2]
        if not T[i] - T[j0] >= full_s:
            continue
        cnt = i + 1 - j0
        bound = _RANGE_MARGIN * math.sqrt(2.0 * cnt)
        hopeless = False
        sure = True  # every σ certainly below its limit (σ ≤ range/2): only the gyro means are summed
        for c in range(4):
            while dqmax[c, hmax[c]] < j0:
                hmax[c] += 1
            while dqmin[c, hmin[c]] < j0:
                hmin[c] += 1
            spread = X[dqmax[c, hmax[c]], c] - X[dqmin[c, hmin[c]], c]
            lim_c = gyr_std if c < 3 else acc_std
            if spread >= bound * lim_c:
                hopeless = True
            if not spread < _SURE_RANGE * lim_c:
                sure = False
        if hopeless:
            continue
        if not sure and sums_hold:
            verdict = _sigma_verdict(w1, w2, t1, t2, cnt, limits)
            if verdict < 0:
                continue  # some σ certainly at or above its limit: not still
            sure = verdict > 0  # every σ certainly below: only the gyro means are summed
        # each column summed on its own, oldest first (module docstring), the columns side by
        # side: the same additions in the same order per column, four chains at once
        s0 = s1 = s2 = s3 = 0.0
        if sure:
            for j in range(j0, i + 1):
                s0 += X[j, 0]
                s1 += X[j, 1]
                s2 += X[j, 2]
        else:
            for j in range(j0, i + 1):
                s0 += X[j, 0]
                s1 += X[j, 1]
                s2 += X[j, 2]
                s3 += X[j, 3]
        g[0], g[1], g[2] = s0 / cnt, s1 / cnt, s2 / cnt
        if not sure:
            g[3] = s3 / cnt
            m0, m1, m2, m3 = g[0], g[1], g[2], g[3]
            q0 = q1 = q2 = q3 = 0.0
            for j in range(j0, i + 1):
                d0, d1, d2, d3 = X[j, 0] - m0, X[j, 1] - m1, X[j, 2] - m2, X[j, 3] - m3
                q0 += d0 * d0
                q1 += d1 * d1
                q2 += d2 * d2
                q3 += d3 * d3
            sd[0], sd[1], sd[2], sd[3] = np.sqrt(q0 / cnt), np.sqrt(q1 / cnt), np.sqrt(q2 / cnt), np.sqrt(q3 / cnt)
        if ((sure or (sd[0] < gyr_std and sd[1] < gyr_std and sd[2] < gyr_std and sd[3] < acc_std))
                and math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) < gyr_max):
            still[r] = True
            cur[0], cur[1], cur[2] = g[0], g[1], g[2]
    return out, still, cur


@njit(cache=True)
def motionless_windows(T, X, start, window, full_s, acc_std, gyr_max):  # pragma: no cover - compiled
    """Per sample ``start..n-1``, the verdict on its trailing ``window`` (the motionless windows
    of :mod:`pdr.pipeline`, 7): :data:`MOVING`, :data:`MOTIONLESS` or :data:`UNKNOWN`.

    * **moving** — its samples prove motion, however few they are: a gyro norm (column 1) of
      ``gyr_max`` or more, or σ of the specific-force norm (column 0) of ``acc_std`` or more;
    * **motionless** — they prove none, and they span at least ``full_s`` of the window
      (``T[i] − T[j0] ≥ full_s``);
    * **unknown** — they prove none but span less: a sensor pause (a throttled or busy browser,
      a backgrounded page) or the first samples of a stream. Too few samples prove no motion,
      and they do not prove stillness either: what the motion state makes of an unknown window
      (neither restart nor proof of the stillness, up to a bound) is
      :func:`pdr.fleet_kernels.motion_windows`'.

    Before this rule a short window counted as moving, so that any pause of more than
    ``window − full_s`` (0.1 s) in the samples started the stillness, and the man-down clock,
    again: a still phone whose sensor service hiccups every few seconds never reached no motion."""
    n = T.shape[0]
    still = np.zeros(n - start, np.int8)  # MOVING
    if n > start:  # the samples every window holds: a gyro peak there rules them all out
        a = _first_in_window(T, n - 1, window)
        top = -np.inf
        for j in range(a, start + 1):
            if X[j, 1] > top:
                top = X[j, 1]
        if a <= start and not top < gyr_max:
            return still
    dqmax0 = np.empty(n, np.int64)
    dqmin0 = np.empty(n, np.int64)
    dqmax1 = np.empty(n, np.int64)
    h0 = t0 = h1 = t1 = h2 = t2 = 0
    j0 = 0
    for i in range(n):
        t0 = _push(dqmax0, h0, t0, X, 0, i, 1.0)
        t1 = _push(dqmin0, h1, t1, X, 0, i, -1.0)
        t2 = _push(dqmax1, h2, t2, X, 1, i, 1.0)
        lim = T[i] - window
        while j0 < i and T[j0] <= lim:
            j0 += 1
        if i < start:
            continue
        while dqmax1[h2] < j0:
            h2 += 1
        if not X[dqmax1[h2], 1] < gyr_max:
            continue
        while dqmax0[h0] < j0:
            h0 += 1
        while dqmin0[h1] < j0:
            h1 += 1
        cnt = i + 1 - j0
        spread = X[dqmax0[h0], 0] - X[dqmin0[h1], 0]
        if spread >= _RANGE_MARGIN * math.sqrt(2.0 * cnt) * acc_std:
            continue
        if spread < _SURE_RANGE * acc_std:  # σ ≤ range/2: certainly below the limit
            still[i - start] = MOTIONLESS if T[i] - T[j0] >= full_s else UNKNOWN
            continue
        s = 0.0
        for j in range(j0, i + 1):
            s += X[j, 0]
        mu = s / cnt
        ss = 0.0
        for j in range(j0, i + 1):
            d = X[j, 0] - mu
            ss += d * d
        if np.sqrt(ss / cnt) < acc_std:
            still[i - start] = MOTIONLESS if T[i] - T[j0] >= full_s else UNKNOWN
    return still
