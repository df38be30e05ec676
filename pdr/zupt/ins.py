"""Zero-velocity-aided inertial navigation of one boot: :class:`ZuptIns`.

A strapdown INS integrates the boot's angular rate into attitude and its specific force
into velocity and position; its errors grow with time cubed. Foxlin ("Pedestrian tracking
with shoe-mounted inertial sensors", IEEE CG&A 25(6), 2005) noticed that the foot rests at
every stance and fed that as a pseudo-measurement "velocity = 0" to an error-state Kalman
filter; the errors then stay bounded between stances and position error grows roughly
with distance. OpenShoe (Nilsson, Skog, Händel, Hari, "Foot-mounted INS for everybody — an
open-source embedded implementation", IEEE/ION PLANS 2012) and PyShoe (Wagstaff,
Peretroukhin, Kelly, IPIN 2017; Wagstaff and Kelly, IPIN 2018) are the open references;
this is our own implementation of the same filter with bias states.

State and frames. Navigation frame ENU (z up, ``g = (0, 0, −g)``); the boot's body frame
is whatever the IMU's axes are. The nominal state is position p (m), velocity v (m/s),
attitude q (scalar-first Hamilton quaternion, rotating body → ENU), accelerometer bias
b_a (m/s²) and gyro bias b_g (rad/s), both in the body frame. The filter estimates the
15-dimensional error state ``δx = (δp, δv, ε, δb_a, δb_g)`` with ε the small attitude
error in the navigation frame, ``R_true = (I + [ε×]) R``; its linearised dynamics
(Skog et al. 2010; Solà, "Quaternion kinematics for the error-state Kalman filter", 2017)::

    δṗ = δv
    δv̇ = −[f×] ε − R δb_a + n_a          f = R (f̃ − b_a)
    ε̇  = −R δb_g + n_g
    δḃ_a = n_ba,   δḃ_g = n_bg

discretised as ``F = I + A Δt``, ``Q = diag(0, σ_a² Δt I, σ_g² Δt I, σ_ba² Δt I, σ_bg² Δt I)``.
Updates: ZUPT ``z = −v`` with ``H = [0 I 0 0 0]``, and optionally ZARU
``z = ω̃ − b_g`` with ``H = [0 0 0 0 I]``; after each, the error is injected into the
nominal state (``q ← [1, ε/2] ⊗ q``) and reset.

Start. The INS starts at the first run of ``init_still_s`` stationary samples: roll and
pitch from their mean specific force, which points up at rest (ZYX Euler angles
``φ = atan2(f_y, f_z)``, ``θ = atan2(−f_x, √(f_y² + f_z²))``); yaw is ``initial_yaw``
(0 unless a compass or the operator says otherwise), so the track is drawn in a frame
turned from ENU by an unknown constant when nothing aligned it. Samples before the start
have no position (NaN).

Streaming: the detector and the INS carry their state between batches; a recording fed
in batches of any size gives the same positions and stances, bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdr import quaternion as quat
from pdr.zupt import _ins_kernel as _k
from pdr.zupt.detectors import Decisions, ZeroVelocityDetector
from pdr.zupt.settings import ZuptSettings


@dataclass(frozen=True)
class Stances:
    """The state of the INS once per stance (see :func:`pdr.zupt._ins_kernel.ins_run`)."""

    t: np.ndarray  # (k,) s
    position: np.ndarray  # (k, 3) m, ENU (in the INS's yaw frame)
    position_cov: np.ndarray  # (k, 3, 3) m²
    yaw_var: np.ndarray  # (k,) rad², variance of the yaw error
    peak_acc: np.ndarray  # (k,) m/s², largest ‖f‖ since the previous stance
    tilt: np.ndarray  # (k,) rad, the boot's tilt from its attitude at the start

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @staticmethod
    def from_events(ev: np.ndarray) -> Stances:
        c = ev[:, _k.E_PPP:_k.E_PPP + 6]
        cov = np.stack([c[:, [0, 1, 2]], c[:, [1, 3, 4]], c[:, [2, 4, 5]]], axis=1)
        return Stances(ev[:, _k.E_T].copy(), ev[:, _k.E_P:_k.E_P + 3].copy(), cov, ev[:, _k.E_PYAW].copy(),
                       ev[:, _k.E_PEAK].copy(), np.arccos(np.clip(ev[:, _k.E_TILT_COS], -1.0, 1.0)))

    @staticmethod
    def empty() -> Stances:
        return Stances.from_events(np.empty((0, _k.EVENT_COLS)))


@dataclass(frozen=True)
class InsOutput:
    """Everything one call of :meth:`ZuptIns.update` decided, in time order."""

    t: np.ndarray  # (m,) s
    position: np.ndarray  # (m, 3) m, ENU; NaN before the INS started
    stationary: np.ndarray  # (m,) bool, the detector's decision
    threshold: np.ndarray  # (m,) the detector's threshold at each sample
    quiet: np.ndarray  # (m,) bool, motionless by the detector's strict test (the man-down clock)
    stances: Stances

    def __len__(self) -> int:
        return int(self.t.shape[0])


def initial_attitude(f_mean: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """Attitude (w, x, y, z; body → ENU) of a resting body whose mean specific force is ``f_mean``.

    ZYX Euler angles: at rest ``f_body = Rᵀ (0, 0, g) = g (−sin θ, sin φ cos θ, cos φ cos θ)``,
    so ``φ = atan2(f_y, f_z)``, ``θ = atan2(−f_x, √(f_y² + f_z²))``;
    ``q = q_z(ψ) ⊗ q_y(θ) ⊗ q_x(φ)``.
    """
    fx, fy, fz = (float(v) for v in f_mean)
    roll = math.atan2(fy, fz)
    pitch = math.atan2(-fx, math.hypot(fy, fz))
    qx = np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
    qy = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
    qz = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    q = quat.multiply(qz, quat.multiply(qy, qx))
    return q / math.sqrt(float(np.sum(q * q)))


class ZuptIns:
    """Streaming boot INS: ``out = ins.update(t, acc, gyr)``, ``ins.finish()`` at the end.

    ``initial_yaw`` (rad, ENU yaw of the body x axis's horizontal projection at the start)
    fixes the INS frame; the default 0 draws the track in an arbitrary but fixed frame.
    """

    def __init__(self, settings: ZuptSettings | None = None, initial_yaw: float = 0.0):
        self.settings = s = settings or ZuptSettings()
        self.detector = ZeroVelocityDetector(s.detector)
        self.initial_yaw = float(initial_yaw)
        self._x = np.zeros(16)
        self._P = np.zeros((15, 15))
        self._aux = np.full(_k.AUX_SIZE, np.nan)
        self._par = np.zeros(_k.PAR_SIZE)
        self._pending: Decisions | None = None  # before the start: the stationary run so far
        self.started = False
        self.t_start = math.nan
        self.gravity = math.nan

    # ------------------------------------------------------------------ state
    @property
    def position(self) -> np.ndarray:
        return self._x[0:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self._x[3:6].copy()

    @property
    def attitude(self) -> np.ndarray:
        """Quaternion (w, x, y, z), body → ENU."""
        return self._x[6:10].copy()

    @property
    def acc_bias(self) -> np.ndarray:
        return self._x[10:13].copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        return self._x[13:16].copy()

    @property
    def covariance(self) -> np.ndarray:
        """(15, 15) covariance of (δp, δv, ε, δb_a, δb_g)."""
        return self._P.copy()

    # ------------------------------------------------------------------ streaming
    def update(self, t, acc, gyr) -> InsOutput:
        return self._run(self.detector.update(t, acc, gyr))

    def finish(self) -> InsOutput:
        """The stream has ended: the detector decides its last samples and the INS runs them."""
        out = self._run(self.detector.finish())
        if not self.started and self._pending is not None and len(self._pending):
            rest = self._outputs_before_start(self._pending)  # never started: no position
            self._pending = None
            return _concat([out, rest])
        return out

    def _run(self, d: Decisions) -> InsOutput:
        parts = []
        if not self.started:
            d = self._pending_with(d)
            i0 = self._start_index(d)
            if i0 < 0:  # no start yet: hold the stationary run at the end, give out the rest
                run = _trailing_run(d.stationary)
                head, self._pending = d.split(len(d) - run)
                return self._outputs_before_start(head)
            head, d = d.split(i0)
            parts.append(self._outputs_before_start(head))
            self._start(d)
        if len(d):
            if not parts:
                return self._integrate(d)
            parts.append(self._integrate(d))
        return _concat(parts) if parts else _empty_output()

    def _pending_with(self, d: Decisions) -> Decisions:
        if self._pending is None or not len(self._pending):
            return d
        p = self._pending
        self._pending = None
        return Decisions.concatenate(p, d)

    def _start_index(self, d: Decisions) -> int:
        """First sample of the first stationary run lasting ``init_still_s`` (-1: none yet)."""
        need = self.settings.ins.init_still_s
        zv = d.stationary
        if not zv.any():
            return -1
        edges = np.flatnonzero(np.diff(np.concatenate(([0], zv.astype(np.int8), [0]))))
        for a, b in zip(edges[::2], edges[1::2]):  # runs [a, b)
            if d.t[b - 1] - d.t[a] >= need:
                return int(a)
        return -1

    def _start(self, d: Decisions) -> None:
        s = self.settings
        need = s.ins.init_still_s
        end = int(np.searchsorted(d.t, d.t[0] + need, side="left")) + 1
        f = _k.mean_rows(np.ascontiguousarray(d.acc[:end]))
        g = s.ins.gravity if math.isfinite(s.ins.gravity) else float(math.sqrt(float(np.sum(f * f))))
        self.gravity = g
        q = initial_attitude(f, self.initial_yaw)
        x = self._x
        x[:] = 0.0
        x[6:10] = q
        ins = s.ins
        sig = [ins.init_position_sigma] * 3 + [ins.init_velocity_sigma] * 3 + [ins.init_tilt_sigma] * 2 + \
              [ins.init_yaw_sigma] + [ins.init_acc_bias_sigma] * 3 + [ins.init_gyro_bias_sigma] * 3
        self._P[:] = np.diag(np.square(sig))
        aux = self._aux
        aux[:] = np.nan
        aux[_k.A_EMITTED] = 0.0
        aux[_k.A_PEAK] = 0.0
        aux[_k.A_UP0:_k.A_UP0 + 3] = quat.to_matrix(q)[2]
        par = self._par
        par[_k.K_ACC_PSD] = ins.acc_noise_density ** 2
        par[_k.K_GYR_PSD] = ins.gyro_noise_density ** 2
        par[_k.K_BA_PSD] = ins.acc_bias_walk ** 2
        par[_k.K_BG_PSD] = ins.gyro_bias_walk ** 2
        par[_k.K_ZUPT_VAR] = ins.zupt_sigma ** 2
        par[_k.K_ZARU_VAR] = ins.zaru_sigma ** 2
        par[_k.K_GRAVITY] = g
        par[_k.K_MAX_DT] = ins.max_dt
        par[_k.K_SETTLE_S] = s.stride.settle_s
        par[_k.K_MIN_STANCE_S] = s.stride.min_stance_s
        par[_k.K_MIN_SWING_S] = s.stride.min_swing_s
        par[_k.K_ZARU_MAX_MS] = ins.zaru_max_rate ** 2  # 0: never
        self.started = True
        self.t_start = float(d.t[0])

    def _integrate(self, d: Decisions) -> InsOutput:
        pos, ev, _ = _k.ins_run(self._x, self._P, self._aux, self._par, d.rows, d.stationary, d.ared)
        return InsOutput(d.t, pos, d.stationary, d.threshold, d.quiet,
                         Stances.from_events(ev) if ev.shape[0] else _NO_STANCES)

    @staticmethod
    def _outputs_before_start(d: Decisions) -> InsOutput:
        return InsOutput(d.t, np.full((len(d), 3), np.nan), d.stationary, d.threshold, d.quiet, _NO_STANCES)


def _trailing_run(zv: np.ndarray) -> int:
    """Length of the run of True at the end of ``zv``."""
    if not zv.size or not zv[-1]:
        return 0
    false = np.flatnonzero(~zv)
    return int(zv.size - (false[-1] + 1)) if false.size else int(zv.size)


_NO_STANCES = Stances.empty()


def _empty_output() -> InsOutput:
    z = np.empty(0)
    return InsOutput(z, np.empty((0, 3)), np.empty(0, bool), z, np.empty(0, bool), _NO_STANCES)


def _concat(parts: list[InsOutput]) -> InsOutput:
    parts = [p for p in parts if len(p) or len(p.stances)]
    if not parts:
        return _empty_output()
    if len(parts) == 1:
        return parts[0]
    st = [p.stances for p in parts]
    stances = Stances(*(np.concatenate([getattr(x, k) for x in st]) for k in Stances.__dataclass_fields__))
    return InsOutput(*(np.concatenate([getattr(p, k) for p in parts])
                       for k in ("t", "position", "stationary", "threshold", "quiet")), stances)
