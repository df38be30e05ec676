"""Every setting of the PDR's heading (:class:`pdr.heading.HeadingEstimator`), each with its unit;
the equations they enter are in :mod:`pdr.heading`'s docstring."""
from __future__ import annotations

import dataclasses
import math

from pdr.grip import GripSettings


@dataclasses.dataclass(frozen=True)
class HeadingSettings:
    """Every number with its unit. Defaults: see the module's evaluation notes (IPIN 2023 set)."""

    # orientation basis
    ahrs: str = "decoupled"  # magnetometer-free AHRS used for levelling and gyro heading
    # its settings: shipped defaults, but no rest detection of its own (the bias is this module's)
    # and a tilt error beyond 30° levelled at once (no walker holds the 5.7 m/s² that tilts the
    # low-passed specific force so far; a lost attitude does: pdr.ahrs.decoupled, acc_relevel_angle)
    ahrs_params: tuple[tuple[str, float], ...] = (("rest_time", math.inf), ("acc_relevel_angle", math.radians(30.0)))
    forward_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)  # body axis taken as "forward"
    # body axis that points forward when the phone stands up (forward axis vertical): the back
    # of a phone whose screen faces the walker; (0, 0, 0): the forward axis alone
    upright_axis: tuple[float, float, float] = (0.0, 0.0, -1.0)
    upright_from: float = math.radians(65.0)  # rad, elevation of the forward axis where the upright axis starts to count
    declination: float = 0.0  # rad, east positive (Nuremberg 2023: +3.6° = 0.0628 rad)
    # gyro bias at standstill
    estimate_bias: bool = True
    still_window: float = 1.5  # s
    still_gyr_std: float = 0.005  # rad/s, per-axis standard deviation inside the window
    still_gyr_max: float = 0.02  # rad/s, norm of the window mean (a larger mean is motion, not bias)
    still_acc_std: float = 0.15  # m/s², std of the specific-force norm inside the window
    # compass and disturbance
    use_mag: bool = True
    epoch: float = 0.5  # s, compass epochs of the heading filter
    sigma_mag: float = math.radians(30.0)  # rad, per 0.5 s epoch; with sigma_rw: the compass is averaged over ~10 s
    spread_gate: float = math.radians(6.0)  # rad, reject epochs whose δ varies more
    field_norm: float = math.nan  # µT, expected |B|; NaN: learn from the first reference_seconds
    field_inclination: float = math.nan  # rad, expected dip (positive down); NaN: learn
    reference_seconds: float = 60.0  # s
    norm_gate: float = math.inf  # µT, reject when ||B| − field_norm| exceeds it (only with a given field_norm)
    inclination_gate: float = math.radians(15.0)  # rad, reject when |I − field_inclination| exceeds it (only when given)
    max_rate: float = 1.0  # rad/s, reject epochs whose mean |ω| exceeds it (phone waved: tilt, and so δ, unreliable)
    norm_weight: float = math.radians(1.0)  # rad per µT of norm deviation (k_n)
    inclination_weight: float = 0.5  # rad per rad of inclination deviation (k_I)
    # heading filter
    sigma_init: float = math.radians(30.0)  # rad, P0 around the first compass epoch
    sigma_rw: float = math.radians(2.5)  # rad/√s, random walk of δ (residual bias, grip changes)
    scale_error: float = 0.02  # fraction of each turn (gyro scale factor)
    gate_sigmas: float = 3.0  # innovation gate, in standard deviations
    gate_recover_s: float = 20.0  # s of consistently gated-out compass epochs after which δ is re-decided (inf: never)
    gate_recover_spread: float = math.radians(20.0)  # rad, their circular spread must stay below this
    # a run of compass epochs that agree with each other proves itself sooner across a gyro turn
    # (a field bent by steel moves with the phone when it turns; pdr.compass_streak)
    confirm_turn: float = math.radians(45.0)  # rad, of gyro heading spanned by the run
    confirm_min_s: float = 2.0  # s, the run lasts at least this long
    start_confirm_s: float = 4.0  # s, the first δ: a run this long without a turn also proves itself
    start_odd_confirm_s: float = 12.0  # s, a start run holding an epoch in an odd field (|B| hold_norm off) proves itself by time only after this
    # a walker standing (the specific force's norm varying less than stand_acc_std over an epoch)
    # reads the same place's field epoch after epoch: δ_m = δ + d + v, the place's disturbance d
    # held for the stand, v the epoch's own noise; a stand ends with a step, a gyro turn or a move
    # of the compass offset of stand_turn, or an epoch its prediction gates out (pdr.heading)
    stand_acc_std: float = 0.3  # m/s² (0: no stand is told apart, every epoch is new evidence)
    stand_turn: float = math.radians(20.0)  # rad
    stand_sigma: float = math.radians(5.0)  # rad, σ_v
    # hold: an epoch whose |B| is off the reference by more than hold_norm and whose offset lies
    # farther from δ than max(hold_angle, hold_sigmas · √P) waits in the rejected run
    hold_norm: float = 15.0  # µT (route 02 starts in a 24 µT field and walks on in 35-40 µT: 10 µT held its real compass)
    hold_angle: float = math.radians(35.0)  # rad
    hold_sigmas: float = 3.0
    # a jump: the compass offset moves by more than jump_angle within jump_window_s while the gyro
    # turns by at most jump_max_turn, to farther than max(jump_angle, hold_sigmas·√P) from δ, once
    # δ has been borne out across a turn (pdr.heading, _jump_held): held like an odd field's
    jump_window_s: float = 2.5  # s (0: no jump is held)
    jump_angle: float = math.radians(60.0)  # rad (at 35° an earlier form held route 02's own field swings: T02r04 DR +1.4 m)
    jump_max_turn: float = math.radians(20.0)  # rad (route 53's phone turns 150° in 2 s, its compass with it)
    gap_turn_rate: float = 1.0  # rad/s, δ's variance grows by (rate · gap)² over a gap in the samples
    # changes of grip (walking direction − device heading as a jump state; pdr.grip)
    grip: GripSettings = dataclasses.field(default_factory=GripSettings)
    # per-step outputs
    max_step_duration: float = 1.5  # s, a step never spans more than this
    sigma_arw: float = math.radians(0.5)  # rad/√s, gyro angle random walk
    sigma_bias: float = math.radians(0.1)  # rad/s, residual bias after standstill estimation
