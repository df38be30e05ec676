"""Compiled recursion of :class:`pdr.floors.FloorTracker` (the module docstring there has the
model): one pass over a batch of heights with the tracker's state arrays, which a columnar
engine (:mod:`pdr.fleet`) keeps as rows of its own arrays.

The state vector's layout (``K``, ``B``, ... below) and the ring of the dwell window are the
tracker's; :func:`track_run` reads and writes them in place.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# state vector of the tracker (float64), see track_run
F_K, F_B, F_PEND, F_PEND_TO, F_TPREV, F_IN_DWELL, F_DWELL_ID, F_DSUM, F_DCNT, F_DFLOOR, F_HEAD, F_COUNT, F_REJECTED, F_DSTART, F_RATE, F_PROV_FROM = range(16)
F_STATE = 16
MAX_DRIFT_RATE = 25.0 / 3600.0  # m/s: 3 hPa/h, a fast weather change; the drift rate estimate stays below it
F_UNDECIDED = -2.0  # the open dwell's floor while it is too young to teach a new level
F_EXIT_FACTOR = 2.0  # a dwell ends when the window's rate or range passes this many times the entry limits
F_RING = 1024  # samples the dwell window can hold (6 s at 170 Hz; barometers give 1-25 Hz)
REASONS = ("", "height", "dwell")  # why a floor changed, by the code track_run gives
KNOWN_PROVISIONAL = 3  # ``known`` of a level a fix taught while the walker was moving in height (on stairs):
# used for the floor's thresholds, not for the scale α̂ nor the drift, and replaced by the first dwell near it


@njit(cache=True)
def predict(r, known, elev, pred):  # pragma: no cover - compiled
    """Predicted level of every floor from the seen ones (module docstring); returns α̂."""
    nf = elev.shape[0]
    lo, hi, n = -1, -1, 0
    for f in range(nf):
        if known[f] > 0 and known[f] != KNOWN_PROVISIONAL:  # a level taught on the stairs does not set the scale
            n += 1
            if lo < 0:
                lo = f
            hi = f
    alpha = 1.0
    if n >= 2:
        alpha = (r[hi] - r[lo]) / (elev[hi] - elev[lo])
        if not alpha > 0.0:
            alpha = 1.0
    for f in range(nf):
        if known[f] > 0:
            pred[f] = r[f]
            continue
        below, above = -1, -1
        for g in range(f - 1, -1, -1):
            if known[g] > 0:
                below = g
                break
        for g in range(f + 1, nf):
            if known[g] > 0:
                above = g
                break
        if below >= 0 and above >= 0:
            pred[f] = r[below] + (r[above] - r[below]) * (elev[f] - elev[below]) / (elev[above] - elev[below])
        elif below >= 0:
            pred[f] = r[below] + alpha * (elev[f] - elev[below])
        else:
            pred[f] = r[above] + alpha * (elev[f] - elev[above])
    return alpha


@njit(cache=True)
def _local_gap(pred, f):  # pragma: no cover - compiled
    nf = pred.shape[0]
    gap = np.inf
    if f > 0:
        gap = min(gap, abs(pred[f] - pred[f - 1]))
    if f + 1 < nf:
        gap = min(gap, abs(pred[f + 1] - pred[f]))
    return gap


@njit(cache=True)
def _reach(margin, alpha, elev, k):  # pragma: no cover - compiled
    """How far (m) the threshold path reaches from floor ``k``'s level: (½ + margin) of its
    configured gap, scaled by α̂ (the predicted gaps may lean on a provisional level itself)."""
    return (0.5 + margin) * alpha * _local_gap(elev, k)


@njit(cache=True)
def _match(level, r, known, pred, match_fraction):  # pragma: no cover - compiled
    """The seen floor whose level is within ``match_fraction`` of its local gap of ``level`` (nearest), else -1."""
    best, best_d = -1, np.inf
    for f in range(r.shape[0]):
        if known[f] > 0:
            d = abs(level - r[f])
            if d <= match_fraction * _local_gap(pred, f) and d < best_d:
                best, best_d = f, d
    return best


@njit(cache=True)
def _decide(level, r, known, elev, pred, alpha, match_fraction, scale_lo, scale_hi):  # pragma: no cover - compiled
    """The floor index of a dwell at ``level``, or -1 when it is on no floor (module docstring)."""
    nf = elev.shape[0]
    best = _match(level, r, known, pred, match_fraction)
    if best >= 0:
        return best
    a, da = -1, np.inf  # the seen floor nearest in level
    for f in range(nf):
        if known[f] > 0 and abs(level - r[f]) < da:
            a, da = f, abs(level - r[f])
    if a < 0:
        return -1
    step = 1 if level > r[a] else -1
    c = -1  # the next seen floor on that side
    f = a + step
    while 0 <= f < nf:
        if known[f] > 0:
            c = f
            break
        f += step
    if c >= 0:  # between two seen floors: the nearest interpolated level, if close
        best, best_d = -1, np.inf
        f = a + step
        while f != c:
            d = abs(level - pred[f])
            if d < best_d:
                best, best_d = f, d
            f += step
        if best >= 0 and best_d <= match_fraction * _local_gap(pred, best):
            return best
        return -1
    f = a + step  # beyond the seen floors: the fewest floors whose implied spacing is plausible
    while 0 <= f < nf:
        q = (level - r[a]) / (elev[f] - elev[a]) / alpha
        if scale_lo <= q <= scale_hi:
            return f
        if q < scale_lo:
            return -1  # farther floors imply even smaller spacings
        f += step
    return -1


@njit(cache=True)
def track_run(t, h, S, ring_t, ring_z, r, known, learned_in, pred, elev, P):  # pragma: no cover - compiled
    """The tracker over one batch; returns (floor index, z, reason of a change) per sample.

    ``S`` (float64[F_STATE]) holds the floor index, the offset b, the start and target of a
    pending threshold switch, the last time, the open dwell (flag, id, running sum and count of
    z, its floor) and the ring buffer's head and count; ``ring_t``/``ring_z`` the dwell window;
    ``r``/``known``/``learned_in`` the learned levels (known: 0 not seen, 1 seen on a dwell,
    2 start or fix, 3 a fix's while moving: :data:`KNOWN_PROVISIONAL`), ``pred`` the predicted levels. ``P`` = switch margin, dwell_s, window,
    max rate, band, match fraction, scale lo, scale hi, τ_d, max_dt, learn_s, drift band. All updated in place.
    """
    margin, hold, window, max_rate, band, match, s_lo, s_hi, tau, max_dt, learn_s, drift_fraction = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7], P[8], P[9], P[10], P[11]
    n = t.shape[0]
    nf = elev.shape[0]
    cap = ring_t.shape[0]
    out_k = np.empty(n, dtype=np.int64)
    out_z = np.empty(n)
    out_why = np.zeros(n, dtype=np.int64)
    alpha = predict(r, known, elev, pred)
    for i in range(n):
        k = int(S[F_K])
        t_prev = S[F_TPREV]
        dt = 0.0 if math.isnan(t_prev) else min(max(t[i] - t_prev, 0.0), max_dt)
        S[F_TPREV] = t[i]
        S[F_B] += S[F_RATE] * dt  # the weather keeps drifting between updates
        z = h[i] - S[F_B]
        # the dwell window: push, drop what is older than the window
        head, count = int(S[F_HEAD]), int(S[F_COUNT])
        ring_t[(head + count) % cap] = t[i]
        ring_z[(head + count) % cap] = z
        if count < cap:
            count += 1
        else:
            head = (head + 1) % cap
        while count > 1 and ring_t[head] <= t[i] - window:
            head = (head + 1) % cap
            count -= 1
        S[F_HEAD], S[F_COUNT] = head, count
        if known[k] == KNOWN_PROVISIONAL and S[F_IN_DWELL] == 0.0 and not math.isnan(S[F_PROV_FROM]):
            # a level named on the stairs follows the climb to where it ends (the walker pressed
            # the landmark before reaching the level), at most the threshold path's reach from
            # where it was named: farther, the walker went on to another floor
            reach = _reach(margin, alpha, elev, k)
            r[k] = min(max(z, S[F_PROV_FROM] - reach), S[F_PROV_FROM] + reach)
            alpha = predict(r, known, elev, pred)
        # threshold path on the predicted levels
        c = k
        while c + 1 < nf and z > pred[c] + (0.5 + margin) * (pred[c + 1] - pred[c]):
            c += 1
        if c == k:
            while c > 0 and z < pred[c] - (0.5 + margin) * (pred[c] - pred[c - 1]):
                c -= 1
        new_k, why = k, 0
        if c != k:
            if math.isnan(S[F_PEND]) or int(S[F_PEND_TO]) != c:
                S[F_PEND], S[F_PEND_TO] = t[i], c
            if t[i] - S[F_PEND] >= hold:
                new_k, why = c, 1
        else:
            S[F_PEND] = math.nan
        # steady height over the window: least-squares rate and range
        span = t[i] - ring_t[head]
        steady = False
        if span >= 0.9 * window and count >= 3:
            st = 0.0
            sz = 0.0
            zmin, zmax = np.inf, -np.inf
            for j in range(count):
                q = (head + j) % cap
                st += ring_t[q] - t[i]
                sz += ring_z[q]
                zmin = min(zmin, ring_z[q])
                zmax = max(zmax, ring_z[q])
            mt, mz = st / count, sz / count
            num, den = 0.0, 0.0
            for j in range(count):
                q = (head + j) % cap
                dtj = ring_t[q] - t[i] - mt
                num += dtj * (ring_z[q] - mz)
                den += dtj * dtj
            rate = num / den if den > 0.0 else 0.0
            # hysteresis: a dwell is entered under the limits and left only well past them
            x = 1.0 if S[F_IN_DWELL] == 0.0 else F_EXIT_FACTOR
            steady = abs(rate) <= x * max_rate and zmax - zmin <= x * band
        if steady:
            if S[F_IN_DWELL] == 0.0:  # a new dwell: on a floor seen before?
                S[F_IN_DWELL] = 1.0
                S[F_DWELL_ID] += 1.0
                S[F_DSTART] = ring_t[head]
                S[F_DSUM], S[F_DCNT] = mz * count, float(count)
                f = _match(mz, r, known, pred, match)
                if known[k] == KNOWN_PROVISIONAL and abs(mz - r[k]) <= _reach(margin, alpha, elev, k):
                    # the first dwell after a fix taught on the stairs is that floor's real level (within
                    # the threshold path's reach of the provisional one)
                    f, r[k], known[k] = k, mz, 2
                    S[F_PROV_FROM] = math.nan
                    alpha = predict(r, known, elev, pred)
                S[F_DFLOOR] = f if f >= 0 else F_UNDECIDED
            else:
                S[F_DSUM] += z
                S[F_DCNT] += 1.0
            if S[F_DFLOOR] == F_UNDECIDED and t[i] - S[F_DSTART] >= learn_s:  # long enough: a floor not seen yet?
                level = S[F_DSUM] / S[F_DCNT]
                f = _decide(level, r, known, elev, pred, alpha, match, s_lo, s_hi)
                if f >= 0 and not math.isnan(S[F_REJECTED]) and abs(level - S[F_REJECTED]) <= match * _local_gap(pred, f):
                    f = -1  # back at a level already judged to be on no floor (a landing)
                if f < 0:
                    S[F_REJECTED] = level
                elif known[f] == 0:
                    known[f], r[f], learned_in[f] = 1, level, S[F_DWELL_ID]
                    alpha = predict(r, known, elev, pred)
                S[F_DFLOOR] = f
            f = int(S[F_DFLOOR])
            if f >= 0:
                if f != new_k:
                    why = 2
                new_k = f
                S[F_PEND] = math.nan
        else:
            S[F_IN_DWELL] = 0.0
        if tau > 0.0 and known[new_k] > 0 and known[new_k] != KNOWN_PROVISIONAL and abs(z - r[new_k]) <= drift_fraction * _local_gap(pred, new_k):
            e = z - r[new_k]  # near a seen floor's level: follow the drift (critically damped, ramps without lag)
            g = dt / tau
            S[F_B] += 2.0 * g * e
            S[F_RATE] = min(max(S[F_RATE] + g / tau * e, -MAX_DRIFT_RATE), MAX_DRIFT_RATE)
        if new_k != k:
            S[F_K] = new_k
            S[F_PEND] = math.nan
            S[F_REJECTED] = math.nan
            S[F_PROV_FROM] = math.nan
        else:
            why = 0
        out_k[i] = new_k
        out_z[i] = z
        out_why[i] = why
    return out_k, out_z, out_why
