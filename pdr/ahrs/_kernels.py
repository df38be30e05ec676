"""Compiled per-sample recursions of the orientation filters.

An AHRS is a recursion over time, so it cannot be vectorised along the samples; it is
compiled instead (numba, cached on disk). Each kernel takes the state quaternion, the
per-sample ``dt`` and sensor arrays, and returns the quaternion after every sample.

All kernels work in the filters' *native* frame: x towards magnetic north
(horizontal), z up, y west. Quaternions are scalar first and rotate body -> native
frame; a reference vector ``v`` is predicted in the body as ``R(q)ᵀ v`` (Justa eq. 14).
The Python wrappers in :mod:`pdr.ahrs.base` convert to and from ENU.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _qmul(aw, ax, ay, az, bw, bx, by, bz):
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True, inline="always")
def _store_unit(out, i, w, x, y, z):
    """Normalise (sign fixed so that w >= 0), write row ``i`` of ``out`` and return it."""
    nrm = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        nrm = -nrm
    w, x, y, z = w / nrm, x / nrm, y / nrm, z / nrm
    out[i, 0] = w
    out[i, 1] = x
    out[i, 2] = y
    out[i, 3] = z
    return w, x, y, z


@njit(cache=True, inline="always")
def _unit3(x, y, z):
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-12:
        return 0.0, 0.0, 0.0, 0.0
    return x / n, y / n, z / n, n


@njit(cache=True)
def scf_run(q0, dt, acc, gyr, mag, use_mag, gain_acc, gain_mag, exact):  # pragma: no cover - compiled
    """SCF (``exact``) or FSCF: Justa (2022) §6.1 eqs. 17-34, constant correction steps.

    Per sample, with ``λ_a = gain_acc·dt`` and ``λ_m = gain_mag·dt`` (rad):

    * prediction: SCF ``q_pred = q ⊗ [√(1-|s|²), s]``, ``s = sin(ω dt / 2)`` (eqs. 17-20);
      FSCF the first-order ``q_pred = q + ½ dt q ⊗ [0, ω]``;
    * ``a_pred = R(q_pred)ᵀ [0,0,1]`` (eq. 23); inclination-adaptive magnetic reference
      ``m_z = a_pred·m``, ``m_r = [√(1-m_z²), 0, m_z]``, ``m_pred = R(q_pred)ᵀ m_r`` (eqs. 24-25);
    * separate correction axes ``a_cor = unit(a × a_pred)``, ``m_cor = unit(m × m_pred)`` (eq. 26);
    * fused correction ``f = (λ_a/2) a_cor + (λ_m/2) m_cor`` (eq. 30); SCF
      ``q_cor = [√(1-|f c|²), f c]`` with ``c = sinc(|f|)`` (eqs. 31-32), FSCF ``q_cor = [1, f]`` (eq. 33);
    * ``q = normalise(q_pred ⊗ q_cor)``, sign fixed to ``q_w ≥ 0`` (eq. 34).
    """
    n = dt.shape[0]
    out = np.empty((n, 4))
    w, x, y, z = q0[0], q0[1], q0[2], q0[3]
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        if exact:
            sx = math.sin(0.5 * gx * h)
            sy = math.sin(0.5 * gy * h)
            sz = math.sin(0.5 * gz * h)
            s2 = sx * sx + sy * sy + sz * sz
            sw = math.sqrt(1.0 - s2) if s2 < 1.0 else 0.0
            w, x, y, z = _qmul(w, x, y, z, sw, sx, sy, sz)
        else:
            hh = 0.5 * h
            dw, dx, dy, dz = _qmul(w, x, y, z, 0.0, gx, gy, gz)
            w, x, y, z = w + hh * dw, x + hh * dx, y + hh * dy, z + hh * dz
        # predicted gravity direction in the body (third row of R)
        apx = 2.0 * (x * z - w * y)
        apy = 2.0 * (y * z + w * x)
        apz = 1.0 - 2.0 * (x * x + y * y)
        fx = 0.0
        fy = 0.0
        fz = 0.0
        ax, ay, az, an = _unit3(acc[i, 0], acc[i, 1], acc[i, 2])
        if an > 0.0:
            cx, cy, cz, cn = _unit3(ay * apz - az * apy, az * apx - ax * apz, ax * apy - ay * apx)
            if cn > 0.0:
                half = 0.5 * gain_acc * h
                fx += half * cx
                fy += half * cy
                fz += half * cz
        if use_mag:
            mx, my, mz, mn = _unit3(mag[i, 0], mag[i, 1], mag[i, 2])
            if mn > 0.0:
                mrz = apx * mx + apy * my + apz * mz
                if mrz > 1.0:
                    mrz = 1.0
                elif mrz < -1.0:
                    mrz = -1.0
                mrx = math.sqrt(1.0 - mrz * mrz)
                # first row of R (the native x axis seen from the body)
                r0x = 1.0 - 2.0 * (y * y + z * z)
                r0y = 2.0 * (x * y - w * z)
                r0z = 2.0 * (x * z + w * y)
                mpx = mrx * r0x + mrz * apx
                mpy = mrx * r0y + mrz * apy
                mpz = mrx * r0z + mrz * apz
                cx, cy, cz, cn = _unit3(my * mpz - mz * mpy, mz * mpx - mx * mpz, mx * mpy - my * mpx)
                if cn > 0.0:
                    half = 0.5 * gain_mag * h
                    fx += half * cx
                    fy += half * cy
                    fz += half * cz
        if exact:
            fn = math.sqrt(fx * fx + fy * fy + fz * fz)
            c = math.sin(fn) / fn if fn > 1e-12 else 1.0
            fx *= c
            fy *= c
            fz *= c
            f2 = fx * fx + fy * fy + fz * fz
            fw = math.sqrt(1.0 - f2) if f2 < 1.0 else 0.0
        else:
            fw = 1.0
        w, x, y, z = _qmul(w, x, y, z, fw, fx, fy, fz)
        w, x, y, z = _store_unit(out, i, w, x, y, z)
    return out


@njit(cache=True)
def madgwick_run(q0, dt, acc, gyr, mag, use_mag, beta):  # pragma: no cover - compiled
    """Madgwick's gradient-descent filter (Madgwick 2010; Smartphone thesis §2.6, eqs. 21-32).

    ``q̇ = ½ q ⊗ [0, ω] − β ∇f/|∇f|`` with ``∇f = Jᵀ f`` for the gravity objective
    ``f_g = R(q)ᵀ[0,0,1] − â`` and, with a magnetometer, the field objective against the
    reference ``b = [√(h_x²+h_y²), 0, h_z]``, ``h = q ⊗ m̂ ⊗ q*`` (magnetic distortion
    compensation, "group 1"); integrated with ``dt`` and normalised.
    """
    n = dt.shape[0]
    out = np.empty((n, 4))
    q1, q2, q3, q4 = q0[0], q0[1], q0[2], q0[3]
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        # rate of change from the gyroscope
        d1 = 0.5 * (-q2 * gx - q3 * gy - q4 * gz)
        d2 = 0.5 * (q1 * gx + q3 * gz - q4 * gy)
        d3 = 0.5 * (q1 * gy - q2 * gz + q4 * gx)
        d4 = 0.5 * (q1 * gz + q2 * gy - q3 * gx)
        ax, ay, az, an = _unit3(acc[i, 0], acc[i, 1], acc[i, 2])
        if an > 0.0:
            s1 = 0.0
            s2 = 0.0
            s3 = 0.0
            s4 = 0.0
            # gravity objective and its Jacobian transpose
            f1 = 2.0 * (q2 * q4 - q1 * q3) - ax
            f2 = 2.0 * (q1 * q2 + q3 * q4) - ay
            f3 = 2.0 * (0.5 - q2 * q2 - q3 * q3) - az
            s1 += -2.0 * q3 * f1 + 2.0 * q2 * f2
            s2 += 2.0 * q4 * f1 + 2.0 * q1 * f2 - 4.0 * q2 * f3
            s3 += -2.0 * q1 * f1 + 2.0 * q4 * f2 - 4.0 * q3 * f3
            s4 += 2.0 * q2 * f1 + 2.0 * q3 * f2
            if use_mag:
                mx, my, mz, mn = _unit3(mag[i, 0], mag[i, 1], mag[i, 2])
                if mn > 0.0:
                    # field in the earth frame, h = q m q*
                    hx = mx * (1 - 2 * (q3 * q3 + q4 * q4)) + my * 2 * (q2 * q3 - q1 * q4) + mz * 2 * (q2 * q4 + q1 * q3)
                    hy = mx * 2 * (q2 * q3 + q1 * q4) + my * (1 - 2 * (q2 * q2 + q4 * q4)) + mz * 2 * (q3 * q4 - q1 * q2)
                    hz = mx * 2 * (q2 * q4 - q1 * q3) + my * 2 * (q3 * q4 + q1 * q2) + mz * (1 - 2 * (q2 * q2 + q3 * q3))
                    bx = math.sqrt(hx * hx + hy * hy)
                    bz = hz
                    f4 = 2 * bx * (0.5 - q3 * q3 - q4 * q4) + 2 * bz * (q2 * q4 - q1 * q3) - mx
                    f5 = 2 * bx * (q2 * q3 - q1 * q4) + 2 * bz * (q1 * q2 + q3 * q4) - my
                    f6 = 2 * bx * (q1 * q3 + q2 * q4) + 2 * bz * (0.5 - q2 * q2 - q3 * q3) - mz
                    s1 += -2 * bz * q3 * f4 + (-2 * bx * q4 + 2 * bz * q2) * f5 + 2 * bx * q3 * f6
                    s2 += 2 * bz * q4 * f4 + (2 * bx * q3 + 2 * bz * q1) * f5 + (2 * bx * q4 - 4 * bz * q2) * f6
                    s3 += (-4 * bx * q3 - 2 * bz * q1) * f4 + (2 * bx * q2 + 2 * bz * q4) * f5 + (2 * bx * q1 - 4 * bz * q3) * f6
                    s4 += (-4 * bx * q4 + 2 * bz * q2) * f4 + (-2 * bx * q1 + 2 * bz * q3) * f5 + 2 * bx * q2 * f6
            sn = math.sqrt(s1 * s1 + s2 * s2 + s3 * s3 + s4 * s4)
            if sn > 1e-12:
                d1 -= beta * s1 / sn
                d2 -= beta * s2 / sn
                d3 -= beta * s3 / sn
                d4 -= beta * s4 / sn
        q1 += d1 * h
        q2 += d2 * h
        q3 += d3 * h
        q4 += d4 * h
        nrm = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3 + q4 * q4)
        q1, q2, q3, q4 = q1 / nrm, q2 / nrm, q3 / nrm, q4 / nrm
        out[i, 0] = q1
        out[i, 1] = q2
        out[i, 2] = q3
        out[i, 3] = q4
    return out


@njit(cache=True)
def complementary_run(q0, dt, acc, gyr, mag, use_mag, tau_tilt, tau_heading, alpha):  # pragma: no cover
    """Complementary filter; heading blend of the smartphone thesis (§2.4, eqs. 15-16, 33).

    The gyroscope integrates the orientation exactly (``q ⊗ exp(ω dt / 2)``). Tilt is
    pulled towards the accelerometer's gravity by the fraction ``dt/(τ_tilt + dt)`` of the
    angle between them. Heading is blended with the tilt-compensated compass,
    ``θ = α (θ_prev + ω Δt) + (1 − α) θ_compass`` (eq. 33), computed wrap-safe as
    ``θ_pred + (1 − α)·wrap(θ_compass − θ_pred)``; ``α = τ/(τ + Δt)`` (eq. 16) unless a fixed
    ``alpha`` in (0, 1] is given.
    """
    n = dt.shape[0]
    out = np.empty((n, 4))
    w, x, y, z = q0[0], q0[1], q0[2], q0[3]
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i, 0] * h, gyr[i, 1] * h, gyr[i, 2] * h
        ang = math.sqrt(gx * gx + gy * gy + gz * gz)
        if ang > 1e-15:
            s = math.sin(0.5 * ang) / ang
            w, x, y, z = _qmul(w, x, y, z, math.cos(0.5 * ang), gx * s, gy * s, gz * s)
        ax, ay, az, an = _unit3(acc[i, 0], acc[i, 1], acc[i, 2])
        if an > 0.0 and tau_tilt >= 0.0:
            apx = 2.0 * (x * z - w * y)
            apy = 2.0 * (y * z + w * x)
            apz = 1.0 - 2.0 * (x * x + y * y)
            cx, cy, cz, cn = _unit3(ay * apz - az * apy, az * apx - ax * apz, ax * apy - ay * apx)
            if cn > 0.0:
                err = math.atan2(cn, ax * apx + ay * apy + az * apz)
                k = h / (tau_tilt + h) if tau_tilt + h > 0.0 else 1.0
                half = 0.5 * k * err
                sh = math.sin(half)
                w, x, y, z = _qmul(w, x, y, z, math.cos(half), cx * sh, cy * sh, cz * sh)
        if use_mag:
            mx, my, mz, mn = _unit3(mag[i, 0], mag[i, 1], mag[i, 2])
            if mn > 0.0:
                # field in the native frame; its horizontal direction should be +x
                hx = mx * (1 - 2 * (y * y + z * z)) + my * 2 * (x * y - w * z) + mz * 2 * (x * z + w * y)
                hy = mx * 2 * (x * y + w * z) + my * (1 - 2 * (x * x + z * z)) + mz * 2 * (y * z - w * x)
                if hx * hx + hy * hy > 1e-12:
                    e = math.atan2(hy, hx)  # compass minus predicted heading, already wrapped
                    a = alpha if alpha > 0.0 else tau_heading / (tau_heading + h)
                    half = -0.5 * (1.0 - a) * e
                    # rotation about the native z axis applied on the left (earth frame)
                    cw, cz_ = math.cos(half), math.sin(half)
                    w, x, y, z = _qmul(cw, 0.0, 0.0, cz_, w, x, y, z)
        w, x, y, z = _store_unit(out, i, w, x, y, z)
    return out
