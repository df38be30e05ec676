"""Compiled per-sample parts of :class:`pdr.heading.HeadingEstimator`.

Each sample is handled on its own (or folded into a running sum, oldest first), so a
stream cut into frames of any size gives bit-identical results, and a 10-sample frame
costs one call instead of a dozen small array operations. The gyro bias at standstill is
:func:`pdr.window_kernels.still_bias`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi
TIP_FROM = math.sin(math.radians(15.0))  # the back's elevation over which a tipped phone's g takes the lead
TIP_OPPOSITE = math.cos(math.radians(45.0))  # f_h and g_h count as opposite from 135° apart (a pitch: 180°)


@njit(cache=True)
def level_and_compass(q, fwd, acc, mag, use_mag, declination):  # pragma: no cover - compiled
    """Per sample, from the attitude ``q`` (n, 4) body -> ENU, scalar first (R = R(q), Justa eq. 13):

    * ``raw`` — yaw of the device's heading vector, wrapped: ``fwd`` holds the forward axis
      ``f``, the upright axis ``g`` and ``s₀²`` (7 numbers), and the heading vector is
      ``h = R f + w · R g`` taken horizontally, ``atan2(h_y, h_x)``, with
      ``w = clip(((R f)_z² − s₀²) / (1 − s₀²), 0, 1)``. Up to an elevation of ``asin s₀`` the
      phone points with ``f`` alone; stood up further (``f`` towards vertical, where its yaw is
      ill-conditioned: an inclination error ε across it turns it by about ε / cos(elevation))
      ``g`` (the back of the phone, −z, for a screen facing the walker) takes over; both point
      the same way for a phone pitched in the hand, so the heading is continuous, and a phone
      rolled on its side keeps ``f``. ``g = 0`` gives the yaw of ``f`` alone. Tipped past
      vertical (``f`` over the walker's shoulder, the back of the phone above the horizon), both
      the back and the reverse of ``f`` point forward, ``h = R g − R f`` (a roll about ``f``
      leaves ``−f`` where it was), blended in by ``b = a · clip((R g)_z / sin 15°, 0, 1)``
      with ``a = clip((−cos ∠(f_h, g_h) − cos 45°) / (1 − cos 45°), 0, 1)`` (1 when the
      horizontal parts point opposite ways, as for a pitch; 0 from 135° apart down, as for a
      phone rolled on its side): the heading stays continuous
      through the pitch, where the yaw of ``f + w g`` alone flipped by 180° from 108° of
      elevation on (issue 27's ``grip_x``);
    * ``af``, ``al``, ``az`` — the specific force ``acc`` (n, 3) levelled, ``R a``, and turned
      into the device-heading frame: along the forward axis's yaw, to its left, and up (m/s²;
      for the walking direction, :func:`pdr.walking_direction.walking_angle`);
    * ``d`` — compass offset, ``wrap(π/2 − D − atan2(m_y, m_x))`` with ``m = R b`` the field
      levelled into ENU and ``D`` the declination: what to add to the gyro heading to point
      the device's x axis at true north (NaN without a magnetometer);
    * ``norm`` — ``|b|`` (µT), ``inc`` — dip ``atan2(−m_z, √(m_x² + m_y²))`` (positive down).
    """
    n = q.shape[0]
    raw = np.empty(n)
    d = np.full(n, np.nan)
    norm = np.full(n, np.nan)
    inc = np.full(n, np.nan)
    af = np.empty(n)
    al = np.empty(n)
    az = np.empty(n)
    fx, fy, fz = fwd[0], fwd[1], fwd[2]
    gx, gy, gz = fwd[3], fwd[4], fwd[5]
    s0 = fwd[6]
    for i in range(n):
        w, x, y, z = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        r00 = 1.0 - 2.0 * (y * y + z * z)
        r01 = 2.0 * (x * y - w * z)
        r02 = 2.0 * (x * z + w * y)
        r10 = 2.0 * (x * y + w * z)
        r11 = 1.0 - 2.0 * (x * x + z * z)
        r12 = 2.0 * (y * z - w * x)
        r20 = 2.0 * (x * z - w * y)
        r21 = 2.0 * (y * z + w * x)
        r22 = 1.0 - 2.0 * (x * x + y * y)
        up = r20 * fx + r21 * fy + r22 * fz
        wu = min(max((up * up - s0) / (1.0 - s0), 0.0), 1.0)
        fe, fn = r00 * fx + r01 * fy + r02 * fz, r10 * fx + r11 * fy + r12 * fz
        ge, gn, gu = r00 * gx + r01 * gy + r02 * gz, r10 * gx + r11 * gy + r12 * gz, r20 * gx + r21 * gy + r22 * gz
        # tipped past vertical (the back points up, f's horizontal part against g's): g leads
        fg = math.sqrt((fe * fe + fn * fn) * (ge * ge + gn * gn))
        a = min(max((-(fe * ge + fn * gn) / fg - TIP_OPPOSITE) / (1.0 - TIP_OPPOSITE), 0.0), 1.0) if fg > 1e-12 else 0.0
        b = a * min(max(gu / TIP_FROM, 0.0), 1.0)
        yaw = math.atan2((1.0 - b) * (fn + wu * gn) + b * (gn - fn), (1.0 - b) * (fe + wu * ge) + b * (ge - fe))
        raw[i] = yaw
        ax, ay, azb = acc[i, 0], acc[i, 1], acc[i, 2]
        ex = r00 * ax + r01 * ay + r02 * azb
        ny = r10 * ax + r11 * ay + r12 * azb
        cy, sy = math.cos(yaw), math.sin(yaw)
        af[i] = cy * ex + sy * ny
        al[i] = cy * ny - sy * ex
        az[i] = r20 * ax + r21 * ay + r22 * azb
        if use_mag:
            bx, by, bz = mag[i, 0], mag[i, 1], mag[i, 2]
            mx = r00 * bx + r01 * by + r02 * bz
            my = r10 * bx + r11 * by + r12 * bz
            mz = r20 * bx + r21 * by + r22 * bz
            a = 0.5 * math.pi - declination - math.atan2(my, mx)
            d[i] = math.pi - ((math.pi - a) % TWO_PI)
            norm[i] = math.sqrt(bx * bx + by * by + bz * bz)
            inc[i] = math.atan2(-mz, math.sqrt(mx * mx + my * my))
    return raw, d, norm, inc, af, al, az


# running sums of the open epoch: index, count, Σcos d, Σsin d, Σ|b|, ΣI, Σ|ω|, last ψ, Σ‖f‖, Σ‖f‖²
EPOCH_STATE = 10
EPOCH_COLUMNS = ("t_end", "psi", "cos_d", "sin_d", "norm", "inc", "rate", "acc_std")


@njit(cache=True)
def close_epochs(t, psi, d, norm, inc, w, a, t0, epoch, state):  # pragma: no cover - compiled
    """Fold samples into compass epochs ``k = ⌊(t − t0) / epoch⌋``; an epoch closes when a
    sample of a later one arrives. Returns one row per closed epoch (:data:`EPOCH_COLUMNS`): end
    time ``t0 + (k + 1)·epoch``, ψ at its last sample, the means of cos δ, sin δ, |b|, I and |ω|
    over its samples, and the standard deviation of the specific force's norm ``a`` (‖f‖: near 0
    while the walker stands, 1-3 m/s² while walking). ``state`` (EPOCH_STATE,) carries the open
    epoch between calls."""
    out = np.empty((t.shape[0] + 1, 8))
    m = 0
    for i in range(t.shape[0]):
        k = math.floor((t[i] - t0) / epoch)
        if state[1] > 0 and k > state[0]:
            c = state[1]
            out[m, 0] = t0 + (state[0] + 1.0) * epoch
            out[m, 1] = state[7]
            out[m, 2] = state[2] / c
            out[m, 3] = state[3] / c
            out[m, 4] = state[4] / c
            out[m, 5] = state[5] / c
            out[m, 6] = state[6] / c
            ma = state[8] / c
            out[m, 7] = math.sqrt(max(state[9] / c - ma * ma, 0.0))
            m += 1
            for j in range(1, 7):
                state[j] = 0.0
            state[8] = 0.0
            state[9] = 0.0
        if state[1] == 0:
            state[0] = k
        state[1] += 1.0
        state[2] += math.cos(d[i])
        state[3] += math.sin(d[i])
        state[4] += norm[i]
        state[5] += inc[i]
        state[6] += w[i]
        state[7] = psi[i]
        state[8] += a[i]
        state[9] += a[i] * a[i]
    return out[:m]


@njit(cache=True)
def walking_stats(t, f, l, z, lag, pca):  # pragma: no cover - compiled
    """(α, e, ρ, σ_z) of one window: :func:`pdr.walking_direction.walking_angle`'s arithmetic."""
    n = t.shape[0]
    if n < 2:
        return 0.0, 0.0, 0.0, 0.0
    mf = ml = mz = 0.0
    for i in range(n):
        mf += f[i]
        ml += l[i]
        mz += z[i]
    mf /= n
    ml /= n
    mz /= n
    cff = cll = cfl = czz = 0.0
    for i in range(n):
        a, b, c = f[i] - mf, l[i] - ml, z[i] - mz
        cff += a * a
        cll += b * b
        cfl += a * b
        czz += c * c
    cff /= n
    cll /= n
    cfl /= n
    sz = math.sqrt(czz / n)
    tr = cff + cll
    e = math.sqrt((cff - cll) ** 2 + 4.0 * cfl * cfl) / tr if tr > 0.0 else 0.0
    alpha = 0.5 * math.atan2(2.0 * cfl, cff - cll) if pca else 0.0
    ca, sa = math.cos(alpha), math.sin(alpha)
    dt = (t[n - 1] - t[0]) / (n - 1)
    k = max(1, int(round(lag / dt))) if dt > 0.0 else 1
    if k >= n:
        return alpha, e, 0.0, sz
    c1 = c2 = su = 0.0
    for i in range(n):
        u = (f[i] - mf) * ca + (l[i] - ml) * sa
        su += u * u
        if i + k < n:
            c2 += u * (z[i + k] - mz)  # u(t) z(t + τ)
        if i >= k:
            c1 += u * (z[i - k] - mz)  # u(t + τ) z(t)
    c = (c1 - c2) / (n - k)
    su = math.sqrt(su / n)
    rho = abs(c) / (su * sz) if su * sz > 0.0 else 0.0
    if c > 0.0:
        alpha = alpha + math.pi if alpha <= 0.0 else alpha - math.pi
    return alpha, e, rho, sz
