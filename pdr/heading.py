"""Heading of travel per step: gyro about the vertical, tilt-compensated compass, and their fusion.

A hand-held phone gives two views of heading (seed 000 §2.4-2.5, seed 002 §2.4):

* the gyroscope, precise over seconds but drifting with its bias;
* the magnetometer, absolute but bent by steel and electrics indoors.

This module keeps them apart long enough to judge the compass, then fuses them. Per sample:

1. **Gyro bias at standstill.** Over a sliding window of ``still_window`` seconds the phone is
   *still* when every gyro axis varies less than ``still_gyr_std`` (rad/s), the mean rate is
   below ``still_gyr_max`` (rad/s) and the specific-force norm varies less than
   ``still_acc_std`` (m/s²). The window mean of the gyro is then the bias ``b``; it is used for
   every later sample (zero-velocity angular-rate update, seed 000 §2.5 "bias correction").
2. **Levelling.** A magnetometer-free AHRS (``make_filter(ahrs, gains, mag=None)``) integrates
   ``ω − b`` and corrects tilt with the accelerometer; its yaw is arbitrary but gyro-only, so
   the yaw of the device's forward axis ``f`` (default the phone's y axis, Android's azimuth
   axis), ``ψ_g = atan2((R f)_N, (R f)_E)``, is the integrated gyro heading (eq. 4.5 of seed 000,
   done in 3-D so a tilted phone is handled).
3. **Tilt-compensated compass** in the same levelled frame: ``m_n = R(q) m`` and the yaw of
   magnetic north in the gyro frame ``ψ_m = atan2(m_n,y, m_n,x)``. The offset that takes the
   gyro frame to ENU (true north) is

       δ = π/2 − D − ψ_m                                   (D: declination, east positive)

   because magnetic north lies at true bearing ``D``, i.e. at ENU yaw ``π/2 − D``.
   A gyro-only ``ψ_g`` plus ``δ`` is the compass heading of ``f``, without the sway of the
   hand (δ does not change when the phone turns; only when the field or the gyro are wrong).
   Field norm ``|m|`` and inclination ``I = atan2(−m_n,z, |m_n,xy|)`` are kept too.
4. **Disturbance.** Per epoch of ``epoch`` seconds the compass offset is the circular mean of δ,
   its spread ``s = √(−2 ln ρ)`` (ρ the mean resultant length) says whether the field was
   quasi-static along the path (Afzal, Renaudin, Lachapelle, "Magnetic field based heading
   estimation for pedestrian navigation environments", IPIN 2011: a uniform field rotates
   with the device exactly as the gyro says, so δ stays constant). The norm and inclination are
   compared with a reference (``field_norm``/``field_inclination`` in the settings, e.g. the
   WMM value, else the median over the first ``reference_seconds`` of the stream). The
   measurement standard deviation is

       σ_m² = σ_mag² + s² + (k_n Δ|m|)² + (k_I ΔI)²,

   and σ_m = ∞ (the epoch is rejected) when ``s`` passes ``spread_gate``, when the mean rate
   ``|ω|`` over the epoch passes ``max_rate`` (a waved phone: the levelling, and so δ, is poor
   while the hand accelerates and rotates fast; a hand-held phone in a walk turns at < 1 rad/s,
   while the calibration wave of the IPIN logs runs at 2-8 rad/s), or when ``Δ|m|`` / ``ΔI``
   pass their gates. The gates on ``Δ|m|`` and ``ΔI`` act only against a *configured*
   reference (``field_norm``/``field_inclination``, e.g. WMM for the incident site): a
   reference learned at the start is the field of wherever the walker stood — often disturbed
   — so it only weighs, never rejects.
5. **Fusion:** a scalar Kalman filter on δ (the gyro is the process, the compass the
   measurement; seed 000 §2.7, eqs. 5.3-5.8 with F = H = 1):

       predict   P ← P + σ_rw² Δt + (k_s Δψ_g)²          (bias random walk, scale-factor error)
       innovate  ν = wrap(δ_m − δ),  S = P + σ_m²
       gate      reject when ν² > n_σ² S
       update    K = P / S,  δ ← δ + K ν,  P ← (1 − K) P

   The filter starts (only the initial position is given, so the initial heading is the
   compass's) from a run of epochs that agree with each other for ``start_confirm_s`` or across
   a gyro turn (:mod:`pdr.compass_streak`), with ``P = σ_init²``; steps before take the run's mean
   with P = π². Steel held near the phone gives a δ_m that is steady while the walker goes
   straight but not across a turn. A run that holds an epoch in an odd field (``|B|`` more
   than ``hold_norm`` from the reference) proves itself by time only after
   ``start_odd_confirm_s`` (12 s; across a turn as any other): steel met at the start (4-15 s
   in the suite's ``mag_steel``) proved itself in 4 s and set δ far off, and the clean field
   after it, gated out, waited for ``P`` to grow past the error (``phone50_steel --seed 2``,
   T04r02: 120° off for 15 s, live p75 13.6 m; 3.5 m with the rule). It only delays: a
   reference learned in steel makes every later epoch odd (``mag_steel --seed 2``, T03r02), and
   an odd run must still be able to start δ. A first form that never started δ from an odd run
   left that walk without a compass start for its whole length (+0.9 m).

   Later, an offset far from δ in a field whose strength is off the reference is *held*
   (:func:`pdr.compass_streak.held`), for the filter and the step's compass.

   **A jump is held too** (:meth:`HeadingEstimator._jump_held`), whatever the field's strength:
   an offset δ_m that moves by more than ``jump_angle`` (60°) within ``jump_window_s`` (2.5 s)
   while the gyro turns by at most ``jump_max_turn`` (20°), to farther than
   ``max(jump_angle, hold_sigmas·√P)`` from δ. Between epochs without a gap the gyro saw every
   turn and cannot drift so far, so the change is the field's (steel met walking or standing,
   bending the field without changing its strength). It waits in the rejected run like a held
   epoch, and ends when the compass comes back near δ or the gyro turns by ``jump_max_turn``.
   Only a δ already borne out by compass epochs across a ``confirm_turn`` is defended so: a δ
   set by a start in steel must yield to the clean field's own jump back.

   **A stand is one piece of evidence.** The compass error is a property of the place: a
   walker standing (an epoch whose specific-force norm ‖f‖ varies by less than
   ``stand_acc_std``, 0.3 m/s²; walking gives 1-3) reads the same bent field epoch after epoch.
   So an epoch of a stand measures ``δ_m = δ + d + v``: ``d`` the place's disturbance, held for
   the stand, ``v`` the epoch's own noise (σ_v = ``stand_sigma``, 5°). ``d`` enters with the
   stand's first epoch, ``d ~ N(0, σ_m² − σ_v²)`` (so that epoch weighs as a walking one), and
   the filter carries ``[δ, d]`` with ``H = [1 1]``, ``R = σ_v²``: ``S = P + 2C + D + σ_v²``,
   ``K_δ = (P + C)/S``, ``K_d = (C + D)/S`` (C the covariance of δ and d, D the variance of d).
   The stand's further epochs follow δ's drift (the gyro's) but add no absolute evidence. A
   stand ends with a step, a gyro turn of ``stand_turn`` (20°; a field bent by the place
   changes with the heading), a compass offset ``stand_turn`` from the stand's first, or an
   epoch the stand's prediction ``δ + d`` gates out (the place's field changed: steel moved
   away); the next epoch begins afresh. Before, a 30 s stand beside steel took √P from 30° to
   7°, and the walk's clean field then needed some 20 s to pull δ back (T01r04 under the
   robustness suite's ``phone50_steel``); dead reckoning on the development walks gains most
   (docs/robustness.md, round 9).

   **The gate does not lock out.** Once δ is wrong by more than the gate (a gyro drift while
   the field was rejected, a device frame that moved), every later epoch would be gated out
   until ``P`` had grown past the error. So a streak of gated-out epochs that agree among
   themselves (circular spread of their δ_m below ``gate_recover_spread``) for
   ``gate_recover_s`` seconds, or across a turn of ``confirm_turn``, reopens the filter: δ restarts from the streak's circular mean,
   ``P ← max(P, σ_init²)``, and the epoch is gated again (raising ``P`` alone cannot accept an
   error beyond the gate, about 127°). A disturbed field does not agree with itself for that long while the walker
   moves; a wrong δ does.

   **A gap in the samples** (epochs with no sample: the sensor service paused) hides the turns
   made in it from the gyro: ``P ← P + (ω_gap · T_gap)²`` (``gap_turn_rate`` 1 rad/s, T_gap the
   time between the epochs less one epoch), so the compass after the gap sets the heading (a
   1.4 s gap at a corner of trial 04 rep 01 left the steps 71° off for three legs).

   ``σ_rw`` = 2.5°/√s with ``σ_mag`` = 30° per 0.5 s epoch make the steady-state gain about
   0.07 per epoch, i.e. the compass offset is averaged over roughly the last 10 s. That is
   short enough to forget a disturbed start and to follow the residual gyro drift (the
   standstill bias test never fires on a hand-held phone: the hand is never still to
   0.005 rad/s; δ drifted up to 0.2°/s in the IPIN logs), long enough to average the hand's
   sway and local disturbances out.

Evaluation (IPIN 2023 museum, 37 logs, pure PDR from the initial position, pooled p75 of the
landmark errors; declination 3.6°): former defaults (σ_mag 80°, σ_rw 0.3°/√s, no rate or
inclination gate) 6.37 m; with these defaults 5.41 m; with ``field_inclination`` = WMM 64.6°
(gate 15°) 5.11 m. The optimum is flat: σ_rw 1.5-4°/√s × σ_mag 15-40° all give 5.07-5.37 m,
inclination gate 10-20° gives 5.0-5.2 m, ``max_rate`` 0.5-1.5 rad/s 5.10-5.14 m; chosen on
trials 01-05 alone the grid optimum gives 3.99 m on trials 21-52 (their own best 3.70 m).

Per step ``k`` spanning ``(t_{k−1}, t_k]`` (at most ``max_step_duration`` long) the outputs are

* ``device_heading`` ψ̄_k: circular mean of ψ_g over the step plus δ̂ — averaging over the
  step removes the hand's sway;
* ``heading = device_heading + walking_offset``: the offset ω of the walking direction from
  the device's forward axis, a jump state that holds 0 (the texting grip) until the walk's
  acceleration pattern says the grip changed (:mod:`pdr.grip`), plus any offset the caller
  supplies; ``heading_sigma = √P``;
* ``heading_change = ψ̄_g,k − ψ̄_g,k−1`` with σ² = σ_arw² Δt + (σ_b Δt)² + (k_s Δψ)² (σ = ∞ on
  the step where ω jumps, the turn being the phone's, and across a sample gap > ``epoch``, unseen);
* ``mag_heading`` = ψ̄_g,k + circular mean of δ over the step (NaN when that step's field
  failed the gates) and its σ_m (∞ when disturbed) — for a fusion that wants to weigh the
  compass itself.

Streaming: the state is the AHRS, the bias, the samples of the last window and of the
unfinished epoch, the filter and the last step; epochs sit on a grid anchored at the first
sample, so any batching gives the same numbers as one batch. A step is answered once samples
up to its time have arrived (earlier steps wait in a queue).
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque

import numpy as np

from pdr.ahrs import make_filter
from pdr.angles import wrap  # noqa: F401  (re-exported)
from pdr.compass_streak import OffsetStreak, held
from pdr.compass_weight import measurement_sigma, odd_field
from pdr.grip import GripTracker
from pdr.heading_settings import HeadingSettings  # noqa: F401  (re-exported)
from pdr.fixed_order import mean0, row_dot
from pdr.heading_kernels import EPOCH_STATE, close_epochs, level_and_compass
from pdr.walking_direction import walking_angle
from pdr.window_kernels import still_bias
from pdr.windows import norm3, spans_gap, unwrap_turns

TWO_PI = 2.0 * math.pi
# per-sample columns kept for the steps: time, gyro heading, compass offset, |B|, dip, and the
# levelled specific force along the device's heading, to its left and up (the walking direction)
BUF_COLUMNS = ("t", "psi", "d", "norm", "inc", "af", "al", "az", "qw", "qx", "qy", "qz")  # q: levelling attitude


@dataclasses.dataclass(frozen=True)
class StepHeadings:
    """Per-step heading outputs (arrays of equal length, radians, ENU yaw CCW from East)."""

    t: np.ndarray  # s
    heading: np.ndarray
    heading_sigma: np.ndarray
    heading_change: np.ndarray
    heading_change_sigma: np.ndarray
    mag_heading: np.ndarray  # NaN where the compass looked disturbed
    mag_heading_sigma: np.ndarray  # inf where disturbed
    device_heading: np.ndarray  # fused heading of the forward axis, before the walking offset
    walking_offset: np.ndarray  # walking direction − device heading

    def __len__(self) -> int:
        return len(self.t)

    @staticmethod
    def concatenate(parts: list[StepHeadings]) -> StepHeadings:
        fields = [f.name for f in dataclasses.fields(StepHeadings)]
        if not parts:
            return StepHeadings(*[np.empty(0) for _ in fields])
        return StepHeadings(*[np.concatenate([getattr(p, n) for p in parts]) for n in fields])


class HeadingEstimator:
    """Streaming heading of travel: ``update(t, acc, gyr, mag, step_times) -> StepHeadings``.

    ``t`` (N,) s, ``acc`` (N, 3) m/s², ``gyr`` (N, 3) rad/s on the same clock, ``mag`` (N, 3) µT
    or None; ``step_times`` the times of steps detected so far (any that lie beyond the last
    sample wait for later batches). ``walking_offset`` optionally gives, per step, the angle
    from the device's forward axis to the walking direction (rad, CCW), e.g. from
    :class:`pdr.walking_direction.WalkingDirection`.

    After each update ``samples`` holds per-sample diagnostics of the batch (gyro heading,
    compass offset, norm, inclination, stillness, bias) for plots and tests.
    """

    _start_odd = False  # the start run holds an epoch in an odd field (a snapshot from before it: none)

    # class defaults: an estimator restored from a snapshot taken before jumps were held
    _jumped, _jump_psi = False, math.nan
    _tested = (math.inf, -math.inf)  # range of ψ_g over which compass epochs bore δ out since it (re)started
    # a stand (:meth:`_innovation`, :meth:`_update`): its disturbance d, d's variance D and its covariance C with δ;
    # ψ_g where it began (NaN: the walker is not standing, or δ restarted since)
    _stand_d, _stand_D, _stand_C, _stand_psi, _stand_dm = 0.0, 0.0, 0.0, math.nan, 0.0

    @property
    def _recent(self) -> deque:
        """The compass epochs (t_end, ψ_g, δ_m) of the last ``jump_window_s`` (:meth:`_jump_held`)."""
        if "_recent_epochs" not in self.__dict__:  # an estimator restored from an older snapshot
            self._recent_epochs = deque()
        return self._recent_epochs

    def __init__(self, settings: HeadingSettings | None = None):
        self.settings = s = settings or HeadingSettings()
        self._ahrs = make_filter(s.ahrs, dict(s.ahrs_params))
        up = np.asarray(s.upright_axis, float)
        self._fwd = np.concatenate([np.asarray(s.forward_axis, float) / np.linalg.norm(s.forward_axis),
                                    up / max(float(np.linalg.norm(up)), 1e-300), [math.sin(s.upright_from) ** 2]])
        self.bias = np.zeros(3)  # rad/s, current gyro bias estimate
        self._t0: float | None = None
        self._tail = {"t": np.empty(0), "g": np.empty((0, 3)), "a": np.empty(0)}
        self._raw_last: float | None = None  # last gyro heading, wrapped
        self._turns = 0  # whole turns of the gyro heading at that sample
        self._epoch_state = np.zeros(EPOCH_STATE)  # the open compass epoch (see close_epochs)
        self._ref_norm = s.field_norm
        self._ref_inc = s.field_inclination
        self._ref_buf: list[np.ndarray] = []
        self._delta: float | None = None  # KF state: gyro frame -> ENU yaw offset
        self._P = s.sigma_init**2
        self._kf_t = -math.inf  # end time of the last epoch the filter has seen
        self._kf_psi: float | None = None  # gyro heading at that epoch end
        self._hist = deque([(-math.inf, math.nan, math.inf)])  # (epoch end, δ, P) for step lookups
        self._jumped, self._jump_psi = False, math.nan  # the compass jumped away from δ (at this ψ_g) and has not come back
        self._recent_epochs: deque = deque()  # (t_end, ψ_g, δ_m) of the last jump_window_s
        # runs of compass epochs that agree with each other (pdr.compass_streak): the epochs the
        # filter turned away, and before the first δ the epochs that would set it
        self._rejected = OffsetStreak(s.gate_recover_spread, s.confirm_turn, s.confirm_min_s, s.gate_recover_s)
        self._start_run = OffsetStreak(s.gate_recover_spread, s.confirm_turn, s.confirm_min_s, s.start_confirm_s)
        self.grip = GripTracker(s.grip)
        self._pending: list[float] = []
        self._pending_off: list[float] = []
        self._buf = np.empty((0, len(BUF_COLUMNS)))  # samples for step means and the walking direction
        self._prev_step: tuple[float, float] | None = None  # (t, mean gyro heading)
        self._index = 0
        self.samples: dict[str, np.ndarray] = {}

    # ---------------------------------------------------------------- samples
    def update(self, t, acc, gyr, mag=None, step_times=(), walking_offset=None, acc_norm=None) -> StepHeadings:
        """``acc_norm`` (N,) optionally passes ‖acc‖ when the caller has it already."""
        s = self.settings
        t = np.asarray(t, float).reshape(-1)
        if len(t) == 0:
            return self.steps(step_times, walking_offset)
        acc = np.asarray(acc, float).reshape(-1, 3)
        gyr = np.asarray(gyr, float).reshape(-1, 3)
        use_mag = s.use_mag and mag is not None
        self._queue_steps(step_times, walking_offset)
        self.start(t[0])
        self.prune_history(t[0])
        an = norm3(acc) if acc_norm is None else acc_norm
        bias = self._bias_per_sample(t, an, gyr) if s.estimate_bias else np.tile(self.bias, (len(t), 1))
        q = self._ahrs.update(t, acc, gyr - bias)
        mag = np.ascontiguousarray(mag, float).reshape(-1, 3) if use_mag else np.empty((0, 3))
        raw, d, norm, inc, af, al, az = level_and_compass(np.ascontiguousarray(q), self._fwd, np.ascontiguousarray(acc),
                                                          mag, use_mag, s.declination)
        turns, self._turns = unwrap_turns(raw, self._raw_last, self._turns)
        self._raw_last = float(raw[-1])
        psi = raw + TWO_PI * turns
        self.samples = {"t": t, "psi_gyro": psi, "delta_mag": d, "norm": norm, "inclination": inc, "bias": bias, "q": q}
        if self._epoch_state.size < EPOCH_STATE:  # restored from a snapshot before the epochs summed ‖f‖
            self._epoch_state = np.concatenate([self._epoch_state, np.zeros(EPOCH_STATE - self._epoch_state.size)])
        self.take_epochs(close_epochs(t, psi, d, norm, inc, norm3(gyr - bias), an, self._t0, s.epoch, self._epoch_state))
        # older samples leave before the new ones come in: steps found in this batch later (or
        # held back by the detector, a few steps before it) still find their samples
        keep = self._buf[:, 0] > (t[0] - 4 * s.max_step_duration)
        self._buf = np.concatenate([self._buf[keep], np.column_stack((t, psi, d, norm, inc, af, al, az, q))])
        return self.answer_steps(self._buf)

    # ---------------------------------------------------------------- what a columnar engine calls
    @property
    def ahrs(self):
        """The levelling filter (its kernel state seeds a columnar engine's row)."""
        return self._ahrs

    @property
    def forward_axes(self) -> np.ndarray:
        """Forward axis, upright axis, sin²(upright_from): :func:`pdr.heading_kernels.level_and_compass`'s ``fwd``."""
        return self._fwd

    def start(self, t0: float) -> None:
        """The stream's first sample is at ``t0`` (s): epochs and the field reference count from it."""
        if self._t0 is None:
            self._t0 = float(t0)

    def prune_history(self, t_first: float) -> None:
        """Filter history no step can ask for once samples start at ``t_first`` leaves (one before stays)."""
        s = self.settings
        limit = t_first - 4 * s.max_step_duration - s.epoch
        while len(self._hist) > 1 and self._hist[1][0] < limit:
            self._hist.popleft()

    def _bias_per_sample(self, t, acc_norm, gyr) -> np.ndarray:
        """Bias used for each sample: the gyro mean of the latest still window ending before it."""
        s = self.settings
        T = np.concatenate([self._tail["t"], t])
        G = np.vstack([self._tail["g"], gyr])
        A = np.concatenate([self._tail["a"], acc_norm])
        m = len(self._tail["t"])
        bias, still, self.bias = still_bias(T, np.column_stack((G, A)), m, s.still_window, s.still_gyr_std,
                                            s.still_gyr_max, s.still_acc_std, np.asarray(self.bias, float))
        keep = T > T[-1] - s.still_window - 1e-9
        self._tail = {"t": T[keep], "g": G[keep], "a": A[keep]}
        self.samples_still = still
        return bias

    # ---------------------------------------------------------------- compass epochs + filter
    def take_epochs(self, rows: np.ndarray) -> None:
        """Closed compass epochs (rows of :func:`pdr.heading_kernels.close_epochs`) into the
        reference, the measurement sigma and the filter (also the columnar engine's path,
        :mod:`pdr.fleet`)."""
        s = self.settings
        if not len(rows):
            return
        t_end, psi_end, cs, sn, nrm, inc_m, rate, acc_std = rows.T
        dm = np.arctan2(sn, cs)
        rho = np.clip(np.hypot(cs, sn), 1e-12, 1.0)
        spread = np.sqrt(-2.0 * np.log(rho))
        # a few epochs per second: the rest in Python floats (a scalar filter loop, each epoch's weight)
        epochs = list(zip(*(c.tolist() for c in (t_end, psi_end, dm, spread, nrm, inc_m, rate))))
        self._learn_reference(epochs)
        for (t, psi, d, sp, f, inc, w), a in zip(epochs, acc_std.tolist()):
            sig = math.inf if w > s.max_rate else self._measurement_sigma(sp, f, inc, t)
            self._kf_step(t, psi, d, sig, self._odd_field(f, t), a < s.stand_acc_std)

    def _learned_by(self) -> float:
        """From when a learned field reference counts (:mod:`pdr.compass_weight`)."""
        return -math.inf if self._t0 is None else self._t0 + self.settings.reference_seconds

    def _odd_field(self, nrm: float, t: float) -> bool:
        """Only an epoch or step in an odd field can be held (:meth:`_accepts`; :func:`pdr.compass_weight.odd_field`)."""
        return odd_field(self.settings, nrm, t, self._ref_norm, self._learned_by())

    def _learn_reference(self, epochs: list[tuple]) -> None:
        """The field reference from epochs (t_end, ψ, δ_m, spread, |B|, I, |ω|) within its window
        that passed the spread gate (an epoch over ``max_rate`` has none)."""
        s = self.settings
        if math.isfinite(self._ref_norm) and math.isfinite(self._ref_inc):
            return
        if self._t0 is None or not any(math.isfinite(e[4]) for e in epochs):
            return
        end = self._t0 + s.reference_seconds
        ok = [(f, inc) for t, _, _, sp, f, inc, w in epochs
              if t <= end and not w > s.max_rate and sp < s.spread_gate and math.isfinite(f)]
        if ok:
            self._ref_buf.append(np.array(ok, float))
        if not all(e[0] <= end for e in epochs):  # the reference window is over: fix the medians
            ref = np.vstack(self._ref_buf) if self._ref_buf else np.empty((0, 2))
            if len(ref):
                if not np.isfinite(self._ref_norm):
                    self._ref_norm = float(np.median(ref[:, 0]))
                if not np.isfinite(self._ref_inc):
                    self._ref_inc = float(np.median(ref[:, 1]))
            else:
                self._ref_norm = self._ref_norm if np.isfinite(self._ref_norm) else math.inf
                self._ref_inc = self._ref_inc if np.isfinite(self._ref_inc) else math.inf

    @property
    def field_reference(self) -> tuple[float, float]:
        """(|B| µT, inclination rad) the disturbance test compares with (NaN while learning)."""
        return self._ref_norm, self._ref_inc

    def _measurement_sigma(self, spread: float, nrm: float, inc_m: float, t: float) -> float:
        """σ_m of an epoch (or step) ending at ``t`` (:func:`pdr.compass_weight.measurement_sigma`)."""
        return measurement_sigma(self.settings, spread, nrm, inc_m, t, self._ref_norm, self._ref_inc,
                                 self._learned_by())

    def _kf_step(self, t_end, psi_end, dm, sig, odd: bool = False, standing: bool = False) -> None:
        s = self.settings
        if self._delta is None:
            # initial heading: a run of epochs that pass the gates and agree with each other, tested
            # by a turn or by time (pdr.compass_streak); until then the steps take the run's mean
            # with P = π² (no absolute evidence: steel at the first landmark must not set δ)
            if np.isfinite(sig) and self._start_proved(t_end, dm, psi_end, odd):
                self._delta = self._start_run.mean
                self._P = s.sigma_init**2
                self._tested = (self._start_run.psi_lo, self._start_run.psi_hi)
                self._start_run.clear()
                self._stand_psi = math.nan
                if standing:  # δ is this place's field: δ + d is known, d is not (C = −D)
                    self._begin_stand(psi_end, dm, self._P - s.stand_sigma**2)
                    self._stand_C = -self._stand_D
        else:
            dt = t_end - self._kf_t
            dpsi = psi_end - self._kf_psi
            self._P += s.sigma_rw**2 * dt + (s.scale_error * dpsi) ** 2
            if dt > 1.5 * s.epoch:  # epochs without a sample between: a gap the gyro did not see
                self._P += (s.gap_turn_rate * (dt - s.epoch)) ** 2
            odd_field, odd = odd, self._jump_held(t_end, psi_end, dm) or odd
            if not (standing and s.stand_acc_std > 0 and abs(psi_end - self._stand_psi) <= s.stand_turn
                    and not abs(float(wrap(dm - self._stand_dm))) > s.stand_turn):
                self._stand_psi = math.nan  # walking, turned, a field that moved, or no stand told apart: a new place
            if np.isfinite(sig):
                if standing and s.stand_acc_std > 0 and (math.isnan(self._stand_psi)
                                                         or not self._accepts(*self._innovation(dm, sig), odd)):
                    self._begin_stand(psi_end, dm, sig**2 - s.stand_sigma**2)  # a new stand, or the place's field changed
                nu, sig_e = self._innovation(dm, sig)
                if self._gate(t_end, psi_end, dm, self._accepts(nu, sig_e, odd)):
                    self._stand_psi = math.nan
                    nu, sig_e = self._innovation(dm, sig)
                if self._accepts(nu, sig_e, odd):
                    if not odd_field:  # only a field of the usual strength bears δ out (the jump rule's test)
                        self._tested = (min(self._tested[0], psi_end), max(self._tested[1], psi_end))
                    self._update(nu, sig_e)
        self._kf_t, self._kf_psi = t_end, psi_end
        if self._delta is None:
            self._hist.append((t_end, self._start_run.mean, math.pi**2))
        else:
            self._hist.append((t_end, self._delta, self._P, self._jumped))

    def _start_proved(self, t_end: float, dm: float, psi_end: float, odd: bool) -> bool:
        """Adds the epoch to the start run; has the run proved itself? A run that holds an epoch
        in an odd field (steel met at the start, or a reference learned in it) proves itself by
        time only after ``start_odd_confirm_s``, by a turn as any other."""
        run = self._start_run
        proved = run.add(t_end, dm, psi_end)
        self._start_odd = odd if run.n == 1 else (self._start_odd or odd)  # n == 1: the run began again here
        if not proved or not self._start_odd:
            return proved
        return run.proved(t_end, self.settings.start_odd_confirm_s)

    def _begin_stand(self, psi: float, dm: float, D: float) -> None:
        """A stand begins at gyro heading ``psi`` with compass offset ``dm``: its disturbance
        d = 0 ± √D, uncorrelated with δ."""
        self._stand_psi, self._stand_dm, self._stand_d, self._stand_D, self._stand_C = psi, dm, 0.0, max(D, 0.0), 0.0

    def _innovation(self, dm: float, sig: float) -> tuple[float, float]:
        """(ν, σ) of the epoch: ν = wrap(δ_m − δ) and σ = σ_m while walking; in a stand the
        epoch measures δ + d with the epoch's own noise σ_v (``stand_sigma``), so ν = wrap(δ_m −
        δ − d) and σ² = D + 2C + σ_v² (S = P + σ² as for a walking epoch)."""
        if math.isnan(self._stand_psi):
            return float(wrap(dm - self._delta)), sig
        var = self._stand_D + 2.0 * self._stand_C + self.settings.stand_sigma**2
        return float(wrap(dm - self._delta - self._stand_d)), math.sqrt(max(var, 1e-12))

    def _update(self, nu: float, sig: float) -> None:
        """The Kalman update of δ (and, in a stand, of d: H = [1 1], R = σ_v²; seed 000 eqs. 5.6-5.8)."""
        S = self._P + sig**2
        if math.isnan(self._stand_psi):
            K = self._P / S
            self._delta = float(wrap(self._delta + K * nu))
            self._P *= 1.0 - K
            return
        P, C, D = self._P, self._stand_C, self._stand_D
        k_delta, k_d = (P + C) / S, (C + D) / S
        self._delta = float(wrap(self._delta + k_delta * nu))
        self._stand_d = float(wrap(self._stand_d + k_d * nu))
        self._P, self._stand_C, self._stand_D = P - k_delta * (P + C), C - k_delta * (C + D), D - k_d * (C + D)

    def _jump_held(self, t_end: float, psi_end: float, dm: float) -> bool:
        """Is the compass offset ``dm`` of the epoch ending at ``t_end`` part of a *jump*? A jump
        begins when ``dm`` differs by more than ``jump_angle`` from the offset of an epoch less
        than ``jump_window_s`` before, while the gyro heading ``psi_end`` turned by at most
        ``jump_max_turn`` since that epoch, and lies farther than ``max(jump_angle,
        hold_sigmas·√P)`` from δ. The gyro cannot drift so fast and saw every turn, so such a
        change is the field's: steel met walking or standing (seen in ``mag_steel --seed 1``:
        after a stand had grown P, a 40 µT offset that left the field's strength as it was was
        taken at 72° from δ and turned the walk 86°). The jump is held like an epoch in an odd
        field (:func:`pdr.compass_streak.held`), so it waits in the rejected run until that run
        proves itself (a turn, or ``gate_recover_s``). It ends when the compass comes back within
        that distance of δ, or once the gyro has turned by ``jump_max_turn`` since it began (a
        field seen across a turn is no longer the one that jumped)."""
        s = self.settings
        if not math.isfinite(dm) or self._delta is None:
            return self._jumped
        recent = self._recent
        while recent and recent[0][0] < t_end - s.jump_window_s:
            recent.popleft()
        if self._tested[1] - self._tested[0] < s.confirm_turn:  # δ not yet borne out across a turn: it may be the jump
            self._jumped = False
        elif abs(float(wrap(dm - self._delta))) <= max(s.jump_angle, s.hold_sigmas * math.sqrt(self._P)):
            self._jumped = False
        elif self._jumped:
            self._jumped = abs(psi_end - self._jump_psi) <= s.jump_max_turn
        else:
            self._jumped = any(abs(psi_end - p) <= s.jump_max_turn and abs(float(wrap(dm - d))) > s.jump_angle
                               for _, p, d in recent)
            self._jump_psi = psi_end
        recent.append((t_end, psi_end, dm))
        return self._jumped

    def _accepts(self, nu: float, sig: float, odd: bool = False) -> bool:
        """The innovation gate ``ν² ≤ n_σ² (P + σ_m²)``, unless :func:`pdr.compass_streak.held`."""
        s = self.settings
        return not held(nu, self._P, odd, s) and nu * nu <= s.gate_sigmas**2 * (self._P + sig**2)

    def _gate(self, t_end, psi_end, dm, passes: bool) -> bool:
        """The gate must not lock the compass out for good: a run of turned-away epochs that agree
        with each other (circular spread below ``gate_recover_spread``) across a gyro turn of
        ``confirm_turn`` (over at least ``confirm_min_s``) or for ``gate_recover_s`` seconds means
        δ itself is wrong (a gyro drift while the field was rejected, a frame that moved): δ
        restarts from the run's circular mean, ``P = max(P, σ_init²)``, and the caller gates the
        epoch again (raising ``P`` alone cannot accept an error beyond the gate, 127°). Returns
        whether δ restarted."""
        s = self.settings
        r = self._rejected
        if passes:
            r.clear()
            return False
        if r.add(t_end, dm, psi_end):
            self._delta = r.mean
            self._tested = (r.psi_lo, r.psi_hi)
            self._P = max(self._P, s.sigma_init**2)
            r.clear()
            return True
        return False

    def _grip_step(self, t, f, l, z, tk: float, q, before=None) -> tuple[float, bool]:
        """The walking offset ω after the step at ``tk`` whose window holds samples ``t``, ``f``,
        ``l``, ``z``; ``q`` the step's mean attitude, ``before`` the attitudes and vertical
        specific force of the window's samples before the step's own (:mod:`pdr.grip`)."""
        g = self.settings.grip
        if not g.enabled or len(t) < 3:
            return self.grip.offset, False
        return self.grip.step(walking_angle(t, f, l, z, g.lag), tk, q, self.device_yaw, before)

    def device_yaw(self, q) -> np.ndarray:
        """Yaw (rad) of the device's heading vector for attitudes ``q`` (n, 4), as the steps get it."""
        return level_and_compass(np.ascontiguousarray(q, float), self._fwd, np.zeros((len(q), 3)), np.empty((0, 3)),
                                 False, 0.0)[0]

    # ---------------------------------------------------------------- steps
    def steps(self, step_times, walking_offset=None) -> StepHeadings:
        """Headings of steps at ``step_times`` found in samples already given (no new samples)."""
        return self.answer_steps(self._buf, step_times, walking_offset)

    def _queue_steps(self, step_times, walking_offset) -> None:
        if len(step_times) == 0:
            return
        offs = np.zeros(len(step_times)) if walking_offset is None else np.asarray(walking_offset, float)
        self._pending += [float(x) for x in np.asarray(step_times, float).reshape(-1)]
        self._pending_off += [float(x) for x in offs.reshape(-1)]

    def answer_steps(self, buf: np.ndarray, step_times=(), walking_offset=None) -> StepHeadings:
        """Headings of the steps queued so far and at ``step_times`` whose samples have arrived in
        ``buf``: rows of :data:`BUF_COLUMNS` in time order (this estimator's, or a columnar
        engine's, which runs the per-sample part itself)."""
        self._queue_steps(step_times, walking_offset)
        s = self.settings
        if not len(buf) or not self._pending:
            return StepHeadings.concatenate([])
        bt = buf[:, 0]
        order = np.argsort(self._pending, kind="stable")
        ts = np.asarray(self._pending)[order]
        offs = np.asarray(self._pending_off)[order]
        ready = ts <= bt[-1]
        self._pending = list(ts[~ready])
        self._pending_off = list(offs[~ready])
        hist = self._hist
        hist_t = [e[0] for e in hist]
        rows = []
        for tk, off in zip(ts[ready].tolist(), offs[ready].tolist()):
            t_prev = self._prev_step[0] if self._prev_step else -math.inf
            lo = max(t_prev, tk - s.max_step_duration)
            i0 = int(np.searchsorted(bt, lo, side="right"))
            i1 = int(np.searchsorted(bt, tk, side="right"))
            if i1 <= i0:  # no sample in the step: the last one at or before it (after a gap: the oldest)
                i0, i1 = (i1 - 1, i1) if i1 > 0 else (0, 1)
            psi_g = float(mean0(buf[i0:i1, 1]))  # unwrapped: the arithmetic mean is circular
            w0 = int(np.searchsorted(bt, tk - s.grip.window, side="right"))  # samples in (tk − window, tk]
            qs = buf[i0:i1, 8:12]
            qm = mean0(qs * np.sign(row_dot(qs, qs[-1]))[:, None])  # the step's mean attitude (one hemisphere)
            before = (buf[w0:i0, 8:12], buf[w0:i0, 7]) if self.grip.wants_standing else None
            omega, jumped = self._grip_step(buf[w0:i1, 0], buf[w0:i1, 5], buf[w0:i1, 6], buf[w0:i1, 7], tk,
                                            qm / math.sqrt(float(row_dot(qm, qm))), before)
            off = off + omega
            k = bisect.bisect_right(hist_t, tk) - 1
            _, delta, P, *jump = hist[max(k, 0)]
            if not math.isfinite(delta):  # before the first compass epoch
                delta = float(buf[i1 - 1, 2]) if math.isfinite(buf[i1 - 1, 2]) else 0.0
                P = math.pi**2
            elapsed = tk - hist[max(k, 0)][0]
            P = P + s.sigma_rw**2 * elapsed if math.isfinite(P) and math.isfinite(elapsed) else P
            dev = float(wrap(psi_g + delta))
            # compass heading of this step on its own
            dd = buf[i0:i1, 2]
            okd = np.isfinite(dd)
            if np.count_nonzero(okd) >= 2:
                ddo = dd[okd]
                c, sn = float(mean0(np.cos(ddo))), float(mean0(np.sin(ddo)))
                spread = math.sqrt(-2.0 * math.log(min(max(math.hypot(c, sn), 1e-12), 1.0)))
                nrm_k = float(mean0(buf[i0:i1, 3][okd]))
                sig_m = self._measurement_sigma(spread, nrm_k, float(mean0(buf[i0:i1, 4][okd])), tk)
                if held(float(wrap(math.atan2(sn, c) - delta)), P, self._odd_field(nrm_k, tk) or bool(jump and jump[0]), s):
                    sig_m = math.inf  # the filter would hold this compass (_accepts): so must the fusion
                magh = float(wrap(psi_g + math.atan2(sn, c) + off)) if math.isfinite(sig_m) else math.nan
            else:
                sig_m, magh = math.inf, math.nan
            if self._prev_step is None:
                dch, dsig = 0.0, math.inf
            else:
                dt = tk - self._prev_step[0]
                dch = psi_g - self._prev_step[1]
                unknown = jumped or spans_gap(bt, self._prev_step[0], tk, s.epoch)  # a grip's turn; one unseen in a gap
                dsig = math.inf if unknown else math.sqrt(s.sigma_arw**2 * dt + (s.sigma_bias * dt) ** 2 + (s.scale_error * dch) ** 2)
            self._prev_step = (tk, psi_g)
            rows.append((tk, float(wrap(dev + off)), math.sqrt(P), float(wrap(dch)), dsig, magh, sig_m, dev, off))
        if not rows:
            return StepHeadings.concatenate([])
        a = np.array(rows, float)
        return StepHeadings(*[a[:, i] for i in range(a.shape[1])])
