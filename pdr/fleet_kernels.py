"""Compiled kernels of the columnar PDR engine (:mod:`pdr.fleet`): each runs one stage of the
pipeline over every responder of a round.

A round holds, for responders ``j = 0..J-1``, consecutive samples ``off[j]:off[j+1]`` of the
round's concatenated arrays and the responder's state row ``slots[j]`` of arrays with a
responder axis. Per responder, each kernel does exactly what :class:`pdr.pipeline.PdrPipeline`
does to one frame, in the same order of floating-point operations: the per-sample kernels of
the single-responder classes (:func:`pdr.ahrs._decoupled_kernel.decoupled_run`,
:func:`pdr.heading_kernels.still_bias`, :func:`pdr.heading_kernels.level_and_compass`,
:func:`pdr.heading_kernels.close_epochs`, :func:`pdr.windows.trailing_moments`,
:func:`pdr.height._altimeter_run`, :func:`pdr.floors._track_run`) are called on views of the
state rows, and the numpy glue around them is written out so that each number is rounded as
numpy rounds it: sums and means as numpy's pairwise summation (:func:`np_sum`), medians as
``np.median``. So a responder's events are the same, bit for bit, alone or among a thousand,
in any round size (``tests/test_fleet.py``).

Buffers whose length follows the data (the trailing windows, the detector's tail, the
pressure history) are numba typed lists of arrays, one per slot, replaced as the reference
replaces its arrays (``np.concatenate`` then a mask).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pdr.ahrs._decoupled_kernel import decoupled_run
from pdr.floors import _track_run
from pdr.heading_kernels import close_epochs, level_and_compass
from pdr.height import _altimeter_run

TWO_PI = 2.0 * np.pi  # pdr.windows.unwrap_turns' constant
_PW_BLOCK = 128  # numpy's PW_BLOCKSIZE

# detector state columns (float64 row per slot)
D_RATE, D_ZI_SET, D_NEXT, D_LAST_STEP, D_PEAK_ON, D_PEAK_T, D_PEAK_Y, D_LAST_PEAK, D_NSWING, D_BOUT, D_NBOUT = range(11)
D_STATE = 11
MAX_SWINGS = 64  # ring of recent swings (the reference keeps reference_steps of them)
# motion state columns
M_FIRST, M_LAST_MOVING, M_GRID_K, M_STATE, M_SINCE, M_T0, M_TLAST = range(7)
M_STATE_N = 7
WALKING, STILL, NO_MOTION = 0, 1, 2


# ------------------------------------------------------------------ numpy's arithmetic, written out
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


@njit(cache=True, inline="always")
def _norm3(x, y, z):
    return math.sqrt(x * x + y * y + z * z)


@njit(cache=True)
def keep_after(buf, lim, extra):  # pragma: no cover - compiled
    """The rows of ``buf`` whose first column is above ``lim`` (``buf[buf[:, 0] > lim]``), in a
    new array with ``extra`` rows left free at the end; one block copy when they are a suffix
    (times in order, the usual case)."""
    n = buf.shape[0]
    k0 = n
    for i in range(n - 1, -1, -1):  # the kept suffix
        if buf[i, 0] > lim:
            k0 = i
        else:
            break
    suffix = True
    for i in range(k0):
        if buf[i, 0] > lim:
            suffix = False
            break
    if suffix:
        out = np.empty((n - k0 + extra, buf.shape[1]))
        out[:n - k0] = buf[k0:]
        return out
    k = 0
    for i in range(n):
        if buf[i, 0] > lim:
            k += 1
    out = np.empty((k + extra, buf.shape[1]))
    k = 0
    for i in range(n):
        if buf[i, 0] > lim:
            out[k] = buf[i]
            k += 1
    return out


# ------------------------------------------------------------------ heading, detector buffer, motion windows
@njit(cache=True)
def heading_stage(slots, off, T, ACC, GYR, MAG, has_mag, AN,
                  ahrs_s, ahrs_p, turn, bias, bias_tails, bias_cfg, fwd, use_mag_cfg, declination,
                  raw_last, turns, t0h, ep_state, epoch, hbufs, hbuf_keep,
                  ep_rows, ep_slot):  # pragma: no cover - compiled
    """Per responder of the round: ‖f‖, gyro bias at standstill, levelling AHRS, gyro heading
    and compass offset, compass epochs and the sample buffer the steps' headings read
    (:meth:`pdr.heading.HeadingEstimator.update`). Returns the number of closed epoch rows
    written to ``ep_rows`` (their responder index in ``ep_slot``)."""
    n_ep = 0
    estimate_bias = bias_cfg[0] > 0.0
    window, gstd, gmax, astd = bias_cfg[1], bias_cfg[2], bias_cfg[3], bias_cfg[4]
    for j in range(slots.shape[0]):
        r = slots[j]
        a0, a1 = off[j], off[j + 1]
        n = a1 - a0
        t = T[a0:a1]
        acc = ACC[a0:a1]
        gyr = GYR[a0:a1]
        an = AN[a0:a1]
        if math.isnan(t0h[r]):
            t0h[r] = t[0]
        # 1. gyro bias at standstill
        b = np.empty((n, 3))
        if estimate_bias:
            tail = bias_tails[r]
            m = tail.shape[0]
            X = np.empty((m + n, 4))
            TT = np.empty(m + n)
            for i in range(m):
                TT[i] = tail[i, 0]
                X[i, 0], X[i, 1], X[i, 2], X[i, 3] = tail[i, 1], tail[i, 2], tail[i, 3], tail[i, 4]
            for i in range(n):
                TT[m + i] = t[i]
                X[m + i, 0], X[m + i, 1], X[m + i, 2], X[m + i, 3] = gyr[i, 0], gyr[i, 1], gyr[i, 2], an[i]
            b0 = bias[r].copy()
            bb, _, cur = still_bias_fast(TT, X, m, window, gstd, gmax, astd, b0)
            b[:, :] = bb
            bias[r, 0], bias[r, 1], bias[r, 2] = cur[0], cur[1], cur[2]
            lim = TT[m + n - 1] - window - 1e-9
            k = 0
            for i in range(m + n):
                if TT[i] > lim:
                    k += 1
            nt = np.empty((k, 5))
            k = 0
            for i in range(m + n):
                if TT[i] > lim:
                    nt[k, 0] = TT[i]
                    nt[k, 1], nt[k, 2], nt[k, 3], nt[k, 4] = X[i, 0], X[i, 1], X[i, 2], X[i, 3]
                    k += 1
            bias_tails[r] = nt
        else:
            for i in range(n):
                b[i, 0], b[i, 1], b[i, 2] = bias[r, 0], bias[r, 1], bias[r, 2]
        g = np.empty((n, 3))
        for i in range(n):
            g[i, 0], g[i, 1], g[i, 2] = gyr[i, 0] - b[i, 0], gyr[i, 1] - b[i, 1], gyr[i, 2] - b[i, 2]
        # 2. levelling AHRS, without the magnetometer
        q = np.empty((n, 4))
        decoupled_run(ahrs_s[r], ahrs_p, t, acc, g, acc, False, turn, q)
        # 3. gyro heading and compass offset
        use_mag = use_mag_cfg and has_mag[j]
        mag = MAG[a0:a1] if use_mag else np.empty((0, 3))
        raw, d, nrm, inc, af, al, az = level_and_compass(q, fwd, acc, mag, use_mag, declination)
        prev = raw[0] if math.isnan(raw_last[r]) else raw_last[r]
        tn = turns[r]
        psi = np.empty(n)
        for i in range(n):
            step = -np.int64(np.rint((raw[i] - prev) / TWO_PI))
            tn += step
            prev = raw[i]
            psi[i] = raw[i] + TWO_PI * tn
        turns[r] = tn
        raw_last[r] = raw[n - 1]
        # 4. compass epochs
        w = np.empty(n)
        for i in range(n):
            w[i] = _norm3(g[i, 0], g[i, 1], g[i, 2])
        rows = close_epochs(t, psi, d, nrm, inc, w, t0h[r], epoch, ep_state[r])
        for i in range(rows.shape[0]):
            ep_rows[n_ep] = rows[i]
            ep_slot[n_ep] = j
            n_ep += 1
        # 5. samples kept for the steps' headings: t, ψ, δ, |b|, I, levelled specific force (f, l, up)
        buf = hbufs[r]
        nb = keep_after(buf, t[0] - hbuf_keep, n)
        k = nb.shape[0] - n
        for i in range(n):
            nb[k + i, 0], nb[k + i, 1], nb[k + i, 2], nb[k + i, 3], nb[k + i, 4] = t[i], psi[i], d[i], nrm[i], inc[i]
            nb[k + i, 5], nb[k + i, 6], nb[k + i, 7] = af[i], al[i], az[i]
        hbufs[r] = nb
    return n_ep


@njit(cache=True)
def motion_windows(slots, off, T, GYR, AN, mot, tails, lms, window, full_frac, acc_std, gyr_max):  # pragma: no cover - compiled
    """Per sample: was the trailing ``window`` motionless; per responder the time each sample
    last moved, kept for the state grid (``PdrPipeline._motionless`` / ``_update_motion``).
    ``full_frac`` = 0.9·window."""
    for j in range(slots.shape[0]):
        r = slots[j]
        a0, a1 = off[j], off[j + 1]
        n = a1 - a0
        tail = tails[r]
        m = tail.shape[0]
        TT = np.empty(m + n)
        X = np.empty((m + n, 2))
        for i in range(m):
            TT[i], X[i, 0], X[i, 1] = tail[i, 0], tail[i, 1], tail[i, 2]
        for i in range(n):
            TT[m + i] = T[a0 + i]
            X[m + i, 0] = AN[a0 + i]
            X[m + i, 1] = _norm3(GYR[a0 + i, 0], GYR[a0 + i, 1], GYR[a0 + i, 2])
        motionless = motionless_fast(TT, X, m, window, full_frac, acc_std, gyr_max)
        lim = TT[m + n - 1] - window - 1e-9
        k = 0
        for i in range(m + n):
            if TT[i] > lim:
                k += 1
        nt = np.empty((k, 3))
        k = 0
        for i in range(m + n):
            if TT[i] > lim:
                nt[k, 0], nt[k, 1], nt[k, 2] = TT[i], X[i, 0], X[i, 1]
                k += 1
        tails[r] = nt
        if math.isnan(mot[r, M_FIRST]):
            mot[r, M_FIRST] = T[a0]
        lm_old = lms[r]
        nl = np.empty((lm_old.shape[0] + n, 2))
        nl[:lm_old.shape[0]] = lm_old
        last = mot[r, M_LAST_MOVING]
        for i in range(n):
            still = motionless[i]
            mv = -np.inf if still else TT[m + i]
            if mv > last:
                last = mv
            nl[lm_old.shape[0] + i, 0] = TT[m + i]
            nl[lm_old.shape[0] + i, 1] = last
        mot[r, M_LAST_MOVING] = last
        lms[r] = nl


# ------------------------------------------------------------------ step detection (the norm detector)
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
def detector_stage(slots, off, T, A, use_raw, det, sos, zi, zi_unit, raws, tails, swings, bouts, cfg,
                   out, out_slot):  # pragma: no cover - compiled
    """Band-pass and the norm detector's scan (:class:`pdr.steps.norm.NormDetector`) for
    responders whose rate is known; ``use_raw[j]`` runs the samples that waited for the rate.
    Released steps go to ``out`` rows (t, t_start, a_max, a_min, a_mean, a_mean_abs) with
    their responder in ``out_slot``; returns how many."""
    floor, relative, ref_steps, ref_window = cfg[0], cfg[1], int(cfg[2]), cfg[3]
    min_interval, bout_gap, min_bout, max_step, margin = cfg[4], cfg[5], int(cfg[6]), cfg[7], cfg[8]
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
            a0, a1 = off[j], off[j + 1]
            k = 0
            for i in range(a0, a1):
                if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
                    k += 1
            t = np.empty(k)
            a = np.empty(k)
            k = 0
            for i in range(a0, a1):
                if T[i] - T[i] == 0.0 and A[i] - A[i] == 0.0:
                    t[k], a[k] = T[i], A[i]
                    k += 1
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
@njit(cache=True)
def motion_grid(slots, mot, lms, step_times, new_steps, new_off, cfg, out, out_slot):  # pragma: no cover - compiled
    """The motion-state grid (``PdrPipeline._update_motion``) after this round's steps:
    ``new_steps[new_off[j]:new_off[j+1]]`` are responder j's step times. Writes state changes
    (grid time, state, since) to ``out``; returns how many."""
    grid, delay, still_after, no_motion_after = cfg[0], cfg[1], cfg[2], cfg[3]
    n_out = 0
    for j in range(slots.shape[0]):
        r = slots[j]
        k0, k1 = new_off[j], new_off[j + 1]
        if k1 > k0:
            old = step_times[r]
            keep = old[max(old.shape[0] - 64, 0):]
            ns = np.empty(keep.shape[0] + k1 - k0)
            ns[:keep.shape[0]] = keep
            ns[keep.shape[0]:] = new_steps[k0:k1]
            step_times[r] = ns
        st = step_times[r]
        t0 = mot[r, M_T0]
        horizon = mot[r, M_TLAST] - delay
        k_hi = math.floor((horizon + 1e-9 - t0) / grid)
        gk = int(mot[r, M_GRID_K])
        if k_hi < gk:
            continue
        lm = lms[r]
        lm_t = lm[:, 0].copy()
        g_last = 0.0
        for k in range(gk, k_hi + 1):
            g = t0 + grid * float(k)
            g_last = g
            i = np.searchsorted(lm_t, g, side="right") - 1
            lmv = lm[max(i, 0), 1] if i >= 0 else -np.inf
            if not (lmv - lmv == 0.0):
                lmv = mot[r, M_FIRST]
            q = np.searchsorted(st, g, side="right") - 1
            last_step = st[q] if q >= 0 else -np.inf
            walking = g - last_step < still_after
            no_motion = (not walking) and (g - lmv >= no_motion_after)
            new = WALKING if walking else NO_MOTION if no_motion else STILL
            if new == mot[r, M_STATE] and not math.isnan(mot[r, M_SINCE]):
                continue
            if new == WALKING:
                since = last_step
            elif new == NO_MOTION:
                since = lmv
            elif last_step - last_step == 0.0:
                a = last_step + still_after
                since = a if a >= mot[r, M_FIRST] else mot[r, M_FIRST]
            else:
                since = mot[r, M_FIRST]
            mot[r, M_STATE], mot[r, M_SINCE] = new, since
            out[n_out, 0], out[n_out, 1], out[n_out, 2] = g, new, since
            out_slot[n_out] = j
            n_out += 1
        mot[r, M_GRID_K] = k_hi + 1
        lim = g_last - 1.0
        k = 0
        for i in range(lm.shape[0]):
            if not lm[i, 0] < lim:
                k += 1
        nl = np.empty((k, 2))
        k = 0
        for i in range(lm.shape[0]):
            if not lm[i, 0] < lim:
                nl[k] = lm[i]
                k += 1
        lms[r] = nl
    return n_out


# ------------------------------------------------------------------ height and floor
@njit(cache=True)
def altimeter_stage(slots, poff, PT, PV, alt, tau, reference_s, filt, pref, good):  # pragma: no cover - compiled
    """Low-pass and reference of every responder's pressure samples (finite ones only, as
    :meth:`pdr.height.BarometricAltimeter.update`); ``good`` marks them."""
    for j in range(slots.shape[0]):
        r = slots[j]
        b0, b1 = poff[j], poff[j + 1]
        k = 0
        for i in range(b0, b1):
            good[i] = (PT[i] - PT[i] == 0.0) and (PV[i] - PV[i] == 0.0)
            if good[i]:
                k += 1
        if k == 0:
            continue
        tt = np.empty(k)
        pp = np.empty(k)
        k = 0
        for i in range(b0, b1):
            if good[i]:
                tt[k], pp[k] = PT[i], PV[i]
                k += 1
        f, pr = _altimeter_run(tt, pp, alt[r], tau, reference_s)
        k = 0
        for i in range(b0, b1):
            if good[i]:
                filt[i], pref[i] = f[k], pr[k]
                k += 1


@njit(cache=True)
def floor_stage(slots, poff, PT, H, good, h0, height, S, ring_t, ring_z, rr, known, learned_in, pred, elev, P,
                pres, ch, ch_slot):  # pragma: no cover - compiled
    """Heights (``h0 + relative height``, the last one held over bad samples), the floor tracker
    (:func:`pdr.floors._track_run`) and the pressure history for the steps' dz. Floor changes
    go to ``ch`` rows (t, index from, index to, z, why); returns how many."""
    n_ch = 0
    for j in range(slots.shape[0]):
        r = slots[j]
        b0, b1 = poff[j], poff[j + 1]
        n = b1 - b0
        if n == 0:
            continue
        h = np.empty(n)
        last = height[r]
        for i in range(n):
            if good[b0 + i]:
                h[i] = h0[r] + H[b0 + i]
                last = h[i]
            else:
                h[i] = last
        height[r] = h[n - 1]
        t = PT[b0:b1]
        k0 = int(S[r, 0])
        k = 0
        for i in range(n):
            if h[i] - h[i] == 0.0 and t[i] - t[i] == 0.0:
                k += 1
        kout = np.full(n, k0)
        zout = np.full(n, np.nan)
        why = np.zeros(n, np.int64)
        if k > 0:
            tg = np.empty(k)
            hg = np.empty(k)
            idx = np.empty(k, np.int64)
            k = 0
            for i in range(n):
                if h[i] - h[i] == 0.0 and t[i] - t[i] == 0.0:
                    tg[k], hg[k], idx[k] = t[i], h[i], i
                    k += 1
            if math.isnan(S[r, 1]):
                S[r, 1] = hg[0] - rr[r, k0]
            kk, zz, ww = _track_run(tg, hg, S[r], ring_t[r], ring_z[r], rr[r], known[r], learned_in[r], pred[r],
                                    elev, P)
            cur = k0
            q = 0
            for i in range(n):
                if q < k and idx[q] == i:
                    cur = kk[q]
                    zout[i], why[i] = zz[q], ww[q]
                    q += 1
                kout[i] = cur
        prev = k0
        for i in range(n):
            if kout[i] != prev:
                ch[n_ch, 0], ch[n_ch, 1], ch[n_ch, 2], ch[n_ch, 3], ch[n_ch, 4] = t[i], prev, kout[i], zout[i], why[i]
                ch_slot[n_ch] = j
                n_ch += 1
            prev = kout[i]
        npr = keep_after(pres[r], t[n - 1] - 60.0, n)
        k = npr.shape[0] - n
        for i in range(n):
            npr[k + i, 0], npr[k + i, 1] = t[i], h[i]
        pres[r] = npr
    return n_ch


# ------------------------------------------------------------------ typed-list access from Python (1 µs, not 7)
@njit(cache=True)
def get_rows(lst, r):  # pragma: no cover - compiled
    return lst[r]


@njit(cache=True)
def set_rows(lst, r, a):  # pragma: no cover - compiled
    lst[r] = a


@njit(cache=True)
def append_rows(lst, a):  # pragma: no cover - compiled
    lst.append(a)


@njit(cache=True)
def pack_rows(lst, cols):  # pragma: no cover - compiled
    """A typed list of ``(k_i, cols)`` arrays as one ``(sum k_i, cols)`` array and the ``k_i``
    (a snapshot's form: one array, not one object per slot)."""
    n = len(lst)
    lens = np.empty(n, np.int64)
    total = 0
    for i in range(n):
        if lst[i].shape[1] != cols:
            raise ValueError("pack_rows: an entry with another number of columns")
        lens[i] = lst[i].shape[0]
        total += lens[i]
    out = np.empty((total, cols))
    k = 0
    for i in range(n):
        out[k:k + lens[i]] = lst[i]
        k += lens[i]
    return lens, out


@njit(cache=True)
def pack_vectors(lst):  # pragma: no cover - compiled
    """A typed list of 1-D arrays as one array and their lengths (see :func:`pack_rows`)."""
    n = len(lst)
    lens = np.empty(n, np.int64)
    total = 0
    for i in range(n):
        lens[i] = lst[i].shape[0]
        total += lens[i]
    out = np.empty(total)
    k = 0
    for i in range(n):
        out[k:k + lens[i]] = lst[i]
        k += lens[i]
    return lens, out


# ------------------------------------------------------------------ trailing windows, paid only where it can matter
# The stillness tests need a window's standard deviation only where it could pass: a window whose
# range is at least √(2n)·σ_max cannot have σ < σ_max (σ ≥ range/√(2n) for any n samples), and a
# window whose maximum passes a limit fails whatever its σ. Those are decided from exact sliding
# minima and maxima (monotone deques, O(1) per sample); the few windows left are summed exactly
# as pdr.windows.trailing_moments sums them (oldest first, two passes), so every decision and
# every bias is the reference's, bit for bit, at a fraction of the cost while the responder moves.
_RANGE_MARGIN = 1.01  # the bound's safety factor against rounding (relative errors of ~1e-13)


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


@njit(cache=True)
def still_bias_fast(T, X, start, window, gyr_std, gyr_max, acc_std, bias0):  # pragma: no cover - compiled
    """:func:`pdr.heading_kernels.still_bias`, the same outputs (module note above)."""
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
    for i in range(n):
        for c in range(4):
            tmax[c] = _push(dqmax[c], hmax[c], tmax[c], X, c, i, 1.0)
            tmin[c] = _push(dqmin[c], hmin[c], tmin[c], X, c, i, -1.0)
        lim = T[i] - window
        while j0 < i and T[j0] <= lim:
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
        for c in range(4):
            while dqmax[c, hmax[c]] < j0:
                hmax[c] += 1
            while dqmin[c, hmin[c]] < j0:
                hmin[c] += 1
            spread = X[dqmax[c, hmax[c]], c] - X[dqmin[c, hmin[c]], c]
            if spread >= bound * (gyr_std if c < 3 else acc_std):
                hopeless = True
        if hopeless:
            continue
        g = np.empty(4)
        sd = np.empty(4)
        for c in range(4):
            s = 0.0
            for j in range(j0, i + 1):
                s += X[j, c]
            mu = s / cnt
            ss = 0.0
            for j in range(j0, i + 1):
                d = X[j, c] - mu
                ss += d * d
            g[c] = mu
            sd[c] = np.sqrt(ss / cnt)
        if (sd[0] < gyr_std and sd[1] < gyr_std and sd[2] < gyr_std and sd[3] < acc_std
                and math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) < gyr_max):
            still[r] = True
            cur[0], cur[1], cur[2] = g[0], g[1], g[2]
    return out, still, cur


@njit(cache=True)
def motionless_fast(T, X, start, window, full_s, acc_std, gyr_max):  # pragma: no cover - compiled
    """Per sample ``start..n-1``: the trailing ``window`` is full (``full_s``), σ of column 0 is
    below ``acc_std`` and the maximum of column 1 below ``gyr_max`` (``PdrPipeline._motionless``
    on :func:`pdr.windows.trailing_moments`, the same decisions)."""
    n = T.shape[0]
    still = np.zeros(n - start, np.bool_)
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
        if not T[i] - T[j0] >= full_s:
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
        if X[dqmax0[h0], 0] - X[dqmin0[h1], 0] >= _RANGE_MARGIN * math.sqrt(2.0 * cnt) * acc_std:
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
            still[i - start] = True
    return still
