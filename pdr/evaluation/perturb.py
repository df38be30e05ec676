"""Perturbations of a phone's sensor log, for measuring how robust the PDR is.

Each function is pure: arrays in, new arrays out, nothing modified in place, randomness only
from an explicit ``seed`` (a :class:`numpy.random.Generator` seed: an int or a sequence of
ints), so a perturbed walk is the same on every run. Times are seconds on the device clock,
vectors are ``(N, 3)`` in the phone's body frame (x right, y up the long side, z out of the
screen), angles in radians. Each models one physical situation, said in its docstring;
:mod:`pdr.evaluation.robustness` names them and applies them to a whole recording.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

# --------------------------------------------------------------------------------------------
# Sampling and timestamps
# --------------------------------------------------------------------------------------------
ANTI_ALIAS_FRACTION = 0.8  # low-pass corner as a share of the new Nyquist frequency
ANTI_ALIAS_ORDER = 4


def median_rate_hz(t: np.ndarray) -> float:
    """The log's typical rate, robust to the odd gap or late sample."""
    return float(1.0 / np.median(np.diff(t)))


def uniform_grid(t0: float, t1: float, rate_hz: float) -> np.ndarray:
    """Times ``t0 + k / rate_hz`` for k = 0, 1, ... up to ``t1``."""
    return t0 + np.arange(int(np.floor((t1 - t0) * rate_hz + 1e-9)) + 1) / rate_hz


def resample(t: np.ndarray, values: np.ndarray, rate_hz: float, grid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The same motion logged by a phone whose sensor runs at ``rate_hz``.

    Phones log at jittery, non-uniform times, so the samples are first put on a uniform grid at
    the log's own median rate f_s by linear interpolation. Going down (``rate_hz`` < f_s) a
    zero-phase Butterworth low-pass (order 4, corner 0.8 x the new Nyquist frequency
    ``rate_hz / 2``) removes what the new rate cannot carry, as the sensor's own digital
    low-pass would; then the signal is interpolated linearly onto the new grid
    ``t0 + k / rate_hz`` (or onto ``grid`` when given, e.g. to share one grid between the
    accelerometer and the gyroscope). Going up is interpolation alone.
    Returns ``(t_new, values_new)``.
    """
    t = np.asarray(t, float)
    v = np.asarray(values, float).reshape(t.size, -1)
    new_t = uniform_grid(t[0], t[-1], rate_hz) if grid is None else np.asarray(grid, float)
    src_rate = median_rate_hz(t)
    if rate_hz < 0.95 * src_rate:
        tu = uniform_grid(t[0], t[-1], src_rate)
        vu = _interp_columns(tu, t, v)
        sos = butter(ANTI_ALIAS_ORDER, ANTI_ALIAS_FRACTION * rate_hz / src_rate, output="sos")  # Wn in Nyquist units
        if tu.size > 3 * (2 * sos.shape[0] + 1):
            vu = sosfiltfilt(sos, vu, axis=0)
        t, v = tu, vu
    return new_t, _interp_columns(new_t, t, v)


def _interp_columns(at: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(at, t, v[:, k]) for k in range(v.shape[1])])


def browser_stamps(t: np.ndarray, seed, jitter_s: float = 0.003, late_per_s: float = 0.2,
                   late_s: tuple[float, float] = (0.02, 0.1), min_step_s: float = 1e-3) -> np.ndarray:
    """Timestamps a web page would give samples taken at ``t``: each event's arrival time.

    A browser stamps a motion event when the page's event loop handles it, not when the sensor
    sampled it: each stamp is late by ``|N(0, jitter_s)|`` (a few ms of scheduling), and about
    ``late_per_s`` times a second the page is busy (layout, garbage collection) and an event
    arrives ``late_s`` (uniform) late. Events arrive in order, so the ones queued behind a late
    event arrive in a burst just after it: the stamps are made increasing, at least
    ``min_step_s`` apart.
    """
    t = np.asarray(t, float)
    rng = np.random.default_rng(seed)
    delay = np.abs(rng.normal(0.0, jitter_s, t.size))
    late = rng.random(t.size) < late_per_s * np.median(np.diff(t)) if t.size > 1 else np.zeros(t.size, bool)
    delay[late] += rng.uniform(late_s[0], late_s[1], int(late.sum()))
    k = np.arange(t.size) * min_step_s
    return np.maximum.accumulate(t + delay - k) + k


def timer_ticks(t0: float, t1: float, rate_hz: float, seed, wander_s: float = 0.0029, dispatch_s: float = 0.0023,
                late_per_s: float = 0.2, late_s: tuple[float, float] = (0.02, 0.1), min_step_s: float = 3e-3) -> np.ndarray:
    r"""When a browser reads its motion sensors: the ticks of a ``rate_hz`` timer that wanders.

    Chromium fires ``devicemotion`` from a timer in the page's process; at each tick it reads
    the sensor's newest value and stamps the event then, so the reading belongs to the tick
    and the ticks are uneven. Measured in the browser walk test (tests/test_phone_browser.py,
    Chromium under the DevTools sensor overrides, 6546 intervals): median 15.8 ms, mean 17.0 ms,
    standard deviation 4.3 ms, 5-95 % from 10.4 to 24.1 ms, consecutive intervals correlated
    -0.28. Modelled as each interval ``1/rate_hz + N(0, wander_s)`` (the timer drifts) plus
    a dispatch delay ``N(0, dispatch_s)`` per tick (the lag-1 correlation is then
    :math:`-\sigma_d^2 / (\sigma_w^2 + 2\sigma_d^2)`), and about ``late_per_s`` times a
    second a busy page holds a tick back by ``late_s`` (uniform). Ticks stay ``min_step_s``
    apart (what the page keeps, ``client/console/static/js/wear/motion.js``).
    """
    rng = np.random.default_rng(seed)
    n = int(np.ceil((t1 - t0) * rate_hz * 1.2)) + 2
    dt = rng.normal(1.0 / rate_hz, wander_s, n)
    late = rng.random(n) < late_per_s / rate_hz
    dt[late] += rng.uniform(late_s[0], late_s[1], int(late.sum()))
    ticks = t0 + rng.uniform(0.0, 1.0 / rate_hz) + np.cumsum(np.maximum(dt, min_step_s)) + rng.normal(0.0, dispatch_s, n)
    k = np.arange(n) * min_step_s
    ticks = np.maximum.accumulate(ticks - k) + k
    return ticks[(ticks >= t0) & (ticks <= t1)]


def quantize(values: np.ndarray, step: float) -> np.ndarray:
    """Readings rounded to multiples of ``step``, as a browser rounds motion sensors (about
    0.1 m/s² and 0.1 °/s in Chromium, a privacy measure against fingerprinting)."""
    return np.round(np.asarray(values, float) / step) * step


# --------------------------------------------------------------------------------------------
# The phone turned in the hand
# --------------------------------------------------------------------------------------------
def grip_angle(t: np.ndarray, start_s: float, angle_rad: float, turn_s: float = 0.5,
               back_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The angle θ(t) by which the phone has been turned in the hand, and its rate θ'(t).

    The turn starts at ``start_s`` and takes ``turn_s`` along a raised cosine,
    θ = angle · (1 − cos(π s)) / 2 with s = (t − start) / turn_s in [0, 1], so the rate
    θ' = angle · π / (2 turn_s) · sin(π s) is smooth (a hand's turn, not a jump). With
    ``back_s`` the phone is turned back the same way from that time on (held in another
    attitude for a stretch). ``turn_s`` = 0 is an instantaneous turn (θ' = 0).
    """
    t = np.asarray(t, float)

    def ramp(t0: float) -> tuple[np.ndarray, np.ndarray]:
        if turn_s <= 0:
            return (t >= t0).astype(float), np.zeros_like(t)
        s = np.clip((t - t0) / turn_s, 0.0, 1.0)
        inside = (t > t0) & (t < t0 + turn_s)
        return 0.5 * (1.0 - np.cos(np.pi * s)), np.where(inside, 0.5 * np.pi / turn_s * np.sin(np.pi * s), 0.0)

    th, dth = ramp(start_s)
    if back_s is not None:
        b, db = ramp(back_s)
        th, dth = th - b, dth - db
    return angle_rad * th, angle_rad * dth


def in_turned_phone(vectors: np.ndarray, axis, theta: np.ndarray) -> np.ndarray:
    """World vectors (gravity, the Earth's field) as the phone sees them once it is turned in the
    hand by θ about its own ``axis``: if the new body frame is the old one rotated by R(a, θ),
    a vector's new body coordinates are v' = R(a, θ)ᵀ v, i.e. Rodrigues' formula with −θ:
    v' = v cos θ − (a × v) sin θ + a (a · v)(1 − cos θ). Norms are kept."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    v = np.asarray(vectors, float)
    th = np.broadcast_to(np.asarray(theta, float), v.shape[:1])[:, None]
    c, s = np.cos(th), np.sin(th)
    return v * c - np.cross(a, v) * s + np.outer(v @ a, a) * (1.0 - c)


def gyro_in_turned_phone(gyr: np.ndarray, axis, theta: np.ndarray, theta_rate: np.ndarray) -> np.ndarray:
    """The gyroscope of a phone being turned in the hand about its own fixed ``axis``.

    With body attitude q(t) = q_walk(t) ⊗ q(a, θ(t)), the body rate is
    ω' = R(a, θ)ᵀ ω + a θ' (the turn's own rate is along a, which R(a, θ) leaves unchanged).
    """
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    return in_turned_phone(gyr, a, theta) + np.outer(np.asarray(theta_rate, float), a)


# --------------------------------------------------------------------------------------------
# Sensor errors
# --------------------------------------------------------------------------------------------
def random_direction(seed) -> np.ndarray:
    """A unit vector uniform on the sphere (the direction of a bias that nobody calibrated)."""
    v = np.random.default_rng(seed).normal(size=3)
    return v / np.linalg.norm(v)


def with_bias(values: np.ndarray, bias) -> np.ndarray:
    """A constant offset on every sample: an uncalibrated gyroscope's zero-rate offset (up to
    about 0.5 °/s on a phone after warm-up drift) or an accelerometer's (0.1–0.2 m/s²)."""
    return np.asarray(values, float) + np.asarray(bias, float)


def with_scale(values: np.ndarray, factors) -> np.ndarray:
    """Each axis multiplied by its factor: a sensitivity (scale-factor) error, e.g. 1.02 for a
    gyroscope that reads 2 % too much, so every turn comes out 2 % too large."""
    return np.asarray(values, float) * np.asarray(factors, float)


def steel_stretches(t0: float, t1: float, seed, per_min: float = 2.0, length_s: tuple[float, float] = (4.0, 15.0),
                    field_ut: tuple[float, float] = (20.0, 50.0)) -> list[tuple[float, float, np.ndarray]]:
    """Where the walker passes steel (a railing, a machine, a fire door): ``per_min`` stretches
    a minute on average, each ``length_s`` long (uniform), with an extra field of ``field_ut``
    µT (uniform) in a random direction. Returns ``[(start, end, offset (3,)), ...]``, in
    order, not overlapping."""
    rng = np.random.default_rng(seed)
    out, t = [], t0 + rng.exponential(60.0 / per_min)
    while t < t1:
        length = rng.uniform(*length_s)
        v = rng.normal(size=3)
        out.append((t, min(t + length, t1), rng.uniform(*field_ut) * v / np.linalg.norm(v)))
        t += length + rng.exponential(60.0 / per_min)
    return out


def near_steel(t: np.ndarray, mag: np.ndarray, stretches, ramp_s: float = 1.0) -> np.ndarray:
    """The magnetometer near steel: during each stretch ``(start, end, offset)`` the offset is
    added, faded in and out over ``ramp_s`` (raised cosine) as the phone approaches and leaves.
    The offset is held fixed in the body frame (a stretch is short against the walk's turns)."""
    t = np.asarray(t, float)
    out = np.array(mag, float, copy=True)
    for start, end, offset in stretches:
        out += np.outer(faded(t, start, end, ramp_s), offset)
    return out


def faded(t: np.ndarray, start: float, end: float, ramp_s: float) -> np.ndarray:
    """Weight 0..1 of a stretch ``[start, end]`` at times ``t``: faded in after ``start`` and
    out before ``end`` over ``ramp_s`` (raised cosine)."""
    up = np.clip((t - start) / ramp_s, 0.0, 1.0)
    down = np.clip((end - t) / ramp_s, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(np.pi * np.minimum(up, down)))


# --------------------------------------------------------------------------------------------
# Lost samples
# --------------------------------------------------------------------------------------------
def dropped(n: int, fraction: float, seed) -> np.ndarray:
    """Mask of the samples kept when each is lost independently with probability ``fraction``
    (a busy phone dropping sensor events under load)."""
    return np.random.default_rng(seed).random(n) >= fraction


def gap_windows(t0: float, t1: float, seed, every_s: float = 30.0,
                length_s: tuple[float, float] = (0.2, 2.0)) -> np.ndarray:
    """``(k, 2)`` windows [start, end) in which nothing is logged: one in each ``every_s`` of
    the walk, at a random place in it, ``length_s`` long (uniform); the app stalled, the phone
    paused the sensors, a radio link dropped frames."""
    rng = np.random.default_rng(seed)
    n = int((t1 - t0) // every_s)
    starts = t0 + every_s * (np.arange(n) + rng.uniform(0.1, 0.9, n))
    return np.column_stack([starts, starts + rng.uniform(*length_s, n)]) if n else np.empty((0, 2))


def outside_windows(t: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """Mask of the samples not in any window [start, end)."""
    t = np.asarray(t, float)
    keep = np.ones(t.size, bool)
    for start, end in np.asarray(windows, float).reshape(-1, 2):
        keep &= ~((t >= start) & (t < end))
    return keep


# --------------------------------------------------------------------------------------------
# The barometer
# --------------------------------------------------------------------------------------------
PA_PER_M = 11.8  # Pa of pressure per metre of height near the ground (ρ g, ρ = 1.2 kg/m³)


def fan_started(t0: float, t1: float, seed, rise_pa: tuple[float, float] = (20.0, 50.0),
                at: tuple[float, float] = (0.2, 0.6)) -> tuple[float, float, float]:
    """A positive-pressure ventilation fan set in a doorway (a fire service's usual tactic) or a
    stairwell's pressurisation starting: the building's air pressure rises by ``rise_pa`` Pa
    (uniform; stairwell pressurisation is designed for 12.5-87 Pa, NFPA 92) at a random share
    ``at`` of the walk and stays. A barometer reads it as a drop in height of ``rise / 11.8`` m
    (1.7-4.2 m), with no step taken. Returns ``(start, end, offset hPa)`` with ``end = inf``."""
    rng = np.random.default_rng(seed)
    return t0 + rng.uniform(*at) * (t1 - t0), np.inf, rng.uniform(*rise_pa) / 100.0


def door_pulses(t0: float, t1: float, seed, per_min: float = 1.0, length_s: tuple[float, float] = (3.0, 20.0),
                dp_pa: tuple[float, float] = (10.0, 40.0)) -> list[tuple[float, float, float]]:
    """Doors into pressurised stairwells and lobbies opened and shut, air handling switching:
    ``per_min`` stretches a minute on average, each ``length_s`` long (uniform), in which the
    pressure is off by ``dp_pa`` Pa (uniform, either sign; 0.8-3.4 m of apparent height).
    Returns ``[(start, end, offset hPa), ...]``, in order, not overlapping."""
    rng = np.random.default_rng(seed)
    out, t = [], t0 + rng.exponential(60.0 / per_min)
    while t < t1:
        length = rng.uniform(*length_s)
        out.append((t, min(t + length, t1), rng.choice((-1.0, 1.0)) * rng.uniform(*dp_pa) / 100.0))
        t += length + rng.exponential(60.0 / per_min)
    return out


def pressure_offsets(t: np.ndarray, pressure: np.ndarray, stretches, ramp_s: float = 2.0) -> np.ndarray:
    """The pressure (hPa) with each stretch's ``(start, end, offset)`` added, faded in and out
    over ``ramp_s`` (raised cosine: a fan spinning up, a door swinging)."""
    t = np.asarray(t, float)
    out = np.array(pressure, float, copy=True).reshape(len(t), -1)
    for start, end, offset in stretches:
        out += (offset * faded(t, start, end, ramp_s))[:, None]
    return out


def pressure_drift(t: np.ndarray, pressure: np.ndarray, seed, total_hpa: tuple[float, float] = (0.15, 0.3)) -> np.ndarray:
    """Weather and the building's air handling: the pressure drifts linearly by ``total_hpa``
    (uniform, either sign; 1.3-2.5 m of apparent height) across the walk."""
    rng = np.random.default_rng(seed)
    t = np.asarray(t, float)
    total = rng.choice((-1.0, 1.0)) * rng.uniform(*total_hpa)
    share = (t - t[0]) / max(float(t[-1] - t[0]), 1e-9)
    return np.array(pressure, float, copy=True).reshape(len(t), -1) + (total * share)[:, None]


def cheap_barometer(t: np.ndarray, pressure: np.ndarray, seed, rate_hz: float = 1.0,
                    noise_hpa: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A cheaper barometer: ``rate_hz`` readings with white noise of ``noise_hpa`` rms (0.4 m)."""
    tt, v = resample(t, np.asarray(pressure, float).reshape(len(t), -1), rate_hz)
    return tt, v + np.random.default_rng(seed).normal(0.0, noise_hpa, v.shape)
