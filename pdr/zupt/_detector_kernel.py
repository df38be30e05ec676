"""Compiled zero-velocity test statistics over centred time windows (see :mod:`pdr.zupt.detectors`).

Each sample ``k`` gets the statistics of the samples ``j`` with ``|t_j - t_k| <= half``
(``half`` = half the window, s), summed oldest first: its value depends only on those
samples, never on where a batch began. A sample is decided once a sample later than
``t_k + half`` has arrived (or the stream has ended), so the detector lags the newest
sample by half a window.

The samples sit in one buffer ``buf`` (n, 7): time (s), specific force (3, m/s²), angular
rate (3, rad/s).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

SHOE, ARED, MV = 0, 1, 2  # columns of the statistics
STAT_COLS = 3
BUF_COLS = 7  # t, acc (3), gyr (3)


@njit(cache=True)
def window_statistics(buf, start, final, half, gravity, inv_var_a, inv_var_w):  # pragma: no cover
    """Statistics of the windows centred on samples ``start, start+1, ...`` while decidable.

    With ``W`` the samples of the window, ``ā`` their mean specific force (m/s²):

    * SHOE, the GLRT of Skog et al. (2010) eq. 13, stance hypothesis "specific force is
      gravity along ``ā`` and the angular rate is zero"::

          T = (1/W) Σ_j ( |a_j - g ā/|ā||² / σ_a²  +  |ω_j|² / σ_ω² )

    * ARED, the angular-rate energy detector (Skog et al. 2010 eq. 16)::

          T = (1/W) Σ_j |ω_j|²                         (rad²/s²)

    * MV, the acceleration moving variance (Skog et al. 2010 eq. 15)::

          T = (1/W) Σ_j |a_j - ā|²                      (m²/s⁴)

    Returns ``(stats (m, STAT_COLS), m)``: the number of
    samples decided is ``m`` (all of the rest when ``final``).
    """
    t = buf[:, 0]
    n = t.shape[0]
    out = np.empty((max(n - start, 0), STAT_COLS))
    lo = 0
    m = 0
    for k in range(start, n):
        tk = t[k]
        if not final and not (t[n - 1] > tk + half):
            break
        while t[lo] < tk - half:
            lo += 1
        hi = k
        while hi + 1 < n and t[hi + 1] <= tk + half:
            hi += 1
        cnt = hi - lo + 1
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for j in range(lo, hi + 1):
            s0 += buf[j, 1]
            s1 += buf[j, 2]
            s2 += buf[j, 3]
        m0, m1, m2 = s0 / cnt, s1 / cnt, s2 / cnt
        nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        u0, u1, u2 = (m0 / nm, m1 / nm, m2 / nm) if nm > 0.0 else (0.0, 0.0, 0.0)
        shoe = 0.0
        ared = 0.0
        mv = 0.0
        for j in range(lo, hi + 1):
            a0, a1, a2 = buf[j, 1], buf[j, 2], buf[j, 3]
            w0, w1, w2 = buf[j, 4], buf[j, 5], buf[j, 6]
            d0, d1, d2 = a0 - gravity * u0, a1 - gravity * u1, a2 - gravity * u2
            ww = w0 * w0 + w1 * w1 + w2 * w2
            shoe += (d0 * d0 + d1 * d1 + d2 * d2) * inv_var_a + ww * inv_var_w
            ared += ww
            e0, e1, e2 = a0 - m0, a1 - m1, a2 - m2
            mv += e0 * e0 + e1 * e1 + e2 * e2
        r = k - start
        out[r, SHOE] = shoe / cnt
        out[r, ARED] = ared / cnt
        out[r, MV] = mv / cnt
        m += 1
    return out[:m], m


# indices into the decision state (float64 array, updated in place)
D_T0 = 0  # s, time of the first sample (start of the bins); NaN before
D_BIN = 1  # index of the current bin
D_BINS = 2  # 2..: ring of per-bin maxima of ‖f‖ (n_bins), then ring of per-bin minima of SHOE (n_bins)

KIND_SHOE, KIND_ARED, KIND_MV, KIND_ADAPTIVE = 0, 1, 2, 3


def state_size(n_bins: int) -> int:
    return D_BINS + 2 * n_bins


@njit(cache=True)
def decide(rows, stats, kind, state, n_bins, bin_s, g0, a_ref, kappa, g_max, floor_factor, ceiling,
           ared_th2, mv_th2):  # pragma: no cover - compiled
    """Stationary or not, per decided sample (``rows``: their buffer rows).

    Returns ``zv`` (m,) bool, ``threshold`` (m,), ``quiet`` (m,) bool — motionless by the
    strict test: the SHOE statistic below ``g0`` for SHOE and adaptive, else ``zv``.

    ``kind``: SHOE ``T < g0``; ARED ``T < ared_th2``; MV ``T < mv_th2``; adaptive: SHOE
    against

        γ = clip( max( clip(g0 (A/A0)^κ, g0, g_max),  c·F ),  g0, ceiling )

    with ``A`` the largest ``‖f‖`` in the current and the ``n_bins − 1`` previous bins of
    ``bin_s`` seconds (the gait intensity), and ``F`` the smallest SHOE statistic in those
    previous bins (the floor the last stance reached; ``c`` = ``floor_factor``). Bins are
    counted from the first sample, so the same samples always fall in the same bins.
    """
    t = rows[:, 0]
    m = t.shape[0]
    zv = np.zeros(m, np.bool_)
    quiet = np.zeros(m, np.bool_)
    thr = np.empty(m)
    mins = D_BINS + n_bins
    for k in range(m):
        if math.isnan(state[D_T0]):
            state[D_T0] = t[k]
            state[D_BIN] = 0.0
            for j in range(n_bins):
                state[D_BINS + j] = 0.0
                state[mins + j] = math.inf
        b = math.floor((t[k] - state[D_T0]) / bin_s)
        cur = state[D_BIN]
        if b - cur >= n_bins:  # a gap longer than the window: every bin is empty
            for j in range(n_bins):
                state[D_BINS + j] = 0.0
                state[mins + j] = math.inf
            cur = b
        while cur < b:  # open the bins up to this sample's; the ring forgets the oldest
            cur += 1.0
            state[D_BINS + int(cur) % n_bins] = 0.0
            state[mins + int(cur) % n_bins] = math.inf
        state[D_BIN] = cur
        slot = int(cur) % n_bins
        fn = math.sqrt(rows[k, 1] * rows[k, 1] + rows[k, 2] * rows[k, 2] + rows[k, 3] * rows[k, 3])
        if fn > state[D_BINS + slot]:
            state[D_BINS + slot] = fn
        a = 0.0
        floor = math.inf
        for j in range(n_bins):
            if state[D_BINS + j] > a:
                a = state[D_BINS + j]
            if j != slot and state[mins + j] < floor:
                floor = state[mins + j]
        shoe, ared, mv = stats[k, SHOE], stats[k, ARED], stats[k, MV]
        if shoe < state[mins + slot]:
            state[mins + slot] = shoe
        if kind == KIND_SHOE:
            thr[k] = g0
            zv[k] = shoe < g0
        elif kind == KIND_ARED:
            thr[k] = ared_th2
            zv[k] = ared < ared_th2
        elif kind == KIND_MV:
            thr[k] = mv_th2
            zv[k] = mv < mv_th2
        else:
            gam = min(max(g0 * (a / a_ref) ** kappa, g0), g_max)
            if floor < math.inf:  # no previous bin yet: no floor
                gam = min(max(gam, floor_factor * floor), ceiling)
            thr[k] = gam
            zv[k] = shoe < gam
        quiet[k] = shoe < g0 if (kind == KIND_SHOE or kind == KIND_ADAPTIVE) else zv[k]
    return zv, thr, quiet
