"""The numbers of the factor-graph fusion, each named with its unit, and why the defaults.

* ``lag_s = 60``: the window must outlive the spacing of fixes, or a pose freezes before the
  next fix can straighten it (``firetrack bench fusion``, a checkpoint every ≈53 s: smoothed
  RMSE 0.77 m at a 15 s lag, 0.59 m at 60 s), and it bounds how late a fix may arrive. The
  cost grows slowly with it (median step 0.07 ms at 15 s, 0.11 ms at 60 s, 0.23 ms at 300 s;
  ≈115 variables at 60 s and 1.9 steps/s).
* Relinearisation per variable type: a position enters the step, checkpoint and GNSS factors
  linearly, so 0.1 m; a heading is a lever on everything after it, so 0.01 rad. Same accuracy
  on the benchmark as 0.01 everywhere, at half the cost per step.
* ``fix_extra_updates``/``fix_convergence_m``: iSAM2 takes one Gauss-Newton step per update; a
  20° heading error corrected by a checkpoint 60 m on leaves ≈2 m after one step, < 1 cm after
  four (tests/test_fusion.py::test_large_correction_converges_within_the_fix).
* Compass on, Cauchy kernel: tests/test_fusion.py (drift bounded; an undetected 50° stretch
  costs ≈3 m instead of ≈18 m with Huber; the heading still recovers after a 45° drift).
* GNSS and UWB: Huber (convex: what passes the gates may pull, boundedly) — gross GNSS
  errors are the χ² gate's job; the UWB gate is off by default because a drifted PDR with an
  optimistic covariance would otherwise refuse the very ranges that should correct it.
* Step noise floors: a PDR that reports a zero sigma must not make the graph rigid.
* Step-length scale (service/fusion/scaled_step.py): prior σ 0.08 around 1 (a step model
  fitted to others is typically 5-10 % off for one person), random walk 0.003/√s (≈3 % per
  two minutes), a new variable every 120 s. IPIN 2023 (37 logs, landmark fix every 3rd):
  live p75 without GNSS 2.22 → 2.07 m, with GNSS 2.08 → ≈2.07 m; flat over σ 0.06-0.12 and
  the same optimum on trials 01-05 and on 21-24+52. Price: GNSS indoors can now stretch the
  track too (initial fix only, GNSS on: 4.29 → 5.03 m, still below dead reckoning's 6.37),
  and the step is a Python CustomFactor (bench median ≈0.6 ms per step instead of 0.1 ms:
  every relinearisation calls Python, and the scale ties the window's poses together).
  ``length_scale_sigma=None`` (now the default, see below) gives the plain BetweenFactorPose2 steps.

Issue 12 (magnetic disturbance and indoor GNSS as the normal case, 40 IPIN walks, figures of
``firetrack eval ipin ... [--fix-every 3]``; the last three are cross-validated, see
:mod:`service.ipin_cv`):

* **GNSS below ground is not evidence** (``gnss_lowest_floor = 0``: floors numbered up from the
  entrance floor 0, basements negative). The phones' basement fixes claimed 8-20 m and were
  10-17 m off (median at the landmarks); on floor 0 they were ≈4 m off. The rule is physics (no
  sky), not a fit. With it, the basement routes stop zig-zagging towards the fixes: K = 0 live p75
  4.91 → 4.48 m on all walks, with no change on floor 0.
* ``gnss_max_accuracy_m = 15``: a phone's stated accuracy beyond that is a network or multipath
  position (no effect on these walks once the floor rule holds; it is the guard for a ground floor
  deep inside a building).
* ``gnss_min_interval_s = 5``: successive indoor fixes share one slowly wandering multipath error,
  so one factor per 5 s (also one fifth of the cost): K = 0 4.48 → 4.18 m; 2 s gives 4.24 m
  (chosen in sample).
* ``mag_window_gate_rad = 15°`` over ``mag_window_s = 5``: the compass must turn with the gyro.
  The offset between compass heading and gyro chain is constant in a uniform field; walking
  through a disturbance bends the field from metre to metre, which the PDR's 0.5 s epochs cannot
  see. 15° is about the 95th percentile of that window spread on the IPIN walks (median 5°).
  Neutral on the IPIN figures (a biased but uniform field passes it, as it must); it is there for
  gradients (tests/test_fusion.py).
* ``stairs_turn_sigma_rad = 10°``: on stairs the phone pitches and the yaw of its forward axis is
  poorly defined (the spiral stair of trials 52/53 gave single-step "turns" of 70-95°); a loose
  turn there lets the compass put the heading right afterwards. K = 3: route 52 7.0 → 3.6 m.
* ``turn_walk = 0``: a random walk on every turn (1°/√s) helped the spiral stair too, but it
  weakens the gyro against a compass that is wrong for a long stretch
  (tests/test_fusion.py::test_robust_compass_kernel_limits_an_undetected_disturbance fails),
  which is what the issue is about; the stair rule does the same job where it is needed.
* ``display_gain = 0.5``: the published pose closes half of the gap to the graph's estimate per
  step (service/fusion/published.py), so a GNSS factor shifts the marker over a few
  steps instead of at once; checkpoints and UWB still move it at once. Accuracy-neutral (K = 0
  4.01 → 4.06 m, K = 3 2.03 → 2.04 m); the published path is 5 % shorter.

Issue 12, second round ("a correction must never make a track worse than no correction"; figures
of ``firetrack eval ipin --cv`` on the 40 walks, pooled leave-one-route-out live p75 and the
number of walks whose live p75 is more than 0.5 m above their dead reckoning's; main before
this round: K = 0 4.05 m and 12/40, K = 3 2.03 m and 3/40):

* **The PDR's fused heading with a wandering offset** (``pdr_heading_interval_s = 2``,
  ``pdr_heading_time_s = 60``, ``pdr_heading_white_rad = 3°``; σ_c = ``pdr_heading_sigma_rad``
  is in the CV grid, 10° or 15°): service/fusion/heading_evidence.py. A heading that is steadily
  off for a corridor goes into the offset, not into the track; the price is that the offset can
  follow a slow gyro drift too (tests/test_fusion.py), which the compass factors bound.
* ``stop_turn_sigma_rad = 20°`` after a stop of ``stop_turn_s = 3`` s: a phone is re-gripped
  while its holder stands; the turn across the stop is not the gyro's alone.
* ``fix_interpolate``: a fix inside a step constrains the point walked at its time
  (service/fusion/fix_timing.py, ``step_motion_s = 0.7`` s per step) instead of dragging the
  nearer pose.
* ``gnss_min_interval_s`` is in the CV grid (5 or 10 s; the default 10 s).
* ``length_scale_sigma = None``: with the heading evidence above, estimating the step-length
  scale from indoor GNSS stretched tracks: in sample, K = 0 live p75 3.63 m with σ 0.08 against
  3.54 m without, and 4 walks instead of 2 more than 0.5 m above dead reckoning (K = 3 1.922 vs
  1.921 m); a step-length bias is better met by a fix every few landmarks than by GNSS.

Issue 27 (robustness suite, ``gaps`` and ``mag_steel``; docs/robustness.md, round 4):

* ``pdr_heading_max_sigma_rad = 90°``: a PDR heading whose own sigma is larger (180° until a
  compass epoch has passed the PDR's gates) gives no factor; before, a first leg 140° off held
  the graph's heading and, through it, the walk gate's reference (mag_steel T04r03 live 18.1 m
  against 9.6 m dead reckoning). A step with an unknown turn restarts the compass gate's window
  and the PDR heading's offset (service/fusion/heading_evidence.py). Cross-validated live p75:
  K = 0 3.694 → 3.646 m, K = 3 1.876 → 1.866 m; suite ``gaps`` 4.46 → 4.13 m (now passes).

* ``pdr_heading_jump_rad = 90°`` (round 7): when the PDR's absolute heading jumps by more than
  this beyond the gyro's turn (its compass offset restarted on a run that proved itself) and the
  graph's heading is as far from it, and no precise fix besides the start has been taken, the
  graph restarts on the PDR's heading (``FusionEstimator._pdr_heading_jumped``; not counted as
  degraded). A graph started on a wrong PDR heading cannot turn by itself: the evidence that
  would turn it is all far off and robustly ignored. T21r02 under the suite's ``phone50_steel``
  draw (a 166° jump): live p75 22.0 → 3.1 m (dead reckoning 3.0 m). At 45° four jumps of 63-86°
  on T53r02 restart it too: K = 0 live 4.48 → 3.33 m but K = 3 2.86 → 2.91 m, and the
  cross-validation's per-fold choice of the GNSS spacing flipped on five routes (K = 3 held out
  1.857 → 1.906 m, over the 1.9 m rail); at 90° no development walk restarts.

Issue 32 ("the estimator cannot crash and cannot hide"; service/fusion/walk_gate.py):

* ``walk_gate_probability = 0.999`` (χ²₂ 13.8), ``walk_gate_drift = 0.05`` m/m,
  ``walk_gate_margin_m = 1``: K = 3 live p75 1.925 → 1.925 m in sample, 1.898 → 1.898 m
  cross-validated, one walk +0.32 m (Trial24 rep02). p = 0.99 / 0.95: 1.955 / 1.971 m with
  Trial03 rep04 +0.89 m, and no clearer bound on a drag (ten 5 m checkpoints every 3 s: 10.8 m
  at 0.999, 15.8 m at 0.99, 8.4 m at 0.95).
* Issue 27, point 5: a precise fix held out and the next precise one, whose leg between them is
  the reference's leg turned (not shifted), are let in together (service/fusion/walk_gate.py,
  *A heading error revealed by two fixes*); "precise" is σ at most ``walk_gate_margin_m``. No new
  number: the same p, β and margin. Development walks unchanged (K = 0 and 3, live, in sample;
  K = 3 smoothed 1.299 → 1.279 m, Trial24 rep02); ``hold_z`` at K = 3 live 2.238 → 2.175 m.
* ``divergence_m = 50``, ``divergence_sigma_m = 1000``: only a graph that has left any walk
  behind (an absurd fix the gate did not see) restarts; ``restart_heading_sigma_rad = 0.3``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from service.fusion.fixes.ble import BleSettings
from service.fusion.noise import KERNELS


@dataclass(frozen=True)
class FusionSettings:
    """Every number of the fusion, with its unit (see the module docstring for the defaults)."""

    # window and solver
    lag_s: float = 60.0  # s, poses older than the newest by more than this are marginalised
    relinearize_position_m: float = 0.1  # m: iSAM2 relinearises a variable whose position moved more ...
    relinearize_heading_rad: float = 0.01  # rad: ... or whose heading moved more (a lever on the whole track)
    relinearize_skip: int = 1  # iSAM2 updates between relinearisation checks
    fix_extra_updates: int = 5  # at most this many extra iSAM2 iterations after an accepted fix ...
    fix_convergence_m: float = 0.005  # m, ... stopping once the newest pose moves less than this
    update_interval_s: float = 1.0  # s of walking per iSAM2 update (steps batched; dead reckoning between); 0: every step
    # steps
    length_sigma_floor_m: float = 0.02  # m, lower bound of the along-track sigma per step
    turn_sigma_floor_rad: float = 0.002  # rad, lower bound of the turn sigma per step
    unknown_turn_sigma_rad: float = 1.0  # rad, turn sigma when the PDR gives none (first step)
    lateral_sigma_m: float = 0.05  # m, sideways sway of a step, independent of the turn
    turn_walk: float = 0.0  # rad/√s, random walk added to each step's turn (gyro heading errors the PDR does not report)
    stairs_turn_sigma_rad: float = math.radians(10.0)  # rad, added to the turn of a step on stairs (the phone pitches: its yaw is poorly defined)
    stop_turn_s: float = 3.0  # s, a step this long after the previous one follows a stop ...
    stop_turn_sigma_rad: float = math.radians(20.0)  # rad, ... and its turn gets this much more sigma (the grip may change while standing)
    # step-length scale (None: not estimated, plain BetweenFactorPose2 steps)
    length_scale_sigma: float | None = None  # 1-sigma prior on the responder's step-length factor around 1
    length_scale_walk: float = 0.003  # 1/√s, random walk of the factor (σ grows as q·√Δt)
    length_scale_interval_s: float = 120.0  # s, a new scale variable this often (the walk's time grid)
    relinearize_scale: float = 0.005  # iSAM2 relinearises the scale when it moved more than this
    # absolute heading evidence (service/fusion/heading_evidence.py)
    use_mag_heading: bool = True  # absolute heading factors: the compass and the PDR's fused heading
    pdr_heading_interval_s: float | None = 2.0  # s, one factor on the PDR's fused heading per interval (None: none)
    pdr_heading_sigma_rad: float = math.radians(15.0)  # rad, stationary sigma of that heading's wandering offset
    pdr_heading_kernel: str = "gaussian"  # kernel of the PDR heading factor (the offset state absorbs a bias)
    pdr_heading_time_s: float | None = 60.0  # s, correlation time of the PDR heading's error (None: independent factors)
    pdr_heading_white_rad: float = math.radians(3.0)  # rad, white part of the PDR heading factor with an offset state
    pdr_heading_max_sigma_rad: float = math.radians(90.0)  # rad, a PDR heading it knows no better than this is no absolute evidence (no factor)
    mag_sigma_floor_rad: float = math.radians(3.0)  # rad, lower bound of the compass sigma
    mag_kernel: str = "cauchy"  # redescending: an undetected disturbance of many sigmas loses its pull
    mag_kernel_width: float = 1.345  # sigmas
    mag_window_s: float = 5.0  # s, window over which the compass must turn with the gyro
    mag_window_gate_rad: float = math.radians(15.0)  # rad, largest spread of compass-minus-gyro offsets in the window (inf: no gate)
    mag_window_min_steps: int = 4  # compass steps in the window before the gate judges
    mag_min_interval_s: float = 0.0  # s, at most one compass factor per interval (0: every step)
    # checkpoint
    checkpoint_sigma_floor_m: float = 0.05  # m
    # GNSS
    gnss_max_accuracy_m: float = 15.0  # m, reject fixes whose stated 1-sigma accuracy is worse
    gnss_gate_probability: float = 0.999  # χ²(2) gate on the innovation against the pose marginal
    gnss_lowest_floor: int | None = 0  # floors below this are underground: no sky, a GNSS fix there is not evidence
    gnss_min_interval_s: float = 10.0  # s, at most one GNSS factor per interval (indoor GNSS errors are slow, not white)
    gnss_kernel: str = "huber"
    gnss_kernel_width: float = 1.345  # sigmas
    # UWB
    uwb_sigma_floor_m: float = 0.05  # m
    uwb_kernel: str = "huber"
    uwb_kernel_width: float = 1.345  # sigmas
    uwb_gate_probability: float | None = None  # χ²(1) gate on the range innovation; None: off
    uwb_anchor_sigma_m: float = 0.01  # m, prior on a surveyed anchor position
    # what the walk allows (service/fusion/walk_gate.py) and when a graph has failed
    walk_gate_probability: float | None = 0.999  # χ² probability of a fix's noise radius against dead reckoning since the last trusted fix; None: no gate
    walk_gate_drift: float = 0.05  # m per m walked since the last trusted fix: drift the reference's covariance does not model
    walk_gate_margin_m: float = 1.0  # m, survey error of a fix and the slip between its time and its step
    divergence_m: float = 50.0  # m, a graph pose further than this beyond the walk's radius from the reference has diverged
    divergence_sigma_m: float = 1000.0  # m, a graph pose with a larger position sigma has diverged
    restart_heading_sigma_rad: float = 0.3  # rad, heading sigma of a track restarted from dead reckoning
    pdr_heading_jump_rad: float | None = math.radians(90.0)  # rad, the PDR's absolute heading jumped by more
    # than this beyond its gyro turn (its compass offset restarted) and the graph's is as far from it:
    # the graph restarts on the PDR's heading (None: never)
    # BLE beacons: the path-loss model and its noise (service/fusion/fixes/ble.py)
    ble: BleSettings = field(default_factory=BleSettings)
    # published pose
    display_gain: float = 0.5  # share of the gap to the graph's estimate the live pose closes per step (1: none kept)
    # time
    fix_interpolate: bool = True  # a fix inside a step constrains the point of the step walked at its time
    step_motion_s: float = 0.7  # s, a step is walked within this long before its pose (the rest of a longer gap is standing)
    fix_before_start_tolerance_s: float = 2.0  # s, a fix up to this much before start() attaches to x0
    max_events: int = 1000  # events kept in TrackFusion.events (oldest leave)

    def __post_init__(self) -> None:
        positive = ("lag_s", "relinearize_position_m", "relinearize_scale", "length_scale_walk", "length_scale_interval_s", "relinearize_heading_rad", "fix_convergence_m",
                    "length_sigma_floor_m", "turn_sigma_floor_rad",
                    "unknown_turn_sigma_rad", "lateral_sigma_m", "mag_sigma_floor_rad", "mag_kernel_width",
                    "checkpoint_sigma_floor_m", "gnss_max_accuracy_m", "gnss_kernel_width", "uwb_sigma_floor_m",
                    "uwb_kernel_width", "uwb_anchor_sigma_m", "pdr_heading_sigma_rad", "pdr_heading_white_rad",
                    "pdr_heading_max_sigma_rad",
                    "step_motion_s", "stop_turn_s", "divergence_m", "divergence_sigma_m", "restart_heading_sigma_rad")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"FusionSettings.{name} must be a finite number > 0, got {v!r}")
        if not self.mag_window_gate_rad > 0 or not self.mag_window_s > 0:
            raise ValueError("FusionSettings.mag_window_gate_rad and mag_window_s must be > 0 (inf: no gate)")
        for name in ("relinearize_skip", "max_events", "mag_window_min_steps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"FusionSettings.{name} must be >= 1, got {getattr(self, name)!r}")
        for name in ("update_interval_s", "fix_extra_updates", "turn_walk", "stairs_turn_sigma_rad", "mag_min_interval_s", "gnss_min_interval_s", "fix_before_start_tolerance_s",
                     "stop_turn_sigma_rad", "walk_gate_drift", "walk_gate_margin_m"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"FusionSettings.{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("pdr_heading_interval_s", "pdr_heading_time_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"FusionSettings.{name} must be a finite number > 0 or None, got {v!r}")
        for name in ("mag_kernel", "gnss_kernel", "uwb_kernel", "pdr_heading_kernel"):
            if getattr(self, name) not in KERNELS:
                raise ValueError(f"FusionSettings.{name} must be one of {KERNELS}, got {getattr(self, name)!r}")
        if not 0.0 < self.display_gain <= 1.0:
            raise ValueError(f"FusionSettings.display_gain must lie in (0, 1], got {self.display_gain!r}")
        if self.length_scale_sigma is not None and not (math.isfinite(self.length_scale_sigma) and self.length_scale_sigma > 0):
            raise ValueError(f"FusionSettings.length_scale_sigma must be a finite number > 0 or None, got {self.length_scale_sigma!r}")
        for name in ("gnss_gate_probability", "uwb_gate_probability", "walk_gate_probability"):
            p = getattr(self, name)
            if p is not None and not 0.0 < p < 1.0:
                raise ValueError(f"FusionSettings.{name} must be in (0, 1) or None, got {p!r}")
