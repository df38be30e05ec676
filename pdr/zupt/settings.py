"""Every number of the boot-mounted INS, with its unit: detector, filter, strides, gait.

The defaults are the shipped defaults for every wearer and every recording. Those chosen
from data (the SHOE threshold law and the process noise) were chosen by cross-validation
across the PyShoe Vicon recordings: see ``docs/zupt.md`` for the sweep and the held-out
figures. The others are physical (sensor noise, gravity) or taken from the literature.
"""
from __future__ import annotations

import dataclasses
import math

from pdr.constants import GRAVITY

DETECTORS = ("shoe", "ared", "mv", "adaptive")


@dataclasses.dataclass(frozen=True)
class DetectorSettings:
    """Zero-velocity detection (Skog et al. 2010; Wagstaff et al. 2017, 2018).

    Each test statistic is computed over a window of ``window_s`` centred on the sample; the
    sample is *stationary* when the statistic is below the detector's threshold.

    * ``shoe``: GLRT statistic (dimensionless, scaled by ``acc_sigma`` and ``gyro_sigma``)
      below ``shoe_threshold``;
    * ``ared``: mean squared angular rate below ``ared_threshold_rad_s``²;
    * ``mv``: mean squared deviation of the specific force from its window mean below
      ``mv_threshold_m_s2``²;
    * ``adaptive``: SHOE whose threshold follows the gait. Over the last
      ``intensity_window_s`` (in bins of ``intensity_bin_s``), ``A`` is the largest
      specific-force norm and ``F`` the smallest SHOE statistic before the current bin::

          γ = clip( max( clip(γ₀ (A/A₀)^κ, γ₀, γ_max),  c·F ),  γ₀, γ_ceiling )

      Walking heel strikes of 2-3 g keep γ near ``shoe_threshold`` (γ₀); running impacts
      of 5-8 g raise it towards ``adaptive_max_threshold``, because a running foot rests
      for only a few samples and never as still (Wagstaff et al. 2017 found the best SHOE
      threshold of running 10-50 times that of walking; PyShoe switches between them with
      an SVM). The floor term ``c·F`` (``adaptive_floor_factor``) follows the level the
      last stance reached, so a gait whose stances never get as quiet (a sprint, another
      sensor) still gets one update per stance; ``adaptive_ceiling`` bounds it.
    """

    detector: str = "adaptive"
    window_s: float = 0.025  # s, whole window (5 samples at 200 Hz, PyShoe's W = 5)
    acc_sigma: float = 0.01  # m/s², SHOE's accelerometer noise (OpenShoe's σ_a)
    gyro_sigma: float = math.radians(0.1)  # rad/s, SHOE's gyro noise (OpenShoe's σ_g)
    gravity: float = GRAVITY  # m/s²
    shoe_threshold: float = 1.0e4  # γ₀, dimensionless
    ared_threshold_rad_s: float = 0.5  # rad/s (RMS angular rate over the window)
    mv_threshold_m_s2: float = 0.5  # m/s² (RMS deviation of the specific force)
    intensity_window_s: float = 2.0  # s, trailing window of the gait intensity A (one stride or more)
    intensity_bin_s: float = 0.1  # s, A is the maximum of per-bin maxima over the window
    adaptive_reference_m_s2: float = 21.0  # A₀, m/s²: the peak of a slow walk
    adaptive_exponent: float = 4.0  # κ
    adaptive_max_threshold: float = 3.0e5  # γ_max
    adaptive_floor_factor: float = 3.0  # c
    adaptive_ceiling: float = 1.0e6  # γ_ceiling

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ValueError(f"unknown zero-velocity detector {self.detector!r}; choose one of {', '.join(DETECTORS)}")
        for name in ("window_s", "acc_sigma", "gyro_sigma", "gravity", "shoe_threshold", "ared_threshold_rad_s",
                     "mv_threshold_m_s2", "intensity_window_s", "intensity_bin_s", "adaptive_reference_m_s2",
                     "adaptive_max_threshold", "adaptive_ceiling"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"DetectorSettings.{name} must be a positive number, got {v!r}")
        if self.adaptive_exponent < 0 or self.adaptive_floor_factor < 0:
            raise ValueError("DetectorSettings.adaptive_exponent and adaptive_floor_factor must not be negative")
        if not self.shoe_threshold <= self.adaptive_max_threshold <= self.adaptive_ceiling:
            raise ValueError("DetectorSettings needs shoe_threshold <= adaptive_max_threshold <= adaptive_ceiling")
        if self.intensity_bin_s > self.intensity_window_s:
            raise ValueError("DetectorSettings.intensity_bin_s must not exceed intensity_window_s")


@dataclasses.dataclass(frozen=True)
class InsSettings:
    """The 15-state error-state Kalman filter (Foxlin 2005; Skog et al. 2010; OpenShoe).

    Noise densities: a white noise of density ``σ`` (unit/√Hz) sampled every Δt has a
    per-sample standard deviation ``σ/√Δt``. PyShoe's process noise, 0.5 m/s² and 0.5 °/s
    per sample at 200 Hz, are densities of 0.035 m/s²/√Hz and 0.035 °/s/√Hz; the defaults
    here, 0.05 m/s² and 1 °/s per sample at 200 Hz, were chosen by cross-validation (the
    3DM-GX3's own white noise is about 0.02 m/s² and 0.5 °/s per sample at 200 Hz: the
    filter's gyro noise also covers the attitude error of a boot that is never quite
    still; ``docs/zupt.md``).
    """

    acc_noise_density: float = 0.05 / math.sqrt(200.0)  # m/s²/√Hz
    gyro_noise_density: float = math.radians(1.0) / math.sqrt(200.0)  # rad/s/√Hz
    acc_bias_walk: float = 0.0  # m/s²/√s, accelerometer bias random walk
    gyro_bias_walk: float = 0.0  # rad/s/√s, gyro bias random walk
    zupt_sigma: float = 0.01  # m/s, zero-velocity pseudo-measurement
    zaru_sigma: float = 0.01  # rad/s, zero-angular-rate pseudo-measurement
    zaru_max_rate: float = 0.0  # rad/s, RMS rate below which a stationary sample also gets ZARU (0: off)
    init_acc_bias_sigma: float = 0.01  # m/s²
    init_gyro_bias_sigma: float = 3.0e-4  # rad/s
    init_tilt_sigma: float = math.radians(0.1)  # rad, roll and pitch from the first still window
    init_position_sigma: float = 1.0e-5  # m
    init_velocity_sigma: float = 1.0e-5  # m/s
    init_yaw_sigma: float = 1.0e-5  # rad: yaw is defined by the start (see ZuptIns), not estimated
    gravity: float = GRAVITY  # m/s²; NaN: the specific-force norm of the first still window
    init_still_s: float = 0.1  # s of continuous zero velocity that start the INS
    max_dt: float = 0.05  # s, a longer interval between samples counts as this long

    def __post_init__(self) -> None:
        for name in ("acc_noise_density", "gyro_noise_density", "zupt_sigma", "zaru_sigma", "init_acc_bias_sigma",
                     "init_gyro_bias_sigma", "init_tilt_sigma", "init_position_sigma", "init_velocity_sigma",
                     "init_yaw_sigma", "init_still_s", "max_dt"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"InsSettings.{name} must be a positive number, got {v!r}")
        for name in ("acc_bias_walk", "gyro_bias_walk", "zaru_max_rate"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"InsSettings.{name} must be a number >= 0, got {v!r}")
        if not (math.isnan(self.gravity) or self.gravity > 0):
            raise ValueError(f"InsSettings.gravity must be positive or NaN, got {self.gravity!r}")


@dataclasses.dataclass(frozen=True)
class StrideSettings:
    """When a stance makes a stride event, and the uncertainty the event carries."""

    settle_s: float = 0.05  # s into a stance when the stride is emitted (ZUPTs have removed the swing's velocity error)
    min_stance_s: float = 0.01  # s, a shorter stationary spell is no stance
    min_swing_s: float = 0.2  # s, a shorter motion between stationary spells does not end the stance
    length_sigma_m: float = 0.01  # m, floor of the along-track sigma
    length_sigma_frac: float = 0.02  # of the stride length (ZUPT INS strides read about 2 % short on Vicon)
    dz_sigma_m: float = 0.02  # m, floor of the vertical sigma
    heading_min_length_m: float = 0.1  # m, a shorter stride keeps the previous direction of travel
    heading_change_sigma_floor: float = math.radians(0.5)  # rad, per stride
    unaligned_heading_sigma: float = math.pi  # rad, absolute heading sigma when no compass aligned the start

    def __post_init__(self) -> None:
        for name in ("settle_s", "min_stance_s", "min_swing_s", "heading_min_length_m", "heading_change_sigma_floor",
                     "unaligned_heading_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"StrideSettings.{name} must be a positive number, got {v!r}")
        for name in ("length_sigma_m", "length_sigma_frac", "dz_sigma_m"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"StrideSettings.{name} must not be negative")


@dataclasses.dataclass(frozen=True)
class GaitSettings:
    """Motion states a commander reads: walking, running, crawling, stairs, still, no motion.

    Per stride: ``stairs`` when it rises or falls by at least ``stairs_min_dz_m`` (one riser
    is 0.15-0.19 m and a stride of one foot spans two); ``crawling`` when the boot rests
    tilted by more than ``crawl_tilt`` from its attitude at the first
    still window (on the knees the boot rests on its toe, sole nearly vertical); ``running`` when the stride
    takes less than ``run_max_stride_s`` or its impact exceeds ``run_min_peak_m_s2``;
    else ``walking``. The state is the class most frequent among the last ``vote_strides``
    strides and holds while a stride came within ``still_after_s``.
    """

    stairs_min_dz_m: float = 0.15  # m per stride
    crawl_tilt: float = math.radians(60.0)  # rad from the boot's attitude at the start (standing)
    run_max_stride_s: float = 0.85  # s (walking strides take 1.0-1.7 s, running 0.7-0.8 s on PyShoe's data)
    run_min_peak_m_s2: float = 55.0  # m/s² (walking heel strikes 2-5 g, running 5-8 g)
    vote_strides: int = 3  # the state is the class most frequent among this many last strides
    still_after_s: float = 2.0  # s without a stride -> still
    no_motion_after_s: float = 30.0  # s motionless -> no motion (man-down; NFPA 1982 PASS alarm time)
    motionless_window_s: float = 1.0  # s
    motionless_acc_std: float = 0.25  # m/s², std of ‖f‖ over the window
    motionless_gyr: float = 0.15  # rad/s, largest gyro norm in the window
    state_grid_s: float = 0.5  # s, the state is decided on this grid of data time

    def __post_init__(self) -> None:
        if self.vote_strides < 1:
            raise ValueError("GaitSettings.vote_strides must be at least 1")
        for name in ("stairs_min_dz_m", "crawl_tilt", "run_max_stride_s", "run_min_peak_m_s2", "still_after_s",
                     "no_motion_after_s", "motionless_window_s", "motionless_acc_std", "motionless_gyr", "state_grid_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"GaitSettings.{name} must be a positive number, got {v!r}")


@dataclasses.dataclass(frozen=True)
class ZuptSettings:
    """Everything the boot-mounted motion model needs, each part with its own record."""

    detector: DetectorSettings = dataclasses.field(default_factory=DetectorSettings)
    ins: InsSettings = dataclasses.field(default_factory=InsSettings)
    stride: StrideSettings = dataclasses.field(default_factory=StrideSettings)
    gait: GaitSettings = dataclasses.field(default_factory=GaitSettings)
