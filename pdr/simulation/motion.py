r"""The walker's motion in closed form, and what a phone's sensors read: the vectorised core.

A walker's plan (:mod:`pdr.simulation.plan`) is two tables. Every sample is evaluated from
one row of each, with no recursion, so a sample's value depends only on its time and its
index, never on how the stream was cut into batches.

**Time rows** ("segments", ``SEG_*``) give the step phase :math:`\varphi` (cycles; one cycle
is one step) and an envelope :math:`e \in [0, 1]` (how much the walker is walking). With
:math:`\tau = t - t_o` and a ramp time :math:`T_r`

.. math::

    e(\tau) = e_a + e_b \cos(\pi\tau/T_r), \qquad
    \varphi(\tau) = \varphi_0 + f\,\big(e_a\tau + e_b\,\tfrac{T_r}{\pi}\sin(\pi\tau/T_r)\big),
    \qquad \dot\varphi = f e

so cruising is :math:`(e_a, e_b) = (1, 0)`, starting :math:`(\tfrac12, -\tfrac12)`, stopping
from :math:`e_0` is :math:`(\tfrac{e_0}2, \tfrac{e_0}2)` and standing :math:`(0, 0)` with
:math:`f = 0` (speed and bounce go to zero smoothly, with zero slope at both ends). A row
also turns the walker on the spot or tips the phone over (a collapse): yaw, pitch and roll
offsets :math:`y_0 + \Delta_y S(\tau/T_a)`, :math:`p_0 + \Delta_p S(\tau/T_a)`,
:math:`r_0 + \Delta_r S(\tau/T_a)` with the smooth step

.. math:: S(x) = x - \frac{\sin 2\pi x}{2\pi}, \quad S'(x) = 1 - \cos 2\pi x \quad (x \in [0, 1])

whose rate is zero at both ends (no jump in the gyroscope).

**Path rows** ("pieces", ``PC_*``) map phase to the place on the path. With
:math:`x = \varphi - \varphi_0` the step length :math:`\lambda(x) = \lambda_0 + G\min(x, W)`
changes linearly over the first :math:`W` steps of a row (from the previous row's length:
the speed never jumps) and the arc length is

.. math:: u = u_0 + \lambda_0 x + G\,m\,(x - m/2), \quad m = \min(x, W), \qquad
    \dot u = \lambda\dot\varphi, \quad \ddot u = \lambda\ddot\varphi + G\,[x < W]\,\dot\varphi^2.

A line has heading :math:`\psi_0`, :math:`\mathbf p = \mathbf p_0 + u(\cos\psi_0, \sin\psi_0)`; a
corner taken while walking is a curve of length :math:`L_s` whose heading is
:math:`\psi(u) = \psi_0 + \Delta\psi\,S(u/L_s)` (the turn rate rises and falls smoothly) and
:math:`\mathbf p(u) = \mathbf p_0 + \int_0^u (\cos\psi, \sin\psi)\,ds` by 8-point
Gauss-Legendre quadrature. On a flight of stairs (a line of :math:`X` steps) the height
follows the steps, not the distance: :math:`z = z_0 + k\,h(x)` where the climb eases in and
out over :math:`\epsilon` steps, :math:`h' = \min(1, x/\epsilon, (X - x)/\epsilon)`, so
:math:`h(X) = X - \epsilon` and :math:`k = \Delta z / (X - \epsilon)`: the vertical speed
(about a riser per step) never jumps, however steep the flight.

**Specific force** (ENU, what an accelerometer at rest reads is :math:`(0, 0, g)`):

.. math::

    \mathbf f = \ddot u\,\mathbf t + \dot u\,\dot\psi\,\mathbf n
      + \gamma\,\big[A \sin 2\pi\varphi\;\mathbf k + B \sin(2\pi\varphi + \delta_f)\,\mathbf t
      - C \sin(\pi\varphi + \delta_l)\,\mathbf n\big] + (g + \ddot z)\,\mathbf k,
    \qquad \gamma = \dot\varphi / f_w

with :math:`\mathbf t` the walking direction, :math:`\mathbf n` its left, :math:`\mathbf k`
up and :math:`f_w` the walker's own cadence: the path's own acceleration (speeding up, the
centripetal part in a corner) plus the gait — a bounce of the body at the step frequency,
a surge along the path and a sway to the sides at half of it (one stride). The gait scale
:math:`\gamma` is 1 when cruising on the flat, 0 standing, and unlike :math:`e` it never
jumps when the cadence changes between legs.

**Attitude** (the phone held flat in front: body x right, y forward, z up, Android's
axes), rotating body -> ENU, scalar first:

.. math:: R = R_z(\alpha)\,R_x(\theta)\,R_y(\rho), \qquad q = q_z(\alpha) \otimes q_x(\theta) \otimes q_y(\rho)

with yaw :math:`\alpha = \psi + y - \pi/2 + \gamma\,Y\sin(\pi\varphi + \delta_y)` (body y
along the heading), pitch :math:`\theta = p + \gamma\,P\sin(2\pi\varphi + \delta_p)` and roll
:math:`\rho = r + \gamma\,Q\sin(\pi\varphi + \delta_r)`. Differentiating :math:`R` gives the
body rate

.. math::

    \boldsymbol\omega = \big(\cos\rho\,\dot\theta - \sin\rho\cos\theta\,\dot\alpha,\;
      \sin\theta\,\dot\alpha + \dot\rho,\;
      \sin\rho\,\dot\theta + \cos\rho\cos\theta\,\dot\alpha\big).

**Sensors**: accelerometer :math:`R^\mathsf T\mathbf f + \mathbf n_a`, gyroscope
:math:`\boldsymbol\omega + \mathbf b + \mathbf n_g`, magnetometer
:math:`R^\mathsf T\mathbf B + \mathbf n_m`, barometer :math:`p(z)` by the inverse of
:func:`pdr.height.relative_height` (:func:`pdr.height.pressure_at_height`) plus noise.

**Noise** is a pure function of (walker key, sample index): a SplitMix64 hash of the
counter (Steele, Lea, Flood, "Fast splittable pseudorandom number generators", OOPSLA 2014)
picks two vectors from two fixed pools of normals, whose sum is the sample's noise (all
channels). Any batching, and a whole fleet at once, therefore give the same noise as one
long call.
"""
from __future__ import annotations

import math

import numpy as np

from pdr.constants import GRAVITY
from pdr.fixed_order import row_dot
from pdr.height import AltimeterSettings, pressure_at_height

TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi

# time rows (segments): columns
(SEG_T0, SEG_T1, SEG_TO, SEG_PHI0, SEG_F, SEG_EA, SEG_EB, SEG_TR,
 SEG_Y0, SEG_DY, SEG_P0, SEG_DP, SEG_R0, SEG_DR, SEG_TA, SEG_LO, SEG_HI) = range(17)
NSEG = 17
# path rows (pieces): columns
(PC_PHI0, PC_LAM, PC_G, PC_W, PC_U0, PC_X0, PC_Y0, PC_PSI0, PC_C, PC_S, PC_DPSI, PC_LS, PC_Z0, PC_ZK,
 PC_ZX, PC_ZE) = range(16)
NPC = 16

# per-walker traits: columns
(TR_AUP, TR_AFW, TR_ALAT, TR_DF, TR_DL, TR_DP, TR_DR, TR_DY, TR_BX, TR_BY, TR_BZ, TR_F) = range(12)
NTR = 12

NOISE_CHANNELS = 10  # acc xyz, gyr xyz, mag xyz, pressure

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_T = 0.5 * (_GL_X + 1.0)  # nodes on [0, 1]


_SC_N = 1024  # table points per turn
_SC_STEP = TWO_PI / _SC_N
_SC_SIN = np.array([math.sin(i * _SC_STEP) for i in range(_SC_N)])
_SC_COS = np.array([math.cos(i * _SC_STEP) for i in range(_SC_N)])


def sincos(x):
    """``sin x, cos x`` to about 2 ulp for moderate ``|x|`` (up to thousands of radians).

    numpy's float64 sine and cosine run scalar library code (about 25 ns per element here,
    the largest cost of the simulator); this is a table of 1024 points per turn and the
    angle-sum formula with short Taylor series for the remainder ``|b| <= π/1024``:
    ``sin(a + b) = sin a cos b + cos a sin b`` with ``sin b ≈ b - b³/6 + b⁵/120`` and
    ``cos b ≈ 1 - b²/2 + b⁴/24 - b⁶/720`` (truncation below 1e-20), all vectorised.
    """
    j = np.rint(x * (1.0 / _SC_STEP))
    b = x - j * _SC_STEP
    i = j.astype(np.int64) & (_SC_N - 1)
    sa, ca = np.take(_SC_SIN, i), np.take(_SC_COS, i)
    b2 = b * b
    sb = b - b * b2 * ((1.0 / 6.0) - b2 * (1.0 / 120.0))
    cb = 1.0 - b2 * (0.5 - b2 * ((1.0 / 24.0) - b2 * (1.0 / 720.0)))
    return sa * cb + ca * sb, ca * cb - sa * sb


def smooth_step(x):
    """``S(x) = x - sin(2πx)/(2π)`` on ``x`` clipped to [0, 1], and ``S'(x) = 1 - cos(2πx)``."""
    x = np.clip(x, 0.0, 1.0)
    a = TWO_PI * x
    return x - np.sin(a) / TWO_PI, 1.0 - np.cos(a)


def phase_profile(tau, phi0, f, ea, eb, tr):
    """Step phase (cycles), envelope ``e`` and its rate ``ė`` (1/s) of a time row at ``tau``."""
    x = (math.pi / tr) * tau
    c, s = np.cos(x), np.sin(x)
    e = ea + eb * c
    phi = phi0 + f * (ea * tau + (eb * tr / math.pi) * s)
    return phi, e, -(eb * math.pi / tr) * s


def curve_offset(u, psi0, dpsi, ls):
    """``∫_0^u (cos ψ, sin ψ) ds`` for ``ψ(s) = ψ0 + Δψ S(s / L_s)``: 8-point Gauss-Legendre."""
    u = np.asarray(u, float)
    s = u[..., None] * _GL_T
    psi = np.asarray(psi0, float)[..., None] + np.asarray(dpsi, float)[..., None] * smooth_step(s / np.asarray(ls, float)[..., None])[0]
    half = 0.5 * u
    sn, cs = sincos(psi)
    return half * row_dot(cs, _GL_W), half * row_dot(sn, _GL_W)


def corner_cut(turn: float) -> float:
    """Distance from a corner to where a smooth turn of ``turn`` rad and unit length starts.

    The curve is symmetric about the corner's bisector, so its chord ``D`` from start to
    end satisfies ``D = d (1 + cos Δψ, sin Δψ)`` for the cut ``d`` (in the incoming frame).
    """
    _, dy = curve_offset(1.0, 0.0, turn, 1.0)
    return float(dy / math.sin(turn))


# -------------------------------------------------------------------------------------------
# noise: counter-based picks from two small pools of normal vectors
# -------------------------------------------------------------------------------------------
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
POOL_BITS = 12  # 4096 vectors per pool: two pools of 320 kB stay in a core's cache
_POOLS = np.random.default_rng(0x5EED_F12E).standard_normal((2, 1 << POOL_BITS, NOISE_CHANNELS)) / math.sqrt(2.0)
_tables: dict[tuple, np.ndarray] = {}


def _splitmix64(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def noise_table(sigma) -> np.ndarray:
    """The two pools scaled by each channel's standard deviation: (2, 4096, NOISE_CHANNELS)."""
    key = tuple(float(v) for v in sigma)
    if key not in _tables:
        _tables[key] = _POOLS * np.asarray(key)
    return _tables[key]


def gaussian_noise(keys: np.ndarray, k: np.ndarray, table: np.ndarray, scratch: np.ndarray | None = None) -> np.ndarray:
    """Noise of shape ``k.shape + (NOISE_CHANNELS,)``: a pure function of walker key and sample index.

    ``keys`` (W,) uint64, ``k`` (W, n) sample indices, ``table`` from :func:`noise_table`. One
    hash per sample, ``h = splitmix64(key + (k+1)·φ64)``; its top two 12-bit fields pick one
    vector from each pool of normals (drawn once, fixed seed, each of variance ½), and their
    sum is the sample's noise: one of 16.8 million normal vectors, i.i.d. across samples.
    ``scratch`` (2, W, n, NOISE_CHANNELS) receives the picks (reused buffers spare the page
    faults of fresh large arrays); the noise is ``scratch[0]`` then.
    """
    h = _splitmix64(keys.astype(np.uint64)[:, None] + (k.astype(np.uint64) + np.uint64(1)) * _GOLDEN)
    i = (h >> np.uint64(64 - POOL_BITS)).astype(np.intp)
    j = ((h >> np.uint64(64 - 2 * POOL_BITS)) & np.uint64((1 << POOL_BITS) - 1)).astype(np.intp)
    if scratch is None:
        scratch = np.empty((2,) + k.shape + (table.shape[-1],))
    # mode="clip" (the indices are in range anyway) lets take write straight into `out`
    np.take(table[0], i, axis=0, out=scratch[0], mode="clip")
    np.take(table[1], j, axis=0, out=scratch[1], mode="clip")
    return np.add(scratch[0], scratch[1], out=scratch[0])


# -------------------------------------------------------------------------------------------
# the core
# -------------------------------------------------------------------------------------------
def evaluate(t, k, seg, path_rows, traits, keys, settings, out) -> None:
    """Truth and sensor readings of samples ``t`` (W, n) with indices ``k`` (W, n), written into ``out``.

    ``seg`` (NSEG, W, n) are the time rows of each sample; ``path_rows(phi)`` returns the path
    rows (NPC, W, n) for the samples' phases; ``traits`` (W, NTR) are the walkers' constants
    (amplitudes, phases, gyro bias, cadence), ``keys`` (W,) their noise keys. ``out`` maps names
    to (views of) arrays to fill: ``imu`` (W, n, 3, 3) = acc, gyr, mag; ``pressure`` (W, n), NaN
    between barometer samples; ``x``, ``y``, ``z``, ``heading``, ``phase`` (W, n); ``q`` (W, n, 4)
    body -> ENU if present; ``noise`` (2, W, n, NOISE_CHANNELS) scratch. Terms that are zero for
    most samples (ramps, turns on the spot, corners, stairs) are computed on those samples only.
    """
    s = settings
    tr = traits[:, :, None]  # (W, NTR, 1): broadcasts against (W, n)
    # -- time row: phase, envelope, on-the-spot turns, falls
    tau = t - seg[SEG_TO]
    f = seg[SEG_F]
    e = seg[SEG_EA].copy()
    phi = seg[SEG_PHI0] + f * (e * tau)  # cruising or standing (e_b = 0)
    edot = np.zeros_like(tau)
    ramp = seg[SEG_EB] != 0.0
    if ramp.any():  # starting, stopping, changing cadence
        phi[ramp], e[ramp], edot[ramp] = phase_profile(tau[ramp], seg[SEG_PHI0][ramp], f[ramp], e[ramp],
                                                       seg[SEG_EB][ramp], seg[SEG_TR][ramp])
    phid = f * e
    phidd = f * edot
    # gait and sway scale with the step rate relative to the walker's own cadence (1 when cruising
    # on the flat, 0 standing); unlike e it never jumps when the cadence changes between legs
    g = phid / tr[:, TR_F]
    gd = phidd / tr[:, TR_F]
    yaw_x, pitch_x, roll_x = seg[SEG_Y0].copy(), seg[SEG_P0].copy(), seg[SEG_R0].copy()
    yaw_xd, pitch_xd, roll_xd = np.zeros_like(tau), np.zeros_like(tau), np.zeros_like(tau)
    act = (seg[SEG_DY] != 0.0) | (seg[SEG_DP] != 0.0) | (seg[SEG_DR] != 0.0)
    if act.any():  # only while turning on the spot or falling
        ta = seg[SEG_TA][act]
        S, dS = smooth_step(tau[act] / ta)
        for ang, rate, col in ((yaw_x, yaw_xd, SEG_DY), (pitch_x, pitch_xd, SEG_DP), (roll_x, roll_xd, SEG_DR)):
            d = seg[col][act]
            ang[act] += d * S
            rate[act] = d * dS / ta

    # -- path row: place, heading of the path, height
    pc = path_rows(phi)
    xp = phi - pc[PC_PHI0]
    m = np.minimum(xp, pc[PC_W])
    lam = pc[PC_LAM] + pc[PC_G] * m
    u = pc[PC_U0] + pc[PC_LAM] * xp + pc[PC_G] * m * (xp - 0.5 * m)
    ud = lam * phid
    udd = lam * phidd
    sw = xp < pc[PC_W]
    if sw.any():  # the step length is changing
        udd[sw] += pc[PC_G][sw] * phid[sw] ** 2
    cpsi = pc[PC_C].copy()
    spsi = pc[PC_S].copy()
    psi = pc[PC_PSI0].copy()
    x = pc[PC_X0] + u * cpsi
    y = pc[PC_Y0] + u * spsi
    psid = np.zeros_like(u)
    bend = pc[PC_DPSI] != 0.0
    if bend.any():  # corners taken while walking
        ub, ls, p0, dp = u[bend], pc[PC_LS][bend], pc[PC_PSI0][bend], pc[PC_DPSI][bend]
        S, dS = smooth_step(ub / ls)
        pb = p0 + dp * S
        psi[bend] = pb
        spsi[bend], cpsi[bend] = sincos(pb)
        ox, oy = curve_offset(ub, p0, dp, ls)
        x[bend] = pc[PC_X0][bend] + ox
        y[bend] = pc[PC_Y0][bend] + oy
        psid[bend] = dp * dS / ls * ud[bend]
    z = pc[PC_Z0].copy()
    zdd = np.zeros_like(u)
    climb = pc[PC_ZK] != 0.0
    if climb.any():  # stairs: the height follows the steps x (0..X) of the flight
        k_, n_x, ep = pc[PC_ZK][climb], pc[PC_ZX][climb], pc[PC_ZE][climb]
        xc = np.clip(xp[climb], 0.0, n_x)
        rest = n_x - xc
        h = np.where(xc < ep, 0.5 * xc * xc / ep, np.where(rest < ep, n_x - ep - 0.5 * rest * rest / ep, xc - 0.5 * ep))
        dh = np.minimum(1.0, np.minimum(xc, rest) / ep)
        ddh = np.where(xc < ep, 1.0, np.where(rest < ep, -1.0, 0.0)) / ep * (rest > 0.0)
        z[climb] += k_ * h
        zdd[climb] = k_ * (ddh * phid[climb] ** 2 + dh * phidd[climb])

    # -- specific force in ENU: path acceleration + gait + gravity
    s1, c1 = sincos(math.pi * np.mod(phi, 2.0))  # the phase grows without bound: reduce it first
    s2, c2 = 2.0 * s1 * c1, c1 * c1 - s1 * s1  # sin, cos of 2πφ

    def shifted(sk, ck, delta):  # sin and cos of (kπφ + δ) from those of kπφ; δ per walker
        cd, sd = np.cos(delta), np.sin(delta)
        return sk * cd + ck * sd, ck * cd - sk * sd

    a_fw = udd + g * tr[:, TR_AFW] * shifted(s2, c2, tr[:, TR_DF])[0]
    a_left = ud * psid - g * tr[:, TR_ALAT] * shifted(s1, c1, tr[:, TR_DL])[0]
    f_e = a_fw * cpsi - a_left * spsi
    f_n = a_fw * spsi + a_left * cpsi
    f_u = GRAVITY + g * tr[:, TR_AUP] * s2 + zdd

    # -- attitude: yaw, pitch, roll with their rates
    def sway(amp, k_pi, sk, ck, delta):
        sn, cs = shifted(sk, ck, delta)
        return g * amp * sn, amp * (gd * sn + g * k_pi * phid * cs)

    yaw_s, yaw_sd = sway(s.yaw_sway_rad, math.pi, s1, c1, tr[:, TR_DY])
    pitch_s, pitch_sd = sway(s.pitch_sway_rad, TWO_PI, s2, c2, tr[:, TR_DP])
    roll_s, roll_sd = sway(s.roll_sway_rad, math.pi, s1, c1, tr[:, TR_DR])
    heading = psi + yaw_x
    alpha = heading - HALF_PI + yaw_s
    alphad = psid + yaw_xd + yaw_sd
    theta = pitch_x + pitch_s
    thetad = pitch_xd + pitch_sd
    roll = roll_x + roll_s
    rolld = roll_xd + roll_sd
    sa, ca = sincos(alpha)
    st, ct = sincos(theta)
    sr, cr = sincos(roll)
    # rows of R = Rz(α) Rx(θ) Ry(ρ); M = Rx Ry has rows (cρ, 0, sρ), (sθsρ, cθ, -sθcρ), (-cθsρ, sθ, cθcρ)
    m10, m12 = st * sr, -st * cr
    r00, r01, r02 = ca * cr - sa * m10, -sa * ct, ca * sr - sa * m12
    r10, r11, r12 = sa * cr + ca * m10, ca * ct, sa * sr + ca * m12
    r20, r21, r22 = -ct * sr, st, ct * cr

    def to_body(ve, vn, vu):  # Rᵀ v
        return ve * r00 + vn * r10 + vu * r20, ve * r01 + vn * r11 + vu * r21, ve * r02 + vn * r12 + vu * r22

    B = s.field
    bias = traits[:, TR_BX:TR_BZ + 1]
    imu = out["imu"]
    for i, v in enumerate((*to_body(f_e, f_n, f_u),
                           cr * thetad - sr * ct * alphad + bias[:, 0:1],
                           st * alphad + rolld + bias[:, 1:2],
                           sr * thetad + cr * ct * alphad + bias[:, 2:3],
                           *to_body(B[0], B[1], B[2]))):
        imu[..., i // 3, i % 3] = v
    noise = gaussian_noise(keys, k, noise_table(_sigmas(s)), out["noise"])
    imu += noise[..., :9].reshape(t.shape + (3, 3))
    pressure = out["pressure"]
    pressure.fill(np.nan)
    at = (k % s.pressure_every) == 0
    if at.any():
        # weather drift counts from the walker's first sample (k / rate is the elapsed time)
        base = s.base_pressure_hpa + (s.pressure_drift_hpa_per_h / 3600.0 / s.rate_hz) * k[at]
        pressure[at] = pressure_at_height(z[at], base, AltimeterSettings(temperature_k=s.temperature_k)) \
            + noise[..., 9][at]
    out["x"][...], out["y"][...], out["z"][...], out["phase"][...] = x, y, z, phi
    out["heading"][...] = np.pi - np.mod(np.pi - heading, TWO_PI)
    if "q" in out:
        _euler_quaternion(ca, ct, cr, sa, st, sr, out["q"])


def _sigmas(s) -> tuple[float, ...]:
    """Noise standard deviation of each channel: acc xyz, gyr xyz, mag xyz, pressure."""
    return (s.acc_noise,) * 3 + (s.gyro_noise,) * 3 + (s.mag_noise,) * 3 + (s.pressure_noise_hpa,)


def sway_at(phi: float, g: float, traits_row: np.ndarray, settings) -> tuple[float, float, float]:
    """The phone's yaw, pitch and roll sway (rad) at phase ``phi`` and gait scale ``g``: the terms
    :func:`evaluate` adds to the attitude, for the planner (scalars)."""
    s, r = settings, traits_row
    return (g * s.yaw_sway_rad * math.sin(math.pi * phi + r[TR_DY]),
            g * s.pitch_sway_rad * math.sin(TWO_PI * phi + r[TR_DP]),
            g * s.roll_sway_rad * math.sin(math.pi * phi + r[TR_DR]))


def _half(c, s):
    """cos and sin of half an angle from its cos and sin, with cos(a/2) >= 0 (a in (-π, π]).

    ``cos(a/2) = √((1+c)/2)``, ``sin(a/2) = sgn(s)·√((1-c)/2)``: square roots instead of
    trigonometry; near a = ±π the sign may flip (q and -q are the same rotation)."""
    return np.sqrt(np.maximum(0.5 * (1.0 + c), 0.0)), np.copysign(np.sqrt(np.maximum(0.5 * (1.0 - c), 0.0)), s)


def _euler_quaternion(ca, ct, cr, sa, st, sr, q) -> None:
    """``q_z(α) ⊗ q_x(θ) ⊗ q_y(ρ)`` (scalar first, Hamilton) from the angles' cos and sin, into ``q``.

    Pitch and roll stay inside (-π, π) (the sway is small and a fall tips the phone by
    ``fall_pitch_rad`` < π), so their half-angle cosines are positive."""
    cz, sz = _half(ca, sa)
    cx, sx = _half(ct, st)
    cy, sy = _half(cr, sr)
    a, b, c, d = cz * cx, cz * sx, sz * sx, sz * cx  # q_z ⊗ q_x
    q[..., 0] = a * cy - c * sy
    q[..., 1] = b * cy - d * sy
    q[..., 2] = a * sy + c * cy
    q[..., 3] = d * cy + b * sy
