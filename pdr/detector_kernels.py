"""Compiled step detection of the columnar PDR engine (:mod:`pdr.fleet`): the ``norm``
detector (:class:`pdr.steps.norm.NormDetector`) over every responder of a round, and the
summation and median it uses.

Sums and medians are numpy's: pairwise summation in blocks of 128 with eight accumulators
(:func:`np_sum`), the median of a sorted copy (:func:`np_median`), so that the detector's
rate estimate and its swing reference are the batch detector's numbers.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_PW_BLOCK = 128  # numpy's PW_BLOCKSIZE
# detector state columns (float64 row per slot)
D_RATE, D_ZI_SET, D_NEXT, D_LAST_STEP, D_PEAK_ON, D_PEAK_T, D_PEAK_Y, D_LAST_PEAK, D_NSWING, D_BOUT, D_NBOUT = range(11)
D_G0, D_GM, D_TP, D_AP = range(11, 15)  # the uniform clock (pdr.steps.uniform): origin, next index, last sample
D_STATE = 15
MAX_SWINGS = 64  # ring of recent swings (the reference keeps reference_steps of them)


@njit(cache=True)
def _pairwise_block(a, lo, n):  # pragma: no cover - compiled
    """numpy's pairwise summation (``loops_utils.h``) of ``n <= 128`` values: 8 accumulators."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    m = n - (n % 8)
    while i < m:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


def _level(lower):
    """One level of numpy's recursion (halves, cut at a multiple of 8), written without
    recursion: numba's cache cannot load self-recursive functions."""
    @njit(cache=True)
    def pairwise(a, lo, n):  # pragma: no cover - compiled
        if n <= _PW_BLOCK:
            return _pairwise_block(a, lo, n)
        n2 = n // 2
        n2 -= n2 % 8
        return lower(a, lo, n2) + lower(a, lo + n2, n - n2)
    return pairwise


_pw1 = _level(_pairwise_block)
_pw2 = _level(_pw1)
_pw3 = _level(_pw2)
_pw4 = _level(_pw3)
_pw5 = _level(_pw4)
_pw6 = _level(_pw5)
_pw7 = _level(_pw6)
_pairwise = _level(_pw7)  # exact for up to 128·2⁸ = 32768 values
PAIRWISE_MAX = 128 * 2**8


@njit(cache=True)
def np_sum(a):  # pragma: no cover - compiled
    """``np.sum(a)`` of a 1-D float64 array of at most :data:`PAIRWISE_MAX` values, bit for bit."""
    return 0.0 + _pairwise(a, 0, a.shape[0])


@njit(cache=True)
def np_median(a):  # pragma: no cover - compiled
    """``np.median(a)`` of a non-empty 1-D float64 array without NaN, bit for bit."""
    s = np.sort(a)
    n = s.shape[0]
    if n % 2:
        return s[n // 2]
    return (0.0 + ((0.0 + s[n // 2 - 1]) + s[n // 2])) / 2.0


@njit(cache=True)
def estimate_rate(t):  # pragma: no cover - compiled
    """:func:`pdr.steps.signals.estimate_rate` (GAP_FACTOR 2.5), bit for bit."""
    dt = np.diff(t)
    dt = dt[dt > 0]
    med = np_median(dt)
    regular = dt[dt <= 2.5 * med]
    return 1.0 / (np_sum(regular) / regular.shape[0])


@njit(cache=True)
def detector_buffer(slots, off, T, A, det, raws, rate_window):  # pragma: no cover - compiled
    """Samples of responders whose rate is not known yet wait in ``raws``; returns per
    responder 1 when the rate became known now (the caller designs the filter), else 0.
    Non-finite samples are dropped (``StepDetector.update``)."""
    ready = np.zeros(slots.shape[0], np.int64)
    for j in range(slots.shape[0]):
        r = slots[j]
        if not math.isnan(det[r, D_RATE]):
            continue
        a0, a1 = off[j], off[j + 1]
        old = raws[r]
        k = 0
        for i in range(a0, a1):
            if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
                k += 1
        nr = np.empty((old.shape[0] + k, 2))
        nr[:old.shape[0]] = old
        k = old.shape[0]
        for i in range(a0, a1):
            if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
                nr[k, 0], nr[k, 1] = T[i], A[i]
                k += 1
        raws[r] = nr
        if nr.shape[0] < 2:
            continue
        for i in range(nr.shape[0]):
            if nr[i, 0] - nr[0, 0] >= rate_window:
                det[r, D_RATE] = estimate_rate(nr[:i + 1, 0].copy())
                ready[j] = 1
                break
    return ready


@njit(cache=True)
def onto_grid(t, a, det, r, max_gap):  # pragma: no cover - compiled
    """:class:`pdr.steps.uniform.UniformClock` for responder ``r`` (its state in ``det``), bit for
    bit: samples ``t``, ``a`` -> the grid points they complete."""
    rate = det[r, D_RATE]
    n = t.shape[0]
    tp, ap, g0, m = det[r, D_TP], det[r, D_AP], det[r, D_G0], det[r, D_GM]
    span = 0.0
    if n > 0:
        span = t[n - 1] - (t[0] if math.isnan(tp) else min(tp, t[0]))
    cap = n + 2 + int(max(span, 0.0) * rate)
    go = np.empty(cap)
    ao = np.empty(cap)
    k = 0
    for i in range(n):
        ti, ai = t[i], a[i]
        if math.isnan(tp) or (ti > tp and ti - tp > max_gap):  # the first sample, or a gap: (re)start
            g0, m, tp, ap = ti, 1.0, ti, ai
            go[k], ao[k] = ti, ai
            k += 1
            continue
        if not ti > tp:
            continue
        while True:
            g = g0 + m / rate
            if g > ti:
                break
            if k == cap:  # (the bound above holds; grow rather than trust it)
                go = np.concatenate((go, np.empty(cap)))
                ao = np.concatenate((ao, np.empty(cap)))
                cap *= 2
            go[k] = g
            ao[k] = ai if g == ti else ap + (ai - ap) * ((g - tp) / (ti - tp))
            k += 1
            m += 1.0
        tp, ap = ti, ai
    det[r, D_TP], det[r, D_AP], det[r, D_G0], det[r, D_GM] = tp, ap, g0, m
    return go[:k].copy(), ao[:k].copy()


@njit(cache=True)
def finite_pairs(T, A, a0, a1):  # pragma: no cover - compiled
    """The samples ``a0 <= i < a1`` whose time ``T[i]`` and value ``A[i]`` are both finite (a
    frame's NaN padding and unset values left out): ``(t, a, index)``."""
    k = 0
    for i in range(a0, a1):
        if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
            k += 1
    t, a, idx = np.empty(k), np.empty(k), np.empty(k, np.int64)
    k = 0
    for i in range(a0, a1):
        if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
            t[k], a[k], idx[k] = T[i], A[i], i
            k += 1
    return t, a, idx


@njit(cache=True)
def detector_stage(slots, off, T, A, use_raw, det, sos, zi, zi_unit, raws, tails, swings, bouts, cfg,
                   out, out_slot):  # pragma: no cover - compiled
    """Band-pass and the norm detector's scan (:class:`pdr.steps.norm.NormDetector`) for
    responders whose rate is known; ``use_raw[j]`` runs the samples that waited for the rate.
    Released steps go to ``out`` rows (t, t_start, a_max, a_min, a_mean, a_mean_abs) with
    their responder in ``out_slot``; returns how many."""
    floor, relative, ref_steps, ref_window = cfg[0], cfg[1], int(cfg[2]), cfg[3]
    min_interval, bout_gap, min_bout, max_step, margin = cfg[4], cfg[5], int(cfg[6]), cfg[7], cfg[8]
    max_gap = cfg[9]
    n_out = 0
    for j in range(slots.shape[0]):
        r = slots[j]
        if math.isnan(det[r, D_RATE]):
            continue
        if use_raw[j]:
            raw = raws[r]
            t = raw[:, 0].copy()
            a = raw[:, 1].copy()
            raws[r] = np.empty((0, 2))
        else:
            t, a, _ = finite_pairs(T, A, off[j], off[j + 1])
        t, a = onto_grid(t, a, det, r, max_gap)
        n = t.shape[0]
        if n == 0:
            continue
        if det[r, D_ZI_SET] == 0.0:
            for s_ in range(zi.shape[1]):
                zi[r, s_, 0] = zi_unit[r, s_, 0] * a[0]
                zi[r, s_, 1] = zi_unit[r, s_, 1] * a[0]
            det[r, D_ZI_SET] = 1.0
        tail = tails[r]
        m = tail.shape[0]
        nt = np.empty((m + n, 2))
        nt[:m] = tail
        ns = sos.shape[1]
        for i in range(n):
            v = a[i]
            for s_ in range(ns):
                o = sos[r, s_, 0] * v + zi[r, s_, 0]
                zi[r, s_, 0] = sos[r, s_, 1] * v - sos[r, s_, 4] * o + zi[r, s_, 1]
                zi[r, s_, 1] = sos[r, s_, 2] * v - sos[r, s_, 5] * o
                v = o
            nt[m + i, 0] = t[i]
            nt[m + i, 1] = v
        tt = nt[:, 0].copy()
        yy = nt[:, 1].copy()
        nn = m + n
        nxt = int(det[r, D_NEXT])
        lo, hi = nxt, nn - 2
        if hi >= lo:
            for i in range(lo, hi + 1):  # the extrema in time order (pdr.steps.base.ordered_extrema)
                before = yy[i] - yy[i - 1]
                after = yy[i + 1] - yy[i]
                if before > 0 and after <= 0:  # a maximum
                    if yy[i] >= floor and (det[r, D_PEAK_ON] == 0.0 or yy[i] > det[r, D_PEAK_Y]):
                        det[r, D_PEAK_ON], det[r, D_PEAK_T], det[r, D_PEAK_Y] = 1.0, tt[i], yy[i]
                    continue
                if not (before < 0 and after >= 0):
                    continue
                if det[r, D_PEAK_ON] == 0.0:
                    continue
                t_peak, y_peak = det[r, D_PEAK_T], det[r, D_PEAK_Y]
                det[r, D_PEAK_ON] = 0.0
                swing = y_peak - yy[i]
                since = t_peak - det[r, D_LAST_PEAK]
                if since < min_interval:
                    continue
                ns_ = int(det[r, D_NSWING])
                first = max(ns_ - ref_steps, 0)
                recent = np.empty(ns_ - first)
                k = 0
                for q in range(first, ns_):
                    tw, w = swings[r, q % MAX_SWINGS, 0], swings[r, q % MAX_SWINGS, 1]
                    if t_peak - tw <= ref_window:
                        recent[k] = w
                        k += 1
                if k > 0 and swing < relative * np_median(recent[:k]):
                    continue
                t_step = tt[i]
                t_start = max(det[r, D_LAST_STEP], t_step - max_step)
                i0 = np.searchsorted(tt, t_start, side="right")
                i1 = np.searchsorted(tt, t_step, side="right")
                if i1 > i0:
                    seg = yy[i0:i1]
                else:
                    seg = yy[max(i1 - 1, 0):i1]
                absd = np.abs(seg)
                row = np.empty(6)
                row[0], row[1] = t_step, t_start
                row[2], row[3] = seg.max(), seg.min()
                row[4] = np_sum(seg) / seg.shape[0]
                row[5] = np_sum(absd) / absd.shape[0]
                swings[r, ns_ % MAX_SWINGS, 0], swings[r, ns_ % MAX_SWINGS, 1] = t_peak, swing
                det[r, D_NSWING] = ns_ + 1
                det[r, D_LAST_PEAK], det[r, D_LAST_STEP] = t_peak, t_step
                # bouts
                if since > bout_gap:
                    det[r, D_NBOUT] = 0.0
                    det[r, D_BOUT] = 0.0
                det[r, D_BOUT] += 1.0
                if det[r, D_BOUT] < min_bout:
                    nb = int(det[r, D_NBOUT])
                    bouts[r, nb] = row
                    det[r, D_NBOUT] = nb + 1
                    continue
                for q in range(int(det[r, D_NBOUT])):
                    out[n_out] = bouts[r, q]
                    out_slot[n_out] = j
                    n_out += 1
                det[r, D_NBOUT] = 0.0
                out[n_out] = row
                out_slot[n_out] = j
                n_out += 1
        nxt = max(nxt, nn - 1)
        lim = tt[nn - 1] - (max_step + margin)
        drop = np.searchsorted(tt, lim)
        drop = min(drop, nxt - 1)
        if drop > 0:
            tails[r] = nt[drop:].copy()
            nxt -= drop
        else:
            tails[r] = nt
        det[r, D_NEXT] = nxt
    return n_out


# ------------------------------------------------------------------ motion state on its grid
