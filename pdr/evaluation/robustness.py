"""The robustness suite: named perturbations of a whole recording, and the verdict on them.

``firetrack eval ipin FILES --perturb NAME[,NAME...]`` (or ``--perturb all``) runs every walk
once as logged and once per perturbation, all through the normal evaluation path. A
perturbation changes only the IMU, magnetometer and pressure series of the loaded
:class:`~pdr.recording.Recording` (values and timestamps); landmarks and GNSS keep their times.
Each walk gets its own random draw, seeded by the suite's seed, the walk's file name and the
perturbation's name, so a run is reproducible (:func:`walk_seed`).

The verdict (issue 27): a perturbation passes when the pooled p75 is at most 25 % worse than
unperturbed and no walk is *broken*: a walk's p75 above 2 x its unperturbed p75 + 2 m.
"""
from __future__ import annotations

import dataclasses
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdr.evaluation import perturb as P
from pdr.recording import Recording, Series

DEFAULT_SEED = 27
POOLED_TOLERANCE = 0.25  # pooled p75 may be this much worse (share)
BROKEN_FACTOR, BROKEN_MARGIN_M = 2.0, 2.0  # a walk is broken above 2 x its p75 + 2 m

X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
DEG = math.pi / 180.0


def walk_seed(seed: int, source: str, name: str) -> list[int]:
    """The random seed of one walk under one perturbation: stable across runs and machines."""
    return [int(seed), zlib.crc32(Path(source).name.encode()), zlib.crc32(name.encode())]


def _series(s: Series | None, t: np.ndarray, v: np.ndarray) -> Series | None:
    return None if s is None else Series(np.asarray(t, float), np.asarray(v, float).reshape(len(t), -1))


def _t0_t1(rec: Recording) -> tuple[float, float]:
    return float(rec.acc.t[0]), float(rec.acc.t[-1])


def _each(rec: Recording, fn, names=("acc", "gyr", "mag", "pressure")) -> Recording:
    """``fn(name, series) -> (t, values)`` applied to each present series."""
    changes = {}
    for name in names:
        s = getattr(rec, name)
        if s is not None and len(s):
            changes[name] = _series(s, *fn(name, s))
    return dataclasses.replace(rec, **changes)


# --------------------------------------------------------------------------------------------
# The perturbations, as whole-recording functions (rec, seed) -> rec
# --------------------------------------------------------------------------------------------
def resampled(rate_hz: float):
    def apply(rec: Recording, seed) -> Recording:
        grid = P.uniform_grid(*_t0_t1(rec), rate_hz)  # accelerometer and gyroscope on one clock, as one chip
        return _each(rec, lambda name, s: P.resample(s.t, s.values, rate_hz, grid),
                     names=("acc", "gyr", "mag"))
    return apply


def browser(rate_hz: float = 60.0, quantized: bool = False):
    def apply(rec: Recording, seed) -> Recording:
        # acc and gyro are read together at each tick of the page's uneven timer (one devicemotion event)
        ticks = P.timer_ticks(*_t0_t1(rec), rate_hz, [*seed, 1])
        steps = {"acc": 0.1, "gyr": 0.1 * DEG, "mag": None}

        def one(name, s):
            if name == "mag":
                t, v = P.resample(s.t, s.values, rate_hz)
                return P.browser_stamps(t, [*seed, 2]), v
            _, v = P.resample(s.t, s.values, rate_hz, ticks)
            return ticks, (P.quantize(v, steps[name]) if quantized else v)
        return _each(rec, one, names=("acc", "gyr", "mag"))
    return apply


def quantized_readings(rec: Recording, seed) -> Recording:
    return _each(rec, lambda name, s: (s.t, P.quantize(s.values, {"acc": 0.1, "gyr": 0.1 * DEG}[name])), names=("acc", "gyr"))


def turned_in_hand(axis, angle_deg: float = 90.0, at: float | None = 0.5, back_at: float | None = None,
                   turn_s: float = 0.5):
    """The phone turned by ``angle_deg`` about its ``axis`` at share ``at`` of the walk (and turned
    back at share ``back_at``); ``at=None``: held so for the whole recording."""
    def apply(rec: Recording, seed) -> Recording:
        t0, t1 = _t0_t1(rec)
        start = -math.inf if at is None else t0 + at * (t1 - t0)
        back = None if back_at is None else t0 + back_at * (t1 - t0)

        def one(name, s):
            th, dth = P.grip_angle(s.t, start, angle_deg * DEG, turn_s, back)
            if name == "gyr":
                return s.t, P.gyro_in_turned_phone(s.values, axis, th, dth)
            return s.t, P.in_turned_phone(s.values, axis, th)
        return _each(rec, one, names=("acc", "gyr", "mag"))
    return apply


def gyro_bias(deg_s: float = 0.5):
    def apply(rec: Recording, seed) -> Recording:
        b = deg_s * DEG * P.random_direction(seed)
        return _each(rec, lambda name, s: (s.t, P.with_bias(s.values, b)), names=("gyr",))
    return apply


def gyro_scale(factor: float):
    def apply(rec: Recording, seed) -> Recording:
        return _each(rec, lambda name, s: (s.t, P.with_scale(s.values, [factor] * 3)), names=("gyr",))
    return apply


def acc_bias(m_s2: float = 0.15):
    def apply(rec: Recording, seed) -> Recording:
        b = m_s2 * P.random_direction(seed)
        return _each(rec, lambda name, s: (s.t, P.with_bias(s.values, b)), names=("acc",))
    return apply


def mag_near_steel(rec: Recording, seed) -> Recording:
    stretches = P.steel_stretches(*_t0_t1(rec), seed)
    return _each(rec, lambda name, s: (s.t, P.near_steel(s.t, s.values, stretches)), names=("mag",))


def _pressure(fn):
    """A barometer perturbation ``fn(t, values, seed) -> values`` or ``-> (t, values)``."""
    def apply(rec: Recording, seed) -> Recording:
        def one(name, s):
            out = fn(s.t, s.values, seed)
            return out if isinstance(out, tuple) else (s.t, out)
        return _each(rec, one, names=("pressure",))
    return apply


def _stretches(draw):
    """Pressure offsets over stretches drawn for the walk (``draw(t0, t1, seed)``)."""
    def apply(rec: Recording, seed) -> Recording:
        stretches = draw(*_t0_t1(rec), seed)
        return _pressure(lambda t, v, _: P.pressure_offsets(t, v, stretches))(rec, seed)
    return apply


def dropped_samples(fraction: float = 0.1):
    def apply(rec: Recording, seed) -> Recording:
        def one(name, s):
            keep = P.dropped(len(s), fraction, [*seed, zlib.crc32(name.encode())])
            keep[0] = keep[-1] = True  # the walk keeps its span
            return s.t[keep], s.values[keep]
        return _each(rec, one)
    return apply


def gaps(rec: Recording, seed) -> Recording:
    windows = P.gap_windows(*_t0_t1(rec), seed)

    def one(name, s):
        keep = P.outside_windows(s.t, windows)
        return s.t[keep], s.values[keep]
    return _each(rec, one)


def together(*parts):
    """Several perturbations at once, in order, each with its own draw from the walk's seed."""
    def apply(rec: Recording, seed) -> Recording:
        for i, part in enumerate(parts):
            rec = part(rec, [*seed, i])
        return rec
    return apply


@dataclass(frozen=True)
class Perturbation:
    name: str
    what: str  # the physical situation, one line
    apply: Callable[[Recording, list[int]], Recording]


PERTURBATIONS: dict[str, Perturbation] = {p.name: p for p in [
    Perturbation("rate50", "resampled to 50 Hz (anti-aliased)", resampled(50.0)),
    Perturbation("rate60", "resampled to 60 Hz (anti-aliased)", resampled(60.0)),
    Perturbation("rate100", "resampled to 100 Hz", resampled(100.0)),
    Perturbation("rate200", "resampled to 200 Hz", resampled(200.0)),
    Perturbation("browser60", "60 Hz read at a browser timer's uneven ticks (intervals sd ~4-6 ms; 0.2/s held back "
                 "20-100 ms)", browser(60.0)),
    Perturbation("browser60q", "browser60 and readings quantised to 0.1 m/s², 0.1 °/s", browser(60.0, quantized=True)),
    Perturbation("grip_x", "mid-walk, phone turned 90° about its x axis (screen tilted up/down) in 0.5 s",
                 turned_in_hand(X)),
    Perturbation("grip_y", "mid-walk, phone turned 90° about its long axis in 0.5 s", turned_in_hand(Y)),
    Perturbation("grip_z", "mid-walk, phone turned 90° about the screen normal (portrait to landscape) in 0.5 s",
                 turned_in_hand(Z)),
    Perturbation("hold_z", "landscape (90° about the screen normal) from 40 % to 60 % of the walk, then back",
                 turned_in_hand(Z, at=0.4, back_at=0.6)),
    Perturbation("hold_x", "tilted 60° about x (screen raised to the eyes) from 40 % to 60 % of the walk, then back",
                 turned_in_hand(X, angle_deg=60.0, at=0.4, back_at=0.6)),
    Perturbation("steep25", "held 25° steeper about x for the whole walk (long axis near vertical; the unseen route 25's "
                 "failure as far as it can be reproduced, docs/heading.md)", turned_in_hand(X, angle_deg=25.0, at=None, turn_s=0.0)),
    Perturbation("flat30", "held 30° flatter about x for the whole walk (screen facing up, read like a map)",
                 turned_in_hand(X, angle_deg=-30.0, at=None, turn_s=0.0)),
    Perturbation("gyro_bias", "gyroscope bias 0.5 °/s in a random direction", gyro_bias(0.5)),
    Perturbation("gyro_scale+2", "gyroscope scale +2 % on every axis", gyro_scale(1.02)),
    Perturbation("gyro_scale-2", "gyroscope scale -2 % on every axis", gyro_scale(0.98)),
    Perturbation("acc_bias", "accelerometer bias 0.15 m/s² in a random direction", acc_bias(0.15)),
    Perturbation("mag_steel", "magnetometer near steel: +20-50 µT for 4-15 s stretches, 2 a minute", mag_near_steel),
    Perturbation("phone50_steep", "another phone and hand: 50 Hz, held 25° steeper (route 25's phone as far as known)",
                 together(resampled(50.0), turned_in_hand(X, angle_deg=25.0, at=None, turn_s=0.0))),
    Perturbation("phone50_worn", "phone50_steep with an uncalibrated gyro (0.5 °/s) and accelerometer (0.15 m/s²)",
                 together(resampled(50.0), turned_in_hand(X, angle_deg=25.0, at=None, turn_s=0.0), gyro_bias(0.5),
                          acc_bias(0.15))),
    Perturbation("phone50_steel", "phone50_worn walking past steel (mag_steel)",
                 together(resampled(50.0), turned_in_hand(X, angle_deg=25.0, at=None, turn_s=0.0), gyro_bias(0.5),
                          acc_bias(0.15), mag_near_steel)),
    Perturbation("ppv_fan", "a ventilation fan (or a stairwell's pressurisation) starts: +20-50 Pa from 20-60 % of the "
                 "walk on (1.7-4.2 m lower to the barometer, no step taken)",
                 _stretches(lambda t0, t1, seed: [P.fan_started(t0, t1, seed)])),
    Perturbation("baro_doors", "doors of pressurised stairwells and lobbies: ±10-40 Pa for 3-20 s, once a minute",
                 _stretches(P.door_pulses)),
    Perturbation("baro_drift", "weather and air handling: the pressure drifts by ±0.15-0.3 hPa across the walk",
                 _pressure(P.pressure_drift)),
    Perturbation("baro_cheap", "a cheaper barometer: 1 Hz, 0.05 hPa rms noise", _pressure(P.cheap_barometer)),
    Perturbation("drops", "10 % of the samples of each sensor lost at random", dropped_samples(0.1)),
    Perturbation("gaps", "one gap of 0.2-2 s (nothing logged) in every 30 s", gaps),
]}


def names_from(spec: str) -> list[str]:
    """``"all"`` or ``"a,b"`` -> the perturbations' names; a clear error naming an unknown one."""
    names = list(PERTURBATIONS) if spec.strip() == "all" else [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in PERTURBATIONS]
    if unknown or not names:
        raise ValueError(f"--perturb: unknown {', '.join(unknown) or 'empty list'}; "
                         f"known: all, {', '.join(PERTURBATIONS)}")
    return names


def seeds_from(spec: str | int) -> list[int]:
    """``"27"`` or ``"27,1,2"`` -> ``[27, 1, 2]``; a clear error naming what is not a seed."""
    parts = [p.strip() for p in str(spec).split(",") if p.strip()]
    bad = [p for p in parts if not p.lstrip("-").isdigit()]
    if bad or not parts:
        raise ValueError(f"--seed: {', '.join(repr(b[:20]) for b in bad[:3]) or 'empty list'} is not a whole number; "
                         f"give one seed or several, e.g. 27 or 27,1,2")
    return list(dict.fromkeys(int(p) for p in parts))


def perturbed(rec: Recording, name: str, seed: int = DEFAULT_SEED) -> Recording:
    """``rec`` under the named perturbation; the walk's own seed from :func:`walk_seed`."""
    out = PERTURBATIONS[name].apply(rec, walk_seed(seed, rec.source, name))
    return dataclasses.replace(out, meta={**rec.meta, "perturbation": name}, warnings=list(rec.warnings))


# --------------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------------
def verdict(base_pooled: float, base_walks: dict[str, float], pooled: float, walks: dict[str, float]) -> dict:
    """Issue 27's criteria for one perturbation against the unperturbed run.

    ``*_walks`` map a walk's name to its p75 (m). Returns the pooled change (share), the worst
    walk (the highest p75), the broken walks (p75 > 2 x unperturbed + 2 m) and ``passes``.
    """
    change = pooled / base_pooled - 1.0 if base_pooled > 0 else math.inf
    broken = sorted((w for w, p in walks.items() if p > BROKEN_FACTOR * base_walks[w] + BROKEN_MARGIN_M),
                    key=lambda w: -walks[w])
    worst = max(walks, key=walks.get) if walks else None
    return {
        "pooled_change": change,
        "worst_walk": worst,
        "worst_p75_m": None if worst is None else walks[worst],
        "worst_unperturbed_p75_m": None if worst is None else base_walks[worst],
        "broken": [{"walk": w, "p75_m": walks[w], "unperturbed_p75_m": base_walks[w]} for w in broken],
        "passes": change <= POOLED_TOLERANCE and not broken,
    }
