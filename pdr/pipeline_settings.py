"""Every setting of one responder's dead reckoning (:mod:`pdr.pipeline`), each part with its own record."""
from __future__ import annotations

from dataclasses import dataclass, field

from pdr.air_guard import AirGuardSettings
from pdr.floors import FloorSettings, StairsSettings
from pdr.heading import HeadingSettings
from pdr.height import AltimeterSettings
from pdr.step_length import ResponderProfile
from pdr.steps import SIGNAL


@dataclass(frozen=True)
class PipelineSettings:
    """Every setting of one responder's pipeline, each part with its own record."""

    detector: str = "norm"
    detector_params: tuple[tuple[str, float], ...] = ()
    profile: ResponderProfile = field(default_factory=ResponderProfile)
    heading: HeadingSettings = field(default_factory=HeadingSettings)
    altimeter: AltimeterSettings = field(default_factory=AltimeterSettings)
    air: AirGuardSettings = field(default_factory=AirGuardSettings)  # pressure changes no motion explains (pdr.air_guard)
    floor: FloorSettings = field(default_factory=FloorSettings)
    stairs: StairsSettings = field(default_factory=StairsSettings)
    length_sigma_m: float = 0.05  # σ_0, m: step-length uncertainty floor
    length_sigma_frac: float = 0.08  # k: fraction of the step length
    dz_sigma_m: float = 0.1  # m, per-step height change (barometer after the low-pass)
    min_step_length_m: float = 0.2  # m, a model answer below this is clipped (no negative steps)
    max_step_length_m: float = 1.4  # m, and above this (a running firefighter's long stride)
    bridge_max_s: float = 4.0  # s, the longest interval a step after a gap in the samples stands in for (pdr.step_events)
    floor_event_hold_s: float = 4.0  # s, a floor change is released this long after it (steps before it are out)
    # motion state
    state_grid_s: float = 0.5  # s
    state_delay_s: float = 4.0  # s, decisions lag the newest sample by this much
    still_after_s: float = 2.0  # s without a step -> still
    no_motion_after_s: float = 30.0  # s motionless -> no motion (man-down)
    motionless_window_s: float = 1.0  # s
    motionless_acc_std: float = 0.25  # m/s², std of ‖f‖ over the window
    motionless_gyr: float = 0.15  # rad/s, largest gyro norm in the window
    motionless_pause_s: float = 2.0  # s, a longer pause in the samples is a gap: stillness counts from its end

    def __post_init__(self) -> None:
        # one engine (pdr.fleet) runs the PDR, compiled for these two; the other step detectors
        # and AHRS filters stay batch algorithms for `eval steps` and `eval ahrs`
        if self.detector != "norm":
            raise ValueError(f"the PDR pipeline runs the 'norm' step detector, not {self.detector!r} "
                             f"(the others, {', '.join(k for k in SIGNAL if k != 'norm')}, are for `eval steps`)")
        if self.heading.ahrs != "decoupled":
            raise ValueError(f"the PDR pipeline levels with the 'decoupled' AHRS, not {self.heading.ahrs!r} "
                             "(the others are for `eval ahrs`)")
        if self.state_grid_s <= 0 or self.state_delay_s < 0:
            raise ValueError("state_grid_s must be positive and state_delay_s not negative")
