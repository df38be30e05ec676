"""Decoupled inclination and heading filter: gyro bias at rest, magnetic disturbance rejection.

The structure follows D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation
with bias estimation and magnetic disturbance rejection", Information Fusion 91 (2023)
187-204 (doi:10.1016/j.inffus.2022.10.014), written here from the paper; the heading
correction is a scalar Kalman filter of our own, the accelerometer correction may be
rate-limited, and a second, fast accelerometer correction acts while the accelerometer can
be trusted. Quaternions are scalar first, Hamilton, body -> frame. Per sample, with
``dt`` the interval (clipped to ``[0, max_dt]``):

1. **Strapdown** into an almost-inertial frame I (as in VQF)::

       q_g ← q_g ⊗ exp(½ (ω − b) dt)

2. **Inclination** (VQF's accelerometer update). The specific force is taken into I,
   ``a_I = R(q_g) a``, and low-passed there by a second-order Butterworth filter of time
   constant ``tau_acc`` (cut-off √2/(2π τ)); in I, gravity is constant while the linear
   accelerations of a moving body average out, whatever the body's rotation. The
   correction ``q_a`` (I -> E6, a turn about a horizontal axis) is then turned so that
   ``R(q_a) ā_I`` points up: by the whole angle ∠(R(q_a) ā_I, z) (VQF), but by at most
   ``acc_rate_max·dt`` (ours: a long, one-sided acceleration, e.g. a lift or a car, can
   then tilt the estimate only that fast), unless that angle passes ``acc_relevel_angle``:
   a tilt error of tens of degrees is no sustained acceleration (30° would take g·tan 30° =
   5.7 m/s² held for seconds) but a lost attitude, e.g. after a fast wave of a sensor whose
   gyroscope scale is 2 % off (200 rad of rotation: 4 rad of attitude error), and slewed at
   ``acc_rate_max`` it would take a minute to level: the inclination then starts again as
   after a gap, below (default ∞: always slewed). The first ``tau_acc`` seconds use the running
   mean of ``a_I`` instead, turned onto z in full (no rate limit), so the start needs no
   settling; so do the ``tau_acc`` seconds after a gap longer than ``max_dt`` (how the
   sensor turned in it is unknown, and the low-passed ``a_I`` would point the wrong way); a filter given a start orientation ``q0`` instead starts the low-pass at
   q0's vertical, so it keeps q0 and corrects it like any later error.

   **Fast path** (ours; the constant-step accelerometer correction of FSCF, Justa, Šmídl,
   Hamáček, Sensors 20(14):3824, 2020, eq. 33, applied only to a trusted sample). After the
   step above, ``q_a`` is turned towards *this* sample's specific force ``e = R(q_a) a_I``
   by ``min(∠(e, z), acc_rate_fast · w · dt)`` with the trust::

       w = exp(−|e − g z|² / (2 σ_e²) − (|a| − g)² / (2 σ_n²)),   g = |ā_I|

   (``ā_I`` the low-pass output, ``σ_e = acc_trust_sigma``, ``σ_n = acc_trust_norm``, m/s²):
   a Gaussian weight on the innovation of the sample against the gravity the filter now
   believes in. ``w`` is 1 while the sensor is not accelerating and the estimate is close,
   and falls towards 0 under linear acceleration, tapping and vibration. Why: a gyroscope whose axes are misaligned with the
   accelerometer's by an angle ε turns I by about ε·|ω| (Justa's recording: ε ≈ 3.5°, so
   6°/s at 100°/s of rotation), faster than the low-pass (lag ≈ ``tau_acc``) and the rate
   limit can follow; a constant step towards the trusted sample removes that drift, and a
   constant step follows the median of noisy samples rather than their spread. The 6D
   orientation is ``q_6 = q_a ⊗ q_g``.

3. **Gyroscope bias at rest** (VQF's rest-phase bias estimation). Gyroscope and accelerometer are
   low-passed (``tau_rest``); the sensor is at rest when for ``rest_time`` seconds every
   sample stays within ``rest_gyr`` and ``rest_acc`` of those low-passes and the low-passed
   rate is below ``bias_clip``. At rest a Kalman filter per axis moves ``b`` towards the
   low-passed rate (measurement σ ``bias_sigma_rest``); its variance grows by
   ``bias_sigma_forget²`` every ``bias_forget`` seconds, up to ``bias_sigma_init²``.

4. **Heading** (ours, on VQF's decoupling of heading from inclination). The field in E6,
   ``h = R(q_6) m``, gives the offset that turns its horizontal part to north (+y in ENU),
   ``δ_m = π/2 − atan2(h_y, h_x)``; only this angle about the vertical is used, so the
   magnetometer never tilts the inclination and its units do not matter. ``δ`` is a
   random walk estimated by a scalar Kalman filter, in units of the magnetometer's heading
   noise intensity (a sample over ``dt`` has variance ``1/dt``)::

       P ← P + dt / tau_mag²
       k = P / (P + 1/dt),   δ ← δ + k·wrap(δ_m − δ),   P ← (1 − k) P

   At steady state ``k ≈ dt / tau_mag``: a first-order filter of time constant
   ``tau_mag``. Without a start orientation ``P`` starts huge, so the first field samples
   set the heading (their running mean); with one it starts at 0. After a rejected
   stretch of length T, ``P`` has grown by T/τ², so the field is trusted again at once
   when it comes back: a drift built up while the field was disturbed is removed in
   seconds, not in τ.

5. **Magnetic disturbance** (VQF's norm-and-dip test and rejection): see :func:`pdr.ahrs._decoupled_kernel._field_check`.
   The norm is compared *relative* to the reference and the dip in radians, so raw counts,
   µT and unit vectors behave the same. While disturbed the heading correction is held
   back for up to ``mag_max_reject`` seconds, then used with its noise raised by
   ``mag_reject_factor``.

Output: ``q = R_z(δ) ⊗ q_a ⊗ q_g`` (body -> ENU), turned into the caller's frame.

Every time setting is in seconds and every rate in rad/s, so one setting means the same at
50 Hz and at 286 Hz. The defaults of the gains (``tau_acc``, ``acc_rate_max``, ``tau_mag``,
``acc_rate_fast``, ``acc_trust_sigma``, ``acc_trust_norm``) were chosen on the 14 BROAD trials
and Justa's Vicon recording, each data set (each IMU) one vote, by leave-one-recording-out
cross-validation (``firetrack tune ahrs --cv --balance dataset``; figures in ``docs/ahrs.md``);
the rest, bias and disturbance settings take the values of VQF's published defaults.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from pdr import quaternion as quat
from pdr.ahrs import _decoupled_kernel as K
from pdr.ahrs.base import FRAMES, FilterSettings, OrientationFilter

# q_frame<-ENU, applied on the left of every output
_FROM_ENU = {"ENU": quat.IDENTITY.copy(), "NWU": quat.from_yaw(-np.pi / 2)}


@dataclasses.dataclass(frozen=True)
class DecoupledSettings(FilterSettings):
    # -- gains: chosen by cross-validation (see the module docstring) --
    tau_acc: float = 1.2  # s, time constant of the specific-force low-pass in I
    acc_rate_max: float = 0.03  # rad/s, limit on the inclination correction rate (0: none)
    tau_mag: float = 25.0  # s, heading correction time constant
    acc_rate_fast: float = 0.2  # rad/s, fast inclination correction towards a trusted specific force (0: off)
    acc_trust_sigma: float = 1.0  # m/s², innovation |R(q_a) a_I − |ā_I| z| at which the fast step is weighted exp(−½)
    acc_trust_norm: float = 1.0  # m/s², | |a| − |ā_I| | at which the fast step is weighted exp(−½) (inf: not used)
    # rad; a tilt error beyond this (low-passed specific force against the believed vertical) skips
    # the rate limit and is levelled at once (inf: always slewed; the PDR sets it, see pdr.heading)
    acc_relevel_angle: float = math.inf
    # -- rest detection and bias (VQF defaults) --
    tau_rest: float = 0.5  # s, low-pass of the rest detector
    rest_gyr: float = math.radians(2.0)  # rad/s, largest gyroscope deviation at rest
    rest_acc: float = 0.5  # m/s², largest accelerometer deviation at rest
    rest_time: float = 1.5  # s, stillness needed before it counts as rest
    bias_sigma_init: float = math.radians(0.5)  # rad/s, bias uncertainty when unknown
    bias_forget: float = 100.0  # s, time in which the bias uncertainty grows by bias_sigma_forget
    bias_sigma_forget: float = math.radians(0.1)  # rad/s
    bias_sigma_rest: float = math.radians(0.03)  # rad/s, noise of the rest measurement of the bias
    bias_clip: float = math.radians(2.0)  # rad/s, a low-passed rate above this is not rest
    # -- magnetic disturbance (VQF defaults) --
    mag_tau_current: float = 0.05  # s, low-pass of the current norm and dip
    mag_tau_ref: float = 20.0  # s, how slowly the reference field follows an undisturbed field
    mag_norm_th: float = 0.1  # relative norm deviation that counts as disturbed
    mag_dip_th: float = math.radians(10.0)  # rad, dip deviation that counts as disturbed
    mag_first_time: float = 5.0  # s, field data averaged into the first reference
    mag_new_time: float = 20.0  # s, a consistent new field held this long becomes the reference
    mag_new_min_gyr: float = math.radians(20.0)  # rad/s, ... counting only while turning this fast
    mag_min_undisturbed: float = 0.5  # s, matching time before the field is used again
    mag_max_reject: float = 60.0  # s, longest stretch without heading correction
    mag_reject_factor: float = 2.0  # noise factor of the field after mag_max_reject

    def pack(self) -> np.ndarray:
        """The settings as the kernel's parameter vector (``P_*`` offsets)."""
        v = np.full(K.N_PARAMS, np.nan)
        for f in dataclasses.fields(self):
            v[getattr(K, "P_" + f.name.upper())] = float(getattr(self, f.name))
        if np.isnan(v).any():  # pragma: no cover - a programming error
            raise RuntimeError("DecoupledSettings and the kernel's parameter offsets disagree")
        return v


class Decoupled(OrientationFilter):
    """Streaming decoupled filter; ``update`` runs one compiled call per batch."""

    name = "decoupled"
    Settings = DecoupledSettings

    def __init__(self, settings: DecoupledSettings | None = None, q0: np.ndarray | None = None, frame: str = "ENU"):
        if frame not in FRAMES:
            raise ValueError(f"unknown frame {frame!r}; expected one of {FRAMES}")
        self.settings = settings if settings is not None else DecoupledSettings()
        _check(self.settings)
        self.frame = frame
        self._p = self.settings.pack()
        self._turn = _FROM_ENU[frame]
        self._s = np.zeros(K.N_STATE)
        q0_enu = np.zeros(4)
        if q0 is not None:
            q0_enu = quat.normalize(quat.multiply(quat.conjugate(self._turn), np.asarray(q0, dtype=float)))
        K.decoupled_start(self._s, q0_enu, q0 is not None)
        self._q0_frame = None if q0 is None else quat.normalize(np.asarray(q0, dtype=float))

    @property
    def q(self) -> np.ndarray | None:
        """The current orientation (body -> frame), or None before the first sample."""
        if self._s[K.S_STARTED] == 0.0:
            return self._q0_frame
        s = self._s
        half = 0.5 * s[K.S_DELTA]
        q = quat.multiply(quat.multiply(np.array([np.cos(half), 0.0, 0.0, np.sin(half)]), s[K.S_QA:K.S_QA + 4]),
                          s[K.S_QG:K.S_QG + 4])
        q = quat.normalize(quat.multiply(self._turn, q))
        return q if q[0] >= 0 else -q

    @property
    def kernel_state(self) -> np.ndarray:
        """The compiled filter's state vector (a copy): what a columnar engine keeps as a row."""
        return self._s.copy()

    @property
    def kernel_params(self) -> np.ndarray:
        """The settings packed for the compiled filter (:meth:`DecoupledSettings.pack`)."""
        return self._p

    @property
    def frame_turn(self) -> np.ndarray:
        """The quaternion from ENU to the output frame (scalar first)."""
        return np.ascontiguousarray(self._turn, dtype=float)

    @property
    def bias(self) -> np.ndarray:
        """The current gyroscope bias estimate (rad/s, body frame)."""
        return self._s[K.S_BIAS:K.S_BIAS + 3].copy()

    def update(self, t, acc, gyr, mag=None) -> np.ndarray:
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        n = t.shape[0]
        acc = np.ascontiguousarray(acc, dtype=np.float64)
        gyr = np.ascontiguousarray(gyr, dtype=np.float64)
        if acc.shape != (n, 3):
            raise ValueError(f"acc must have shape ({n}, 3), got {acc.shape}")
        if gyr.shape != (n, 3):
            raise ValueError(f"gyr must have shape ({n}, 3), got {gyr.shape}")
        use_mag = mag is not None
        if use_mag:
            mag = np.ascontiguousarray(mag, dtype=np.float64)
            if mag.shape != (n, 3):
                raise ValueError(f"mag must have shape ({n}, 3), got {mag.shape}")
        else:
            mag = acc  # not read
        out = np.empty((n, 4))
        K.decoupled_run(self._s, self._p, t, acc, gyr, mag, use_mag, self._turn, out)
        return out


def _check(s: DecoupledSettings) -> None:
    """Settings that would divide by zero or run backwards get a clear error."""
    positive = ("max_dt", "tau_acc", "tau_mag", "acc_relevel_angle", "acc_trust_sigma", "acc_trust_norm", "tau_rest", "rest_time", "bias_sigma_init", "bias_forget",
                "bias_sigma_rest", "bias_sigma_forget", "mag_tau_current", "mag_tau_ref", "mag_norm_th", "mag_dip_th", "mag_reject_factor")
    for name in positive:
        if not getattr(s, name) > 0:
            raise ValueError(f"decoupled filter: {name} must be > 0, got {getattr(s, name)!r}")
    for name in ("acc_rate_max", "acc_rate_fast", "rest_gyr", "rest_acc", "bias_clip",
                 "mag_first_time", "mag_new_time", "mag_new_min_gyr", "mag_min_undisturbed", "mag_max_reject"):
        if not getattr(s, name) >= 0:
            raise ValueError(f"decoupled filter: {name} must be >= 0, got {getattr(s, name)!r}")
