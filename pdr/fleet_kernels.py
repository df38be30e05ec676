"""Compiled kernels of the columnar PDR engine (:mod:`pdr.fleet`): each runs one stage of the
pipeline over every responder of a round.

A round holds, for responders ``j = 0..J-1``, consecutive samples ``off[j]:off[j+1]`` of the
round's concatenated arrays and the responder's state row ``slots[j]`` of arrays with a
responder axis. Per responder, each kernel does what the single-responder classes do to one frame, in the
same order of floating-point operations: their per-sample kernels (:func:`pdr.ahrs._decoupled_kernel.decoupled_run`,
:func:`pdr.window_kernels.still_bias`, :func:`pdr.heading_kernels.level_and_compass`,
:func:`pdr.heading_kernels.close_epochs`, :func:`pdr.window_kernels.motionless_windows`,
:func:`pdr.height.altimeter_run`, :func:`pdr.floor_kernels.track_run`) are called on views of the
state rows. A responder's events are the same, bit for bit, alone or among a thousand, in any
round size (``tests/test_fleet.py``): every kernel loops over the responders and touches only
the responder's own row. The step detector's stage is :mod:`pdr.detector_kernels`, the
trailing windows' :mod:`pdr.window_kernels`, the per-slot buffers' :mod:`pdr.fleet_buffers`.

Buffers whose length follows the data (the trailing windows, the detector's tail, the
pressure history) are numba typed lists of arrays, one per slot, replaced as the reference
replaces its arrays (``np.concatenate`` then a mask).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pdr.ahrs._decoupled_kernel import decoupled_run
from pdr.fleet_buffers import keep_after, kept_with_room
from pdr.floor_kernels import track_run
from pdr.heading_kernels import close_epochs, level_and_compass
from pdr.height import altimeter_run
from pdr.window_kernels import MOVING, UNKNOWN, motionless_windows, still_bias

TWO_PI = 2.0 * np.pi  # pdr.windows.unwrap_turns' constant
# motion state columns
M_FIRST, M_LAST_MOVING, M_GRID_K, M_STATE, M_SINCE, M_T0, M_TLAST, M_JUDGED = range(8)
M_STATE_N = 8
WALKING, STILL, NO_MOTION = 0, 1, 2


@njit(cache=True, inline="always")
def _norm3(x, y, z):
    return math.sqrt(x * x + y * y + z * z)


@njit(cache=True)
def heading_stage(slots, off, T, ACC, GYR, MAG, has_mag, AN,
                  ahrs_s, ahrs_p, turn, bias, bias_tails, bias_cfg, fwd, use_mag_cfg, declination,
                  raw_last, turns, t0h, ep_state, epoch, hbufs, hbases, hb_end, hbuf_keep,
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
            bb, _, cur = still_bias(TT, X, m, window, gstd, gmax, astd, b0)
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
        rows = close_epochs(t, psi, d, nrm, inc, w, an, t0h[r], epoch, ep_state[r])
        for i in range(rows.shape[0]):
            ep_rows[n_ep] = rows[i]
            ep_slot[n_ep] = j
            n_ep += 1
        # 5. samples kept for the steps' headings: t, ψ, δ, |b|, I, levelled specific force (f, l, up), attitude q
        nb, base, end = kept_with_room(hbufs[r], hbases[r], hb_end[r], t[0] - hbuf_keep, n)
        hbases[r] = base  # hbufs[r] is a view of it: a frame's rows are written after the last, no copy
        hb_end[r] = end
        k = nb.shape[0] - n
        for i in range(n):
            nb[k + i, 0], nb[k + i, 1], nb[k + i, 2], nb[k + i, 3], nb[k + i, 4] = t[i], psi[i], d[i], nrm[i], inc[i]
            nb[k + i, 5], nb[k + i, 6], nb[k + i, 7] = af[i], al[i], az[i]
            nb[k + i, 8], nb[k + i, 9], nb[k + i, 10], nb[k + i, 11] = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        hbufs[r] = nb
    return n_ep


@njit(cache=True)
def motion_windows(slots, off, T, GYR, AN, mot, tails, lms, window, full_frac, acc_std, gyr_max,
                   pause_max):  # pragma: no cover - compiled
    """Per sample: the verdict on its trailing ``window`` (:func:`pdr.window_kernels.motionless_windows`);
    per responder the time each sample last moved, kept for the state grid (:mod:`pdr.pipeline`,
    7: motionless windows). ``full_frac`` = 0.9·window: the span of samples a window needs to
    prove stillness.

    The stillness clock (the time of the last motion, ``M_LAST_MOVING``) across sensor pauses:

    * a **moving** window restarts it at its sample;
    * a **motionless** window leaves it;
    * an **unknown** window (too few samples to judge, after a pause in the samples) leaves it
      too, while the pause is short: the samples before it and after it (which prove motion
      from any number of them) decide, and a pause proves neither motion nor stillness;
    * a pause of more than ``pause_max`` between two samples, or unknown windows for more than
      ``pause_max + window`` since the last judged one (a stream too sparse to show motion),
      restart it at the sample: a gap is not stillness, the stillness after it counts from its
      end (the service's own rule for longer gaps, :mod:`service.core.alarms`, is the same).

    A pause of up to ``pause_max`` inside a stillness therefore counts as still: the stillness
    seen on both sides of it. It moves the man-down time by at most ``pause_max`` (a movement
    wholly inside the pause, ending in the same still pose, is not seen) and never delays it;
    counting it as motion (the rule before) kept a still phone whose browser pauses its sensors
    every few seconds from ever reaching no motion, and leaving the pause out of the count would
    delay man-down by the sum of the pauses (a third of 30 s at 0.9 s every 3 s)."""
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
        motionless = motionless_windows(TT, X, m, window, full_frac, acc_std, gyr_max)
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
        judged = mot[r, M_JUDGED]
        for i in range(n):
            t, verdict = TT[m + i], motionless[i]
            paused = m + i > 0 and t - TT[m + i - 1] > pause_max
            if verdict != UNKNOWN:
                judged = t
            if verdict == MOVING or paused or t - judged > pause_max + window:
                if t > last:
                    last = t
            nl[lm_old.shape[0] + i, 0] = TT[m + i]
            nl[lm_old.shape[0] + i, 1] = last
        mot[r, M_LAST_MOVING], mot[r, M_JUDGED] = last, judged
        lms[r] = nl


# ------------------------------------------------------------------ step detection (the norm detector)


@njit(cache=True)
def motion_grid(slots, mot, lms, step_times, new_steps, new_off, cfg, out, out_slot):  # pragma: no cover - compiled
    """The motion-state grid (:mod:`pdr.pipeline`, 7) after this round's steps:
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
        # the rows the next grid times can look up: from the newest at or before g_last - 1 s
        # on (that one too: across a pause in the samples it is the row a grid time finds, and
        # without it the time of the last motion would be lost, the stillness counted from the
        # first sample)
        lim = g_last - 1.0
        k0 = 0
        while k0 < lm.shape[0] and lm[k0, 0] < lim:
            k0 += 1
        lms[r] = lm[max(k0 - 1, 0):].copy()
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
        f, pr = altimeter_run(tt, pp, alt[r], tau, reference_s)
        k = 0
        for i in range(b0, b1):
            if good[i]:
                filt[i], pref[i] = f[k], pr[k]
                k += 1


@njit(cache=True)
def floor_stage(slots, poff, PT, H, good, h0, height, S, ring_t, ring_z, rr, known, learned_in, pred, elev, P,
                pres, ch, ch_slot):  # pragma: no cover - compiled
    """Heights (``h0 + relative height``, the last one held over bad samples), the floor tracker
    (:func:`pdr.floor_kernels.track_run`) and the pressure history for the steps' dz. Floor changes
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
            kk, zz, ww = track_run(tg, hg, S[r], ring_t[r], ring_z[r], rr[r], known[r], learned_in[r], pred[r],
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
