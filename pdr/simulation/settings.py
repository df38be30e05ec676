"""What a simulated walker is and where it walks: :class:`WalkerSettings`, :class:`Route`.

Every number of the simulator is a named setting with its unit. Random routes come from
:func:`random_waypoints` (an endless, lazily drawn stream, what a walker without a route
follows) and :func:`random_route` (a finite :class:`Route` drawn the same way).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator

import numpy as np

from pdr.height import P_STANDARD, T_STANDARD
from pdr.synthetic import FIELD_ENU

Bounds = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (ENU m)
FloorRange = tuple[int, int]  # lowest, highest floor


@dataclasses.dataclass(frozen=True)
class WalkerSettings:
    """How a simulated responder walks and what its phone's sensors add (units in the names or comments).

    Per-walker variety: each walker draws its cadence, step length and oscillation sizes
    around these values (``*_jitter`` are relative standard deviations), its gyro bias
    uniformly within ``±gyro_bias`` per axis and the phases of its sway.
    """

    rate_hz: float = 100.0  # IMU sampling rate
    # gait
    cadence_hz: float = 1.8  # steps per second on the flat
    cadence_jitter: float = 0.05  # per walker, relative
    cadence_leg_jitter: float = 0.02  # per route leg, relative
    step_length_m: float = 0.7  # on the flat
    step_length_jitter: float = 0.05  # per walker, relative
    stairs_tread_m: float = 0.28  # horizontal length of a stair step (random routes' flights)
    stairs_riser_m: float = 0.17  # height of a stair step: a flight takes |Δz| / riser steps
    stairs_cadence_factor: float = 0.85  # cadence on stairs / cadence on the flat
    vertical_acc_amplitude: float = 2.5  # m/s², bounce at the step frequency
    forward_acc_amplitude: float = 1.2  # m/s², surge at the step frequency
    lateral_acc_amplitude: float = 0.6  # m/s², sway of the body at half the step frequency
    amplitude_jitter: float = 0.1  # per walker, relative
    pitch_sway_rad: float = 0.03  # phone pitch wobble at the step frequency
    roll_sway_rad: float = 0.04  # phone roll wobble at half the step frequency
    yaw_sway_rad: float = 0.03  # phone yaw wobble at half the step frequency
    ramp_s: float = 0.5  # s, starting or stopping (speed and bounce go smoothly to or from zero)
    cadence_blend_s: float = 1.0  # s, a change of cadence between legs walked through
    # turns
    turn_s_per_rad: float = 0.8  # s per rad of a turn taken while walking
    turn_min_s: float = 0.5  # s
    turn_max_s: float = 1.6  # s
    max_walking_turn_rad: float = 2.0  # rad; a sharper corner is taken standing: stop, turn, go
    spin_s_per_rad: float = 0.5  # s per rad of a turn on the spot
    spin_min_s: float = 0.6  # s
    # sensors
    gyro_noise: float = 0.003  # rad/s, white, per axis per sample
    gyro_bias: float = 0.003  # rad/s, bound of the per-walker constant bias, per axis
    acc_noise: float = 0.05  # m/s², white, per axis per sample
    mag_noise: float = 0.3  # µT, white, per axis per sample
    field_enu: tuple[float, float, float] = tuple(float(v) for v in FIELD_ENU)  # µT, geomagnetic field
    declination_rad: float = 0.0  # east positive: the field's horizontal part points to bearing D
    pressure_rate_hz: float = 10.0  # barometer rate (every k-th IMU sample, k = round(rate_hz / this))
    pressure_noise_hpa: float = 0.01  # white
    base_pressure_hpa: float = P_STANDARD  # pressure at z = 0 (floor 0)
    pressure_drift_hpa_per_h: float = 0.0  # weather: the base pressure changes linearly in time
    temperature_k: float = T_STANDARD  # air temperature in the pressure formula (pdr.height)
    # building and behaviour
    floor_height_m: float = 3.0  # floor k lies at z = k * floor_height_m
    initial_still_s: float = 2.0  # s standing still before the first step
    pause_probability: float = 0.2  # random routes: chance of a pause at a waypoint
    pause_min_s: float = 2.0
    pause_max_s: float = 8.0
    stairs_probability: float = 0.15  # random routes: chance that a leg changes floor
    leg_min_m: float = 4.0  # random routes: leg length on the flat
    leg_max_m: float = 15.0
    fall_s: float = 1.0  # s, a collapse: the phone tips over during this time
    fall_pitch_rad: float = 1.4  # rad, the phone's pitch once the responder lies on the floor

    def __post_init__(self) -> None:
        positive = ("rate_hz", "cadence_hz", "step_length_m", "stairs_tread_m", "stairs_riser_m",
                    "stairs_cadence_factor", "ramp_s", "cadence_blend_s", "turn_min_s", "turn_max_s", "spin_min_s",
                    "pressure_rate_hz", "base_pressure_hpa", "temperature_k", "floor_height_m",
                    "leg_min_m", "leg_max_m", "fall_s")
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"WalkerSettings.{name} must be a positive finite number, got {v!r}")
        non_negative = ("cadence_jitter", "cadence_leg_jitter", "step_length_jitter", "vertical_acc_amplitude",
                        "forward_acc_amplitude", "lateral_acc_amplitude", "amplitude_jitter", "pitch_sway_rad",
                        "roll_sway_rad", "yaw_sway_rad", "turn_s_per_rad", "spin_s_per_rad", "gyro_noise",
                        "gyro_bias", "acc_noise", "mag_noise", "pressure_noise_hpa", "initial_still_s",
                        "pause_min_s", "pause_max_s", "max_walking_turn_rad")
        for name in non_negative:
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"WalkerSettings.{name} must be a finite number >= 0, got {v!r}")
        for name in ("pause_probability", "stairs_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"WalkerSettings.{name} must lie in [0, 1], got {getattr(self, name)!r}")
        if self.turn_max_s < self.turn_min_s or self.leg_max_m < self.leg_min_m or self.pause_max_s < self.pause_min_s:
            raise ValueError("WalkerSettings: turn_max_s, leg_max_m, pause_max_s must not be below their minimum")
        if len(self.field_enu) != 3 or not all(math.isfinite(v) for v in self.field_enu):
            raise ValueError(f"WalkerSettings.field_enu must be three finite numbers (µT), got {self.field_enu!r}")
        if self.rate_hz < self.pressure_rate_hz:
            raise ValueError("WalkerSettings.pressure_rate_hz must not exceed rate_hz")

    @property
    def pressure_every(self) -> int:
        """The barometer reads at every this many IMU samples."""
        return max(1, round(self.rate_hz / self.pressure_rate_hz))

    @property
    def field(self) -> np.ndarray:
        """The field in ENU (µT) with the declination applied: ``Rz(-D) B``."""
        b = np.asarray(self.field_enu, float)
        c, s = math.cos(self.declination_rad), math.sin(self.declination_rad)
        return np.array([c * b[0] + s * b[1], -s * b[0] + c * b[1], b[2]])


@dataclasses.dataclass(frozen=True)
class Route:
    """Waypoints (K, 2) in ENU metres with their floors (K,) and optional pauses (K,) in seconds.

    The walker starts at waypoint 0 and walks to each next one. A leg between different
    floors is a staircase: the height changes linearly along it and steps are stair treads.
    ``pauses[k]`` seconds are spent standing at waypoint k (after any turn on the spot).
    After the last waypoint the walker stands still for good.
    """

    waypoints: np.ndarray
    floors: np.ndarray
    pauses: np.ndarray | None = None

    def __post_init__(self) -> None:
        wp = np.array(self.waypoints, dtype=float)
        if wp.ndim != 2 or wp.shape[1] != 2 or wp.shape[0] < 1:
            raise ValueError(f"Route.waypoints must have shape (K, 2) with K >= 1, got {wp.shape}")
        if not np.isfinite(wp).all():
            bad = int(np.flatnonzero(~np.isfinite(wp).all(axis=1))[0])
            raise ValueError(f"Route.waypoints[{bad}] is not finite: {wp[bad].tolist()}")
        fl = np.array(self.floors)
        if fl.shape != (wp.shape[0],):
            raise ValueError(f"Route.floors must have shape ({wp.shape[0]},), got {fl.shape}")
        if not np.all(np.asarray(fl, float) == np.round(np.asarray(fl, float))):
            raise ValueError(f"Route.floors must be integers, got {fl.tolist()}")
        fl = fl.astype(np.int64)
        pa = np.zeros(wp.shape[0]) if self.pauses is None else np.array(self.pauses, dtype=float)
        if pa.shape != (wp.shape[0],) or not (np.isfinite(pa).all() and (pa >= 0).all()):
            raise ValueError(f"Route.pauses must be ({wp.shape[0]},) finite seconds >= 0, got {pa.tolist()}")
        same = np.flatnonzero((np.hypot(*np.diff(wp, axis=0).T) < 1e-6) & (np.diff(fl) != 0))
        if same.size:
            k = int(same[0])
            raise ValueError(f"Route: waypoints {k} and {k + 1} change floor without horizontal distance "
                             "(a staircase needs a horizontal run)")
        for name, v in (("waypoints", wp), ("floors", fl), ("pauses", pa)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)

    def __len__(self) -> int:
        return self.waypoints.shape[0]


def random_waypoints(rng: np.random.Generator, bounds: Bounds, floors: FloorRange, settings: WalkerSettings,
                     start: tuple[float, float, int], heading: float) -> Iterator[tuple[float, float, int, float]]:
    """An endless stream of ``(x, y, floor, pause_s)`` waypoints after ``start = (x, y, floor)``.

    Indoor-like legs: mostly a right angle or straight on, sometimes any direction; lengths
    uniform in ``[leg_min_m, leg_max_m]``; with ``stairs_probability`` a staircase to the
    floor above or below (``floor_height / riser`` treads long); a pause with
    ``pause_probability``. A leg that would leave ``bounds`` is redrawn (up to 8 times),
    then the walker heads for the middle of the bounds.
    """
    xmin, xmax, ymin, ymax = _check_bounds(bounds)
    lowest, highest = _check_floors(floors)
    x, y, floor = float(start[0]), float(start[1]), int(start[2])
    stairs_len = settings.floor_height_m / settings.stairs_riser_m * settings.stairs_tread_m
    while True:
        new_floor = floor
        if highest > lowest and rng.random() < settings.stairs_probability:
            up = floor < highest and (floor == lowest or rng.random() < 0.5)
            new_floor = floor + (1 if up else -1)
            length = stairs_len
        else:
            length = rng.uniform(settings.leg_min_m, settings.leg_max_m)
        for _ in range(8):
            r = rng.random()
            if r < 0.5:
                turn = math.copysign(math.pi / 2, rng.random() - 0.5)
            elif r < 0.8:
                turn = rng.uniform(-0.35, 0.35)
            else:
                turn = rng.uniform(-math.pi, math.pi)
            h = heading + turn
            nx, ny = x + length * math.cos(h), y + length * math.sin(h)
            if xmin <= nx <= xmax and ymin <= ny <= ymax:
                break
        else:
            cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
            h = math.atan2(cy - y, cx - x)
            length = min(length, max(math.hypot(cx - x, cy - y), 1.0))
            nx, ny = x + length * math.cos(h), y + length * math.sin(h)
        pause = rng.uniform(settings.pause_min_s, settings.pause_max_s) if rng.random() < settings.pause_probability else 0.0
        x, y, floor, heading = nx, ny, new_floor, h
        yield x, y, floor, pause


def random_start(rng: np.random.Generator, bounds: Bounds, floors: FloorRange) -> tuple[float, float, int, float]:
    """A start ``(x, y, floor, heading)``: uniform inside ``bounds``, floor 0 if in range (else the lowest)."""
    xmin, xmax, ymin, ymax = _check_bounds(bounds)
    lowest, highest = _check_floors(floors)
    x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
    return float(x), float(y), min(max(0, lowest), highest), float(rng.uniform(-math.pi, math.pi))


def random_route(rng: np.random.Generator, bounds: Bounds = (0.0, 40.0, 0.0, 20.0), floors: FloorRange = (0, 2),
                 n_waypoints: int = 10, settings: WalkerSettings | None = None) -> Route:
    """A finite random :class:`Route` of ``n_waypoints`` (start included), drawn like :func:`random_waypoints`."""
    if n_waypoints < 1:
        raise ValueError(f"n_waypoints must be >= 1, got {n_waypoints}")
    settings = settings or WalkerSettings()
    x, y, floor, heading = random_start(rng, bounds, floors)
    pts = [(x, y, floor, 0.0)]
    stream = random_waypoints(rng, bounds, floors, settings, (x, y, floor), heading)
    pts += [next(stream) for _ in range(n_waypoints - 1)]
    a = np.array(pts, dtype=float)
    return Route(a[:, :2], a[:, 2].astype(np.int64), a[:, 3])


def _check_bounds(bounds) -> Bounds:
    try:
        xmin, xmax, ymin, ymax = (float(v) for v in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"bounds must be (xmin, xmax, ymin, ymax) in metres, got {bounds!r}") from None
    if not (xmin < xmax and ymin < ymax) or not all(map(math.isfinite, (xmin, xmax, ymin, ymax))):
        raise ValueError(f"bounds must be finite with xmin < xmax and ymin < ymax, got {bounds!r}")
    return xmin, xmax, ymin, ymax


def _check_floors(floors) -> FloorRange:
    try:
        lowest, highest = (int(v) for v in floors)
    except (TypeError, ValueError):
        raise ValueError(f"floors must be (lowest, highest) integers, got {floors!r}") from None
    if highest < lowest:
        raise ValueError(f"floors must have lowest <= highest, got {floors!r}")
    return lowest, highest
