"""Compiled per-sample recursion of the zero-velocity-aided INS (see :mod:`pdr.zupt.ins`).

An INS is a recursion over time, so it cannot be vectorised along the samples; it is
compiled (numba, cached on disk) and written with explicit loops so that every sample's
arithmetic is the same whatever the batch it arrived in: no BLAS, no reductions whose
grouping depends on an array's length. The state arrays are updated in place; a batch of
any size continues exactly where the previous one stopped.

Layout (all float64):

* ``x`` (16,): position p (ENU, m), velocity v (m/s), attitude q (w, x, y, z; Hamilton,
  body -> ENU), accelerometer bias b_a (m/s², body), gyro bias b_g (rad/s, body);
* ``P`` (15, 15): covariance of the error state δx = (δp, δv, ε, δb_a, δb_g), ε the small
  attitude error in the navigation frame, ``R_true = (I + [ε×]) R``;
* ``aux`` (AUX_SIZE,): time of the last sample, stance bookkeeping and the snapshot of the
  last stance sample (see the ``A_*`` indices);
* ``par`` (PAR_SIZE,): the settings as numbers (see the ``K_*`` indices).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# indices into ``par``
K_ACC_PSD = 0  # (m/s²)²/Hz, accelerometer white noise: Q_v = σ² Δt
K_GYR_PSD = 1  # (rad/s)²/Hz
K_BA_PSD = 2  # (m/s²)²/s, accelerometer bias random walk
K_BG_PSD = 3  # (rad/s)²/s, gyro bias random walk
K_ZUPT_VAR = 4  # (m/s)², zero-velocity pseudo-measurement
K_ZARU_VAR = 5  # (rad/s)², zero-angular-rate pseudo-measurement
K_GRAVITY = 6  # m/s²
K_MAX_DT = 7  # s, a longer interval counts as this long
K_SETTLE_S = 8  # s of stance after which the stride is emitted
K_MIN_STANCE_S = 9  # s: a shorter stationary spell makes no stride
K_MIN_SWING_S = 10  # s: a shorter motion does not end the stance
K_ZARU_MAX_MS = 11  # (rad/s)², a stationary sample whose window's mean squared rate is below gets ZARU
PAR_SIZE = 12

# the columns of a stride event (the state at one stance sample)
E_T = 0  # s
E_P = 1  # 1..3: position, m
E_PPP = 4  # 4..9: position covariance xx xy xz yy yz zz, m²
E_PYAW = 10  # variance of the yaw error ε_z, rad²
E_PEAK = 11  # largest ‖f‖ since the previous event, m/s²
E_TILT_COS = 12  # cosine of the boot's tilt from its attitude at the start
EVENT_COLS = 13

# indices into ``aux``
A_T_PREV = 0  # s, time of the last sample (NaN before the first)
A_STANCE_T0 = 1  # s, start of the current stance (NaN outside a stance)
A_LAST_ZV_T = 2  # s, the last stationary sample
A_EMITTED = 3  # 1 once the current stance has made its event
A_PEAK = 4  # m/s², largest ‖f‖ since the last event
A_UP0 = 5  # 5..7: the navigation "up" seen in the body at the start (third row of R)
A_SNAP = 8  # 8..: the event columns of the last stationary sample
AUX_SIZE = A_SNAP + EVENT_COLS


@njit(cache=True, inline="always")
def _rot(q0, q1, q2, q3):
    """Rotation matrix body -> navigation of a unit quaternion (w, x, y, z)."""
    return (
        1.0 - 2.0 * (q2 * q2 + q3 * q3), 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
        2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q1 * q1 + q3 * q3), 2.0 * (q2 * q3 - q0 * q1),
        2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2),
    )


@njit(cache=True)
def _propagate_cov(P, R, f0, f1, f2, dt, qv, qe, qa, qg):  # pragma: no cover - compiled
    """``P ← F P Fᵀ + Q`` with ``F = I + A Δt`` written block by block (Skog 2010 / OpenShoe).

    Non-zero blocks of A: ``∂δṗ/∂δv = I``, ``∂δv̇/∂ε = -[f×]``, ``∂δv̇/∂δb_a = -R``,
    ``∂ε̇/∂δb_g = -R``. Rows are updated p, v, ε (each reads only blocks not yet touched),
    then columns in the same order, so the product needs no temporary and ~800 flops
    instead of the 6750 of a dense 15x15 triple product.
    """
    # F P: rows
    for c in range(15):
        e0, e1, e2 = P[6, c], P[7, c], P[8, c]
        a0, a1, a2 = P[9, c], P[10, c], P[11, c]
        g0, g1, g2 = P[12, c], P[13, c], P[14, c]
        P[0, c] += dt * P[3, c]
        P[1, c] += dt * P[4, c]
        P[2, c] += dt * P[5, c]
        # -[f×] e = e × f
        P[3, c] += dt * ((e1 * f2 - e2 * f1) - (R[0] * a0 + R[1] * a1 + R[2] * a2))
        P[4, c] += dt * ((e2 * f0 - e0 * f2) - (R[3] * a0 + R[4] * a1 + R[5] * a2))
        P[5, c] += dt * ((e0 * f1 - e1 * f0) - (R[6] * a0 + R[7] * a1 + R[8] * a2))
        P[6, c] -= dt * (R[0] * g0 + R[1] * g1 + R[2] * g2)
        P[7, c] -= dt * (R[3] * g0 + R[4] * g1 + R[5] * g2)
        P[8, c] -= dt * (R[6] * g0 + R[7] * g1 + R[8] * g2)
    # (F P) Fᵀ: columns
    for r in range(15):
        e0, e1, e2 = P[r, 6], P[r, 7], P[r, 8]
        a0, a1, a2 = P[r, 9], P[r, 10], P[r, 11]
        g0, g1, g2 = P[r, 12], P[r, 13], P[r, 14]
        P[r, 0] += dt * P[r, 3]
        P[r, 1] += dt * P[r, 4]
        P[r, 2] += dt * P[r, 5]
        P[r, 3] += dt * ((e1 * f2 - e2 * f1) - (R[0] * a0 + R[1] * a1 + R[2] * a2))
        P[r, 4] += dt * ((e2 * f0 - e0 * f2) - (R[3] * a0 + R[4] * a1 + R[5] * a2))
        P[r, 5] += dt * ((e0 * f1 - e1 * f0) - (R[6] * a0 + R[7] * a1 + R[8] * a2))
        P[r, 6] -= dt * (R[0] * g0 + R[1] * g1 + R[2] * g2)
        P[r, 7] -= dt * (R[3] * g0 + R[4] * g1 + R[5] * g2)
        P[r, 8] -= dt * (R[6] * g0 + R[7] * g1 + R[8] * g2)
    for i in range(3):
        P[3 + i, 3 + i] += qv
        P[6 + i, 6 + i] += qe
        P[9 + i, 9 + i] += qa
        P[12 + i, 12 + i] += qg


@njit(cache=True)
def _update3(P, j, y0, y1, y2, var, dx, K, H):  # pragma: no cover - compiled
    """Kalman update with a 3-vector measurement of the error states ``j..j+2``.

    ``z = δx[j:j+3] + n``, ``n ~ N(0, var·I)``, innovation ``y``:
    ``S = P_jj + var·I``, ``K = P_:j S⁻¹``, ``δx = K y``, ``P ← P - K P_j:`` (then symmetrised).
    S⁻¹ by its adjugate (S is 3x3 symmetric positive definite).
    """
    s00 = P[j, j] + var
    s01 = P[j, j + 1]
    s02 = P[j, j + 2]
    s11 = P[j + 1, j + 1] + var
    s12 = P[j + 1, j + 2]
    s22 = P[j + 2, j + 2] + var
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    det = s00 * c00 + s01 * c01 + s02 * c02
    inv = 1.0 / det
    i00, i01, i02, i11, i12, i22 = c00 * inv, c01 * inv, c02 * inv, c11 * inv, c12 * inv, c22 * inv
    for r in range(15):
        p0, p1, p2 = P[r, j], P[r, j + 1], P[r, j + 2]
        K[r, 0] = p0 * i00 + p1 * i01 + p2 * i02
        K[r, 1] = p0 * i01 + p1 * i11 + p2 * i12
        K[r, 2] = p0 * i02 + p1 * i12 + p2 * i22
        dx[r] = K[r, 0] * y0 + K[r, 1] * y1 + K[r, 2] * y2
    for c in range(15):
        H[0, c] = P[j, c]
        H[1, c] = P[j + 1, c]
        H[2, c] = P[j + 2, c]
    for r in range(15):
        k0, k1, k2 = K[r, 0], K[r, 1], K[r, 2]
        for c in range(r, 15):
            v = P[r, c] - (k0 * H[0, c] + k1 * H[1, c] + k2 * H[2, c])
            P[r, c] = v
    for r in range(15):
        for c in range(r + 1, 15):
            P[c, r] = P[r, c]


@njit(cache=True, inline="always")
def _inject(x, dx):
    """Fold the error estimate into the nominal state and reset it to zero (Solà 2017 §7.2).

    ``p += δp``, ``v += δv``, ``q ← [1, ε/2] ⊗ q`` (normalised), ``b += δb``.
    """
    for i in range(6):
        x[i] += dx[i]
    h0, h1, h2 = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    q0, q1, q2, q3 = x[6], x[7], x[8], x[9]
    w = q0 - h0 * q1 - h1 * q2 - h2 * q3
    a = q1 + h0 * q0 + h1 * q3 - h2 * q2
    b = q2 - h0 * q3 + h1 * q0 + h2 * q1
    c = q3 + h0 * q2 - h1 * q1 + h2 * q0
    n = math.sqrt(w * w + a * a + b * b + c * c)
    x[6], x[7], x[8], x[9] = w / n, a / n, b / n, c / n
    for i in range(9, 15):
        x[i + 1] += dx[i]


@njit(cache=True, inline="always")
def _snapshot(dst, o, t, x, P, peak, up0, up1, up2):
    """The event columns (E_*) of the current state into ``dst[o:o + EVENT_COLS]``."""
    dst[o + E_T] = t
    dst[o + E_P], dst[o + E_P + 1], dst[o + E_P + 2] = x[0], x[1], x[2]
    dst[o + E_PPP], dst[o + E_PPP + 1], dst[o + E_PPP + 2] = P[0, 0], P[0, 1], P[0, 2]
    dst[o + E_PPP + 3], dst[o + E_PPP + 4], dst[o + E_PPP + 5] = P[1, 1], P[1, 2], P[2, 2]
    dst[o + E_PYAW] = P[8, 8]
    dst[o + E_PEAK] = peak
    q0, q1, q2, q3 = x[6], x[7], x[8], x[9]
    # third row of R(q): navigation up in body coordinates
    u0 = 2.0 * (q1 * q3 - q0 * q2)
    u1 = 2.0 * (q2 * q3 + q0 * q1)
    u2 = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
    dst[o + E_TILT_COS] = u0 * up0 + u1 * up1 + u2 * up2


@njit(cache=True)
def ins_run(x, P, aux, par, rows, zv, ared):  # pragma: no cover - compiled
    """Run the INS over one batch; returns per-sample position (n, 3) and the stance events.

    Per sample k (interval Δt = t_k - t_{k-1}, clipped to [0, max_dt]):

    1. strapdown mechanisation (Titterton & Weston 2004 §3; Skog et al. 2010 §II;
       first order, the attitude at the end of the interval rotates the sample's force):
       ``ω = ω̃ - b_g``, ``q ← q ⊗ [cos(|ω|Δt/2), sin(|ω|Δt/2) ω/|ω|]``,
       ``f = R(q)(f̃ - b_a)``, ``v ← v + (f + g)Δt``, ``p ← p + (v_prev + v)Δt/2``,
       with ``g = (0, 0, -g)`` in ENU;
    2. covariance ``P ← F P Fᵀ + Q`` (:func:`_propagate_cov`);
    3. when ``zv[k]``: zero-velocity update ``0 = v + δv + n`` (Foxlin 2005), and when
       also ``ared[k]`` (the window's mean squared rate) is below ``par[K_ZARU_MAX_MS]``,
       zero angular rate ``0 = ω̃ - b_g - δb_g + n`` (the gyro bias becomes observable
       while the foot rests), each injected at once.

    Stances: a stance starts at a stationary sample and ends once the foot has moved for
    ``min_swing_s`` (a shorter flicker of motion inside a stance does not split it). Each
    stance of at least ``min_stance_s`` makes one event: the state ``settle_s`` into it, or
    at its last stationary sample if it was shorter.

    ``rows`` (n, 7): time (s), specific force (3, m/s²), angular rate (3, rad/s), body frame.
    Returns ``pos`` (n, 3), ``events`` (m, EVENT_COLS) and ``event_k`` (m,), the batch
    sample of each event (-1 and below: a sample of an earlier batch).
    """
    n = rows.shape[0]
    t = rows[:, 0]
    acc = rows[:, 1:4]
    gyr = rows[:, 4:7]
    pos = np.empty((n, 3))
    events = np.empty((n + 1, EVENT_COLS))
    event_k = np.empty(n + 1, np.int64)
    m = 0
    dx = np.empty(15)
    Kw = np.empty((15, 3))
    Hw = np.empty((3, 15))
    qv_psd, qe_psd, qa_psd, qg_psd = par[K_ACC_PSD], par[K_GYR_PSD], par[K_BA_PSD], par[K_BG_PSD]
    zupt_var, zaru_var, grav, max_dt = par[K_ZUPT_VAR], par[K_ZARU_VAR], par[K_GRAVITY], par[K_MAX_DT]
    settle_s, min_stance_s, min_swing_s = par[K_SETTLE_S], par[K_MIN_STANCE_S], par[K_MIN_SWING_S]
    zaru_ms = par[K_ZARU_MAX_MS]
    up0, up1, up2 = aux[A_UP0], aux[A_UP0 + 1], aux[A_UP0 + 2]
    for k in range(n):
        dt = 0.0 if math.isnan(aux[A_T_PREV]) else min(max(t[k] - aux[A_T_PREV], 0.0), max_dt)
        aux[A_T_PREV] = t[k]
        # --- mechanisation
        w0 = gyr[k, 0] - x[13]
        w1 = gyr[k, 1] - x[14]
        w2 = gyr[k, 2] - x[15]
        nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        q0, q1, q2, q3 = x[6], x[7], x[8], x[9]
        if nw * dt > 0.0:
            half = 0.5 * nw * dt
            c = math.cos(half)
            s = math.sin(half) / nw
            d1, d2, d3 = s * w0, s * w1, s * w2
            n0 = q0 * c - q1 * d1 - q2 * d2 - q3 * d3
            n1 = q0 * d1 + q1 * c + q2 * d3 - q3 * d2
            n2 = q0 * d2 - q1 * d3 + q2 * c + q3 * d1
            n3 = q0 * d3 + q1 * d2 - q2 * d1 + q3 * c
            nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
            q0, q1, q2, q3 = n0 / nn, n1 / nn, n2 / nn, n3 / nn
            x[6], x[7], x[8], x[9] = q0, q1, q2, q3
        R = _rot(q0, q1, q2, q3)
        b0 = acc[k, 0] - x[10]
        b1 = acc[k, 1] - x[11]
        b2 = acc[k, 2] - x[12]
        f0 = R[0] * b0 + R[1] * b1 + R[2] * b2
        f1 = R[3] * b0 + R[4] * b1 + R[5] * b2
        f2 = R[6] * b0 + R[7] * b1 + R[8] * b2
        v0, v1, v2 = x[3], x[4], x[5]
        x[3] = v0 + f0 * dt
        x[4] = v1 + f1 * dt
        x[5] = v2 + (f2 - grav) * dt
        x[0] += 0.5 * (v0 + x[3]) * dt
        x[1] += 0.5 * (v1 + x[4]) * dt
        x[2] += 0.5 * (v2 + x[5]) * dt
        _propagate_cov(P, R, f0, f1, f2, dt, qv_psd * dt, qe_psd * dt, qa_psd * dt, qg_psd * dt)
        fn = math.sqrt(acc[k, 0] * acc[k, 0] + acc[k, 1] * acc[k, 1] + acc[k, 2] * acc[k, 2])
        if fn > aux[A_PEAK]:
            aux[A_PEAK] = fn
        # --- stance
        in_stance = not math.isnan(aux[A_STANCE_T0])
        if zv[k]:
            if not in_stance:
                aux[A_STANCE_T0] = t[k]
                aux[A_EMITTED] = 0.0
            _update3(P, 3, -x[3], -x[4], -x[5], zupt_var, dx, Kw, Hw)
            _inject(x, dx)
            if ared[k] < zaru_ms:
                _update3(P, 12, gyr[k, 0] - x[13], gyr[k, 1] - x[14], gyr[k, 2] - x[15], zaru_var, dx, Kw, Hw)
                _inject(x, dx)
            aux[A_LAST_ZV_T] = t[k]
            _snapshot(aux, A_SNAP, t[k], x, P, aux[A_PEAK], up0, up1, up2)
            if aux[A_EMITTED] == 0.0 and t[k] - aux[A_STANCE_T0] >= settle_s:
                for i in range(EVENT_COLS):
                    events[m, i] = aux[A_SNAP + i]
                event_k[m] = k
                m += 1
                aux[A_EMITTED] = 1.0
                aux[A_PEAK] = 0.0
        elif in_stance and t[k] - aux[A_LAST_ZV_T] >= min_swing_s:
            if aux[A_EMITTED] == 0.0 and aux[A_LAST_ZV_T] - aux[A_STANCE_T0] >= min_stance_s:
                for i in range(EVENT_COLS):
                    events[m, i] = aux[A_SNAP + i]
                event_k[m] = k - 1  # the sample index is not used, only its order
                m += 1
                aux[A_PEAK] = fn
            aux[A_STANCE_T0] = math.nan
            aux[A_EMITTED] = 0.0
        pos[k, 0], pos[k, 1], pos[k, 2] = x[0], x[1], x[2]
    return pos, events[:m], event_k[:m]


@njit(cache=True)
def mean_rows(a):  # pragma: no cover - compiled
    """Column means of ``a`` (n, k) summed row by row in order (no pairwise regrouping)."""
    n, c = a.shape
    out = np.zeros(c)
    for i in range(n):
        for j in range(c):
            out[j] += a[i, j]
    for j in range(c):
        out[j] /= n
    return out
