"""Compiled per-sample recursion of the decoupled filter; equations in :mod:`pdr.ahrs.decoupled`.

One call runs a whole batch and keeps every state in one float64 array ``s`` (offsets
``S_*``), so a live batch of ten samples costs one dispatch and the filter is a pure
function of its inputs: the same samples in batches of any size give the same bits.
Settings arrive packed in ``p`` (offsets ``P_*``; :meth:`DecoupledSettings.pack`).
"""
from __future__ import annotations

import math

from numba import njit

# -- settings vector (SI units: s, rad/s, m/s², rad; ratios dimensionless) --------------------
P_MAX_DT = 0
P_TAU_ACC = 1
P_ACC_RATE_MAX = 2
P_TAU_MAG = 3
P_TAU_REST = 4
P_REST_GYR = 5
P_REST_ACC = 6
P_REST_TIME = 7
P_BIAS_SIGMA_INIT = 8
P_BIAS_FORGET = 9
P_BIAS_SIGMA_REST = 10
P_BIAS_CLIP = 11
P_MAG_TAU_CURRENT = 12
P_MAG_TAU_REF = 13
P_MAG_NORM_TH = 14
P_MAG_DIP_TH = 15
P_MAG_FIRST_TIME = 16
P_MAG_NEW_TIME = 17
P_MAG_NEW_MIN_GYR = 18
P_MAG_MIN_UNDISTURBED = 19
P_MAG_MAX_REJECT = 20
P_MAG_REJECT_FACTOR = 21
P_BIAS_SIGMA_FORGET = 22
P_ACC_RATE_FAST = 23
P_ACC_TRUST_SIGMA = 24
P_ACC_TRUST_NORM = 25
P_ACC_RELEVEL_ANGLE = 26
N_PARAMS = 27

# -- state vector ------------------------------------------------------------------------------
S_STARTED = 0  # 0 before the first sample, 1 after
S_T = 1  # time of the last sample, s
S_QG = 2  # 2..5: strapdown quaternion, body -> almost-inertial frame I
S_QA = 6  # 6..9: inclination correction, I -> 6D earth frame E6 (no turn about up)
S_DELTA = 10  # heading offset δ about up, E6 -> E, rad
S_BIAS = 11  # 11..13: gyroscope bias, body frame, rad/s
S_BIAS_P = 14  # variance of each bias component, (rad/s)²
S_ACC_LP = 15  # 15..23: low-pass of the specific force in I (outputs 3, filter states 6)
S_ACC_INIT_T = 24  # time spent averaging the first samples, s (< tau_acc while averaging)
S_ACC_INIT_N = 25  # samples averaged so far
S_ACC_MEAN = 26  # 26..28: running mean of the first samples, in I
S_REST_GYR_LP = 29  # 29..37: rest-detection low-pass of the gyroscope
S_REST_ACC_LP = 38  # 38..46: rest-detection low-pass of the accelerometer
S_REST_T = 47  # time the sensor has looked still, s
S_REST_INIT = 48  # 1 once the rest low-passes are primed
S_GYR_NORM_LP = 49  # low-passed |ω − b|, rad/s
S_HEAD_P = 50  # heading variance, in units of the magnetometer's heading noise intensity
S_MAG_INIT = 51  # 1 once the current-field low-pass is primed
S_MAG_NORM = 52  # low-passed field norm (the magnetometer's own units)
S_MAG_DIP = 53  # low-passed dip, rad
S_MAG_REF_NORM = 54  # reference norm (own units); 0 while still being learned
S_MAG_REF_DIP = 55  # reference dip, rad
S_MAG_LEARN_T = 56  # magnetometer time spent learning the first reference, s
S_MAG_LEARN_N = 57  # samples averaged into it
S_MAG_CAND_NORM = 58  # candidate new reference norm
S_MAG_CAND_DIP = 59  # candidate new reference dip, rad
S_MAG_CAND_ON = 60  # 1 while a candidate is held
S_MAG_CAND_T = 61  # time the candidate has held while the sensor turned, s
S_MAG_UNDIST_T = 62  # time the field has matched the reference without a break, s
S_MAG_REJECT_T = 63  # time the heading correction has been held back, s
S_Q0_GIVEN = 64  # 1 when the filter started from a given orientation
N_STATE = 65

SQRT2 = math.sqrt(2.0)
HEAD_P_UNKNOWN = 1e12  # initial heading variance without a start orientation: the first field sample decides


@njit(cache=True, inline="always")
def _qmul(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product a ⊗ b, scalar first."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True, inline="always")
def _rotate(w, x, y, z, vx, vy, vz):
    """R(q) v for a unit quaternion q."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y - w * z) * vy + 2.0 * (x * z + w * y) * vz,
        2.0 * (x * y + w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy + 2.0 * (y * z - w * x) * vz,
        2.0 * (x * z - w * y) * vx + 2.0 * (y * z + w * x) * vy + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


@njit(cache=True, inline="always")
def _unit4(w, x, y, z):
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


@njit(cache=True, inline="always")
def _wrap(a):
    """Angle in (-π, π]."""
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi)) if (a > math.pi or a <= -math.pi) else a


@njit(cache=True, inline="always")
def _butter(tau, dt):
    """Second-order Butterworth low-pass for interval ``dt``: ``(b0, b1, b2, a1, a2)``.

    Bilinear transform with pre-warping of the cut-off ``f_c = √2 / (2π τ)`` (as
    VQF parametrises its filters), so the setting is a time constant in
    seconds and means the same smoothing at any sample rate.
    """
    k = math.tan(math.pi * (SQRT2 / (2.0 * math.pi * tau)) * dt)
    k2 = k * k
    d = 1.0 / (1.0 + SQRT2 * k + k2)
    b0 = k2 * d
    return b0, 2.0 * b0, b0, 2.0 * (k2 - 1.0) * d, (1.0 - SQRT2 * k + k2) * d


@njit(cache=True, inline="always")
def _butter_step(s, o, c, x0, x1, x2):
    """Three channels in ``s[o:o+9]`` (outputs, then two states each), transposed direct form II:
    ``y = b0 x + z1``, ``z1 ← b1 x − a1 y + z2``, ``z2 ← b2 x − a2 y``."""
    b0, b1, b2, a1, a2 = c
    y0 = b0 * x0 + s[o + 3]
    s[o + 3] = b1 * x0 - a1 * y0 + s[o + 4]
    s[o + 4] = b2 * x0 - a2 * y0
    y1 = b0 * x1 + s[o + 5]
    s[o + 5] = b1 * x1 - a1 * y1 + s[o + 6]
    s[o + 6] = b2 * x1 - a2 * y1
    y2 = b0 * x2 + s[o + 7]
    s[o + 7] = b1 * x2 - a1 * y2 + s[o + 8]
    s[o + 8] = b2 * x2 - a2 * y2
    s[o], s[o + 1], s[o + 2] = y0, y1, y2


@njit(cache=True, inline="always")
def _butter_hold(s, o, c, x0, x1, x2):
    """Set three channels to the steady state of a constant input (output = input)."""
    b0, b1, b2, a1, a2 = c
    s[o], s[o + 1], s[o + 2] = x0, x1, x2
    s[o + 3], s[o + 4] = (1.0 - b0) * x0, (b2 - a2) * x0
    s[o + 5], s[o + 6] = (1.0 - b0) * x1, (b2 - a2) * x1
    s[o + 7], s[o + 8] = (1.0 - b0) * x2, (b2 - a2) * x2


@njit(cache=True)
def decoupled_start(s, q0, has_q0):  # pragma: no cover - compiled
    """Reset the state; ``q0`` (body -> ENU) is the start orientation when ``has_q0``."""
    s[:] = 0.0
    s[S_QG] = 1.0
    s[S_QA] = 1.0
    s[S_HEAD_P] = HEAD_P_UNKNOWN
    if has_q0:
        s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3] = q0[0], q0[1], q0[2], q0[3]
        s[S_HEAD_P] = 0.0  # the given heading is trusted; the magnetometer takes over at τ_mag
        s[S_Q0_GIVEN] = 1.0


@njit(cache=True)
def decoupled_run(s, p, t, acc, gyr, mag, use_mag, turn, out):  # pragma: no cover - compiled
    """Run the filter over one batch: ``s`` is updated in place, ``out`` (N, 4) filled.

    ``turn`` (scalar first) takes ENU to the caller's frame and multiplies every output on
    the left. Samples with a non-finite gyroscope or accelerometer reading are skipped
    (the previous orientation is repeated); a non-finite magnetometer sample only skips the
    heading correction.
    """
    n = t.shape[0]
    tau_acc = p[P_TAU_ACC]
    tau_rest = p[P_TAU_REST]
    rate_limit = p[P_ACC_RATE_MAX]
    relevel = p[P_ACC_RELEVEL_ANGLE]
    rate_fast = p[P_ACC_RATE_FAST]
    trust_w = -0.5 / (p[P_ACC_TRUST_SIGMA] * p[P_ACC_TRUST_SIGMA])
    trust_n = -0.5 / (p[P_ACC_TRUST_NORM] * p[P_ACC_TRUST_NORM])
    c_dt = -1.0
    c_acc = (0.0, 0.0, 0.0, 0.0, 0.0)
    c_rest = (0.0, 0.0, 0.0, 0.0, 0.0)
    k_cur = 0.0
    k_ref = 0.0
    k_gyr = 0.0
    for i in range(n):
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        ox, oy, oz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        finite = (ax - ax == 0.0 and ay - ay == 0.0 and az - az == 0.0
                  and ox - ox == 0.0 and oy - oy == 0.0 and oz - oz == 0.0)
        if s[S_STARTED] == 0.0:
            dt = 0.0
            s[S_STARTED] = 1.0
        else:
            dt = t[i] - s[S_T]
            if not dt > 0.0:  # repeated, backwards or NaN time stamp
                dt = 0.0
            elif dt > p[P_MAX_DT]:
                dt = p[P_MAX_DT]
                # A gap: how the sensor turned during it is unknown, so the memory of gravity in I
                # (the low-passed a_I) no longer points where gravity is. Kept, it would take
                # several tau_acc, slewed at acc_rate_max, to learn the new tilt, and the heading
                # meanwhile integrates the rates about a tilted axis (a 1.3 s gap in a phone walk
                # turned its steps by 130 deg). So the inclination starts again as at the first
                # sample: the running mean of a_I over tau_acc, levelled at once.
                s[S_ACC_INIT_T] = 0.0
                s[S_ACC_INIT_N] = 0.0
                s[S_ACC_MEAN], s[S_ACC_MEAN + 1], s[S_ACC_MEAN + 2] = 0.0, 0.0, 0.0
                s[S_Q0_GIVEN] = 0.0
        if t[i] == t[i]:
            s[S_T] = t[i]
        if not finite:
            dt = 0.0
        if dt > 0.0 and dt != c_dt:
            c_dt = dt
            c_acc = _butter(tau_acc, dt)
            c_rest = _butter(tau_rest, dt)
            k_cur = 1.0 - math.exp(-dt / p[P_MAG_TAU_CURRENT])
            k_ref = 1.0 - math.exp(-dt / p[P_MAG_TAU_REF])
            k_gyr = 1.0 - math.exp(-dt / tau_rest)

        gw, gx, gy, gz = s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
        if finite:
            # ---- 1. strapdown: q_g ← q_g ⊗ exp(½ (ω − b) dt)
            wx, wy, wz = ox - s[S_BIAS], oy - s[S_BIAS + 1], oz - s[S_BIAS + 2]
            gnorm = math.sqrt(wx * wx + wy * wy + wz * wz)
            ang = gnorm * dt
            if ang > 1e-15:
                sh = math.sin(0.5 * ang) / gnorm
                gw, gx, gy, gz = _qmul(gw, gx, gy, gz, math.cos(0.5 * ang), wx * sh, wy * sh, wz * sh)
                gw, gx, gy, gz = _unit4(gw, gx, gy, gz)
                s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3] = gw, gx, gy, gz

            # ---- 2. rest detection; the gyroscope bias is its low-passed rate at rest
            if dt > 0.0:
                if s[S_REST_INIT] == 0.0:
                    _butter_hold(s, S_REST_GYR_LP, c_rest, ox, oy, oz)
                    _butter_hold(s, S_REST_ACC_LP, c_rest, ax, ay, az)
                    s[S_GYR_NORM_LP] = gnorm
                    s[S_REST_INIT] = 1.0
                else:
                    _butter_step(s, S_REST_GYR_LP, c_rest, ox, oy, oz)
                    _butter_step(s, S_REST_ACC_LP, c_rest, ax, ay, az)
                    s[S_GYR_NORM_LP] += k_gyr * (gnorm - s[S_GYR_NORM_LP])
                lx, ly, lz = s[S_REST_GYR_LP], s[S_REST_GYR_LP + 1], s[S_REST_GYR_LP + 2]
                dgx, dgy, dgz = ox - lx, oy - ly, oz - lz
                dax, day, daz = ax - s[S_REST_ACC_LP], ay - s[S_REST_ACC_LP + 1], az - s[S_REST_ACC_LP + 2]
                clip = p[P_BIAS_CLIP]
                still = (dgx * dgx + dgy * dgy + dgz * dgz < p[P_REST_GYR] * p[P_REST_GYR]
                         and dax * dax + day * day + daz * daz < p[P_REST_ACC] * p[P_REST_ACC]
                         and abs(lx) < clip and abs(ly) < clip and abs(lz) < clip)
                s[S_REST_T] = s[S_REST_T] + dt if still else 0.0
                var_max = p[P_BIAS_SIGMA_INIT] * p[P_BIAS_SIGMA_INIT]
                s[S_BIAS_P] = min(var_max, s[S_BIAS_P] + p[P_BIAS_SIGMA_FORGET] * p[P_BIAS_SIGMA_FORGET] * dt / p[P_BIAS_FORGET])
                if s[S_REST_T] >= p[P_REST_TIME]:
                    kb = s[S_BIAS_P] / (s[S_BIAS_P] + p[P_BIAS_SIGMA_REST] * p[P_BIAS_SIGMA_REST])
                    s[S_BIAS] += kb * (lx - s[S_BIAS])
                    s[S_BIAS + 1] += kb * (ly - s[S_BIAS + 1])
                    s[S_BIAS + 2] += kb * (lz - s[S_BIAS + 2])
                    s[S_BIAS_P] *= 1.0 - kb

            # ---- 3. inclination: the specific force low-passed in I, turned onto +z
            an = math.sqrt(ax * ax + ay * ay + az * az)
            if an > 0.0:
                aix, aiy, aiz = _rotate(gw, gx, gy, gz, ax, ay, az)
                starting = s[S_ACC_INIT_T] < tau_acc
                if starting and s[S_Q0_GIVEN] == 1.0:
                    # a given start orientation: the memory of gravity starts at its vertical
                    # (I = ENU at that instant), so its inclination is kept and then corrected
                    s[S_ACC_LP], s[S_ACC_LP + 1], s[S_ACC_LP + 2] = 0.0, 0.0, an
                    if dt > 0.0:
                        _butter_hold(s, S_ACC_LP, c_acc, 0.0, 0.0, an)
                        _butter_step(s, S_ACC_LP, c_acc, aix, aiy, aiz)
                        s[S_ACC_INIT_T] = tau_acc
                    starting = False
                elif starting:
                    # the first tau_acc seconds: the running mean, so the start needs no settling
                    m_n = s[S_ACC_INIT_N] + 1.0
                    s[S_ACC_INIT_N] = m_n
                    s[S_ACC_MEAN] += (aix - s[S_ACC_MEAN]) / m_n
                    s[S_ACC_MEAN + 1] += (aiy - s[S_ACC_MEAN + 1]) / m_n
                    s[S_ACC_MEAN + 2] += (aiz - s[S_ACC_MEAN + 2]) / m_n
                    s[S_ACC_INIT_T] += dt
                    s[S_ACC_LP], s[S_ACC_LP + 1], s[S_ACC_LP + 2] = s[S_ACC_MEAN], s[S_ACC_MEAN + 1], s[S_ACC_MEAN + 2]
                    if dt > 0.0:
                        _butter_hold(s, S_ACC_LP, c_acc, s[S_ACC_MEAN], s[S_ACC_MEAN + 1], s[S_ACC_MEAN + 2])
                elif dt > 0.0:
                    _butter_step(s, S_ACC_LP, c_acc, aix, aiy, aiz)
                qw, qx, qy, qz = s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3]
                ex, ey, ez = _rotate(qw, qx, qy, qz, s[S_ACC_LP], s[S_ACC_LP + 1], s[S_ACC_LP + 2])
                hn = math.sqrt(ex * ex + ey * ey)
                if hn > 1e-12 * an:
                    # turn about (e × z)/|e × z| = (e_y, −e_x, 0)/h by ∠(e, z), at most the rate limit
                    turn_angle = math.atan2(hn, ez)
                    if not starting and turn_angle > relevel:
                        # a tilt error no sustained acceleration explains: the attitude was lost
                        # (a fast wave, a gyro scale error); levelled at once, and the memory of
                        # gravity starts again as after a gap (it lags the truth by tau_acc)
                        s[S_ACC_INIT_T] = 0.0
                        s[S_ACC_INIT_N] = 0.0
                        s[S_ACC_MEAN], s[S_ACC_MEAN + 1], s[S_ACC_MEAN + 2] = 0.0, 0.0, 0.0
                        s[S_Q0_GIVEN] = 0.0
                        starting = True
                    if rate_limit > 0.0 and not starting and turn_angle > rate_limit * dt:
                        turn_angle = rate_limit * dt  # the start levels at once, later tilts are slewed
                    sh = math.sin(0.5 * turn_angle) / hn
                    qw, qx, qy, qz = _qmul(math.cos(0.5 * turn_angle), ey * sh, -ex * sh, 0.0, qw, qx, qy, qz)
                    qw, qx, qy, qz = _unit4(qw, qx, qy, qz)
                    s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3] = qw, qx, qy, qz
                if rate_fast > 0.0 and not starting and dt > 0.0:
                    # fast path: towards this sample's specific force, by at most acc_rate_fast·w·dt;
                    # the trust w falls with the innovation e = R(q_a) a_I − |ā_I| z and with | |a| − |ā_I| |
                    g_ref = math.sqrt(s[S_ACC_LP] ** 2 + s[S_ACC_LP + 1] ** 2 + s[S_ACC_LP + 2] ** 2)
                    ex, ey, ez = _rotate(qw, qx, qy, qz, aix, aiy, aiz)
                    dz = ez - g_ref
                    dn = an - g_ref
                    w_trust = math.exp(trust_w * (ex * ex + ey * ey + dz * dz) + trust_n * dn * dn)
                    hn = math.sqrt(ex * ex + ey * ey)
                    if hn > 1e-12 * an:
                        turn_angle = min(math.atan2(hn, ez), rate_fast * w_trust * dt)
                        sh = math.sin(0.5 * turn_angle) / hn
                        qw, qx, qy, qz = _qmul(math.cos(0.5 * turn_angle), ey * sh, -ex * sh, 0.0, qw, qx, qy, qz)
                        qw, qx, qy, qz = _unit4(qw, qx, qy, qz)
                        s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3] = qw, qx, qy, qz

        # 6D orientation, body -> E6
        sw, sx, sy, sz = _qmul(s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3], gw, gx, gy, gz)

        # ---- 4. heading: a scalar Kalman filter on δ fed by the field's heading in E6
        s[S_HEAD_P] += dt / (p[P_TAU_MAG] * p[P_TAU_MAG])
        if use_mag and finite:
            mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
            mn = math.sqrt(mx * mx + my * my + mz * mz)
            if mn > 0.0 and mn - mn == 0.0:
                hx, hy, hz = _rotate(sw, sx, sy, sz, mx, my, mz)
                dip = math.asin(max(-1.0, min(1.0, -hz / mn)))
                if s[S_MAG_INIT] == 0.0:
                    s[S_MAG_NORM], s[S_MAG_DIP], s[S_MAG_INIT] = mn, dip, 1.0
                else:
                    s[S_MAG_NORM] += k_cur * (mn - s[S_MAG_NORM])
                    s[S_MAG_DIP] += k_cur * (dip - s[S_MAG_DIP])
                undisturbed = _field_check(s, p, dt, k_ref)
                hh = math.sqrt(hx * hx + hy * hy)
                if hh > 1e-9 * mn:
                    e = _wrap(0.5 * math.pi - math.atan2(hy, hx) - s[S_DELTA])  # δ_m − δ
                    r = 1.0 / dt if dt > 0.0 else 1.0  # a sample's variance: unit intensity over dt
                    use = True
                    if not undisturbed:
                        s[S_MAG_REJECT_T] += dt
                        if s[S_MAG_REJECT_T] < p[P_MAG_MAX_REJECT]:
                            use = False
                        else:
                            r *= p[P_MAG_REJECT_FACTOR] * p[P_MAG_REJECT_FACTOR]
                    if use:
                        k = s[S_HEAD_P] / (s[S_HEAD_P] + r)
                        s[S_HEAD_P] *= 1.0 - k
                        s[S_DELTA] = _wrap(s[S_DELTA] + k * e)

        # ---- 5. output: turn ⊗ R_z(δ) ⊗ q_a ⊗ q_g, scalar part ≥ 0
        half = 0.5 * s[S_DELTA]
        ow, ox, oy, oz = _qmul(math.cos(half), 0.0, 0.0, math.sin(half), sw, sx, sy, sz)
        ow, ox, oy, oz = _qmul(turn[0], turn[1], turn[2], turn[3], ow, ox, oy, oz)
        ow, ox, oy, oz = _unit4(ow, ox, oy, oz)
        if ow < 0.0:
            ow, ox, oy, oz = -ow, -ox, -oy, -oz
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = ow, ox, oy, oz
    return out


@njit(cache=True)
def _field_check(s, p, dt, k_ref):  # pragma: no cover - compiled
    """Magnetic disturbance test on the low-passed norm and dip; True when the field is usable.

    * The first ``mag_first_time`` seconds of field data are averaged into the reference
      (used meanwhile). Then the field is *undisturbed* once its norm is within
      ``mag_norm_th`` (relative) and its dip within ``mag_dip_th`` of the reference for
      ``mag_min_undisturbed`` seconds; the reference follows it slowly (``mag_tau_ref``).
    * A disturbed field that stays self-consistent (a new candidate norm and dip) while
      the sensor turns faster than ``mag_new_min_gyr`` for ``mag_new_time`` seconds is a
      new environment: it becomes the reference. A magnet attached to the sensor does not
      pass, because its field's norm and dip change as the sensor turns.
    """
    cur_n, cur_d = s[S_MAG_NORM], s[S_MAG_DIP]
    if s[S_MAG_REF_NORM] == 0.0:
        s[S_MAG_LEARN_N] += 1.0
        s[S_MAG_LEARN_T] += dt
        s[S_MAG_CAND_NORM] += (cur_n - s[S_MAG_CAND_NORM]) / s[S_MAG_LEARN_N]
        s[S_MAG_CAND_DIP] += (cur_d - s[S_MAG_CAND_DIP]) / s[S_MAG_LEARN_N]
        if s[S_MAG_LEARN_T] >= p[P_MAG_FIRST_TIME]:
            s[S_MAG_REF_NORM], s[S_MAG_REF_DIP] = s[S_MAG_CAND_NORM], s[S_MAG_CAND_DIP]
            s[S_MAG_CAND_ON] = 0.0
            s[S_MAG_UNDIST_T] = p[P_MAG_MIN_UNDISTURBED]
        return True
    ref_n, ref_d = s[S_MAG_REF_NORM], s[S_MAG_REF_DIP]
    if abs(cur_n - ref_n) < p[P_MAG_NORM_TH] * ref_n and abs(cur_d - ref_d) < p[P_MAG_DIP_TH]:
        s[S_MAG_UNDIST_T] += dt
    else:
        s[S_MAG_UNDIST_T] = 0.0
    if s[S_MAG_UNDIST_T] >= p[P_MAG_MIN_UNDISTURBED]:
        s[S_MAG_REF_NORM] += k_ref * (cur_n - ref_n)
        s[S_MAG_REF_DIP] += k_ref * (cur_d - ref_d)
        s[S_MAG_CAND_ON] = 0.0
        s[S_MAG_REJECT_T] = 0.0
        return True
    cn, cd = s[S_MAG_CAND_NORM], s[S_MAG_CAND_DIP]
    if s[S_MAG_CAND_ON] == 1.0 and abs(cur_n - cn) < p[P_MAG_NORM_TH] * cn and abs(cur_d - cd) < p[P_MAG_DIP_TH]:
        s[S_MAG_CAND_NORM] += k_ref * (cur_n - cn)
        s[S_MAG_CAND_DIP] += k_ref * (cur_d - cd)
        if s[S_GYR_NORM_LP] >= p[P_MAG_NEW_MIN_GYR]:
            s[S_MAG_CAND_T] += dt
    else:
        s[S_MAG_CAND_NORM], s[S_MAG_CAND_DIP] = cur_n, cur_d
        s[S_MAG_CAND_ON], s[S_MAG_CAND_T] = 1.0, 0.0
    if s[S_MAG_CAND_T] >= p[P_MAG_NEW_TIME]:
        s[S_MAG_REF_NORM], s[S_MAG_REF_DIP] = s[S_MAG_CAND_NORM], s[S_MAG_CAND_DIP]
        s[S_MAG_UNDIST_T] = p[P_MAG_MIN_UNDISTURBED]
        s[S_MAG_CAND_ON] = 0.0
        s[S_MAG_REJECT_T] = 0.0
        return True
    return False
