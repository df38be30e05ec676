"""Floors in buildings the configuration gets wrong: simulated walks through simulated buildings.

A building has ``floors`` storeys (0 at the entrance, up to ``floors - 1``) a real ``spacing_m``
apart; the incident configuration says ``spacing_m / ratio`` (``ratio`` = real / configured:
0.6 and 1.4 are a configuration 40 % off either way). A simulated responder
(:mod:`pdr.simulation`: phone IMU and a barometer with noise and weather drift) walks a
scenario of floor visits: on each floor a loop and a pause (a *dwell*), between floors stairs
(one straight flight, one step per 0.17 m riser, several floors at once when the scenario skips
some). The pipeline (:class:`pdr.pipeline.PdrPipeline`) tracks it from the entrance floor; a
scenario may also give a checkpoint that names the floor on arrival somewhere.

Scored: the floor the pipeline reports at every barometer sample of a dwell from
``settle_s`` after arrival on it (the tracker needs a few seconds of steady height to recognise
a level), and whether the sequence of floors of the visits is the true one (stairs up and down
counted right).

Scenarios (floors ``0 .. n-1``):

* ``floor_by_floor``: up one floor at a time to the top, then down to 0 in one go (passing every
  floor), up to the top in one go, down to 1, down to 0;
* ``between_known``: from 0 straight up to 2 passing 1, where a checkpoint names floor 2; then
  down to 1 — a floor never seen, between two known ones — then to 0.
* ``named_on_arrival``: from the top floor down one floor at a time to 0 and back up (a walk
  through 0, -1 and -2 of a basement, seen from below), a checkpoint naming every floor
  arrived at, pressed ``fix_offset_s`` from the arrival on the level (negative: on the last
  stairs, as an IPIN landmark at the stairs' end) and reaching the tracker ``fix_delay_s``
  later (a radio's latency: the barometer may have decided the change in between).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from pdr.floors import FloorElevations
from pdr.pipeline import PdrPipeline, PipelineSettings, frames_of
from pdr.simulation import Route, WalkerSettings, simulate_walk

RISER_M = 0.17  # m per stair step of the simulated flights
TREAD_M = 0.28  # m, horizontal run per stair step
LOOP = np.array([(0.0, 0.0), (12.0, 0.0), (12.0, 6.0), (0.0, 6.0), (0.0, 0.5)])  # m, the walk on each floor
DWELL_PAUSE_S = 8.0  # s standing at the end of each floor's loop
SETTLE_S = 25.0  # s after arriving on a floor from which its floor is scored
STAIRS_X = -2.0  # m, where the flights start (west of the loop)


@dataclasses.dataclass(frozen=True)
class Building:
    floors: int
    spacing_m: float  # real spacing between storeys
    ratio: float  # real / configured spacing

    @property
    def configured(self) -> FloorElevations:
        return FloorElevations.uniform(self.spacing_m / self.ratio, 0, self.floors - 1)


@dataclasses.dataclass(frozen=True)
class FloorScore:
    building: Building
    scenario: str
    dwell_samples: int
    dwell_correct: int
    visits_true: tuple[int, ...]
    visits_seen: tuple[int, ...]

    @property
    def accuracy(self) -> float:
        return self.dwell_correct / self.dwell_samples if self.dwell_samples else math.nan

    @property
    def trips_right(self) -> bool:
        return self.visits_true == self.visits_seen


def scenario_floors(name: str, n: int) -> tuple[list[int], dict[int, int]]:
    """(floors visited in order, {visit index: floor a checkpoint names there})."""
    if name == "floor_by_floor":
        return list(range(n)) + [0, n - 1, 1, 0], {}
    if name == "between_known":
        return [0, 2, 1, 0], {1: 2}
    if name == "named_on_arrival":
        visits = list(range(n - 1, -1, -1)) + list(range(1, n))
        return visits, {i: f for i, f in enumerate(visits) if i}
    raise ValueError(f"unknown floor scenario {name!r}; choose floor_by_floor, between_known or named_on_arrival")


def route_for(visits: list[int], spacing_m: float) -> Route:
    """Waypoints: per visit, the loop on that floor; between visits, a straight flight of stairs
    (one step per riser of ``RISER_M``, a tread of ``TREAD_M``)."""
    pts, floors, pauses = [], [], []
    y = 0.0
    for i, f in enumerate(visits):
        if i:
            steps = max(1, round(abs(f - visits[i - 1]) * spacing_m / RISER_M))
            run = steps * TREAD_M
            pts += [(STAIRS_X - run, y), (STAIRS_X - run, y + 1.5)]
            floors += [f, f]
            pauses += [0.0, 0.0]
            y += 1.5
        for k, (x, yy) in enumerate(LOOP):
            pts.append((x, yy + y))
            floors.append(f)
            pauses.append(DWELL_PAUSE_S if k == len(LOOP) - 1 else 0.0)
        pts.append((STAIRS_X, pts[-1][1]))
        floors.append(f)
        pauses.append(0.0)
        y = pts[-1][1]
    return Route(np.array(pts), np.array(floors), np.array(pauses))


def run_scenario(building: Building, scenario: str, seed: int = 0, drift_hpa_per_h: float = 0.5,
                 settings: PipelineSettings | None = None, fix_offset_s: float | None = None,
                 fix_delay_s: float = 0.0) -> FloorScore:
    """Simulate ``scenario`` in ``building`` and score the pipeline's floors (module docstring).

    A checkpoint is pressed ``fix_offset_s`` after the arrival on its floor's level (default
    :data:`FIX_AFTER_S`; ``named_on_arrival``: :data:`FIX_ON_STAIRS_S`) and handed to the
    pipeline ``fix_delay_s`` later."""
    visits, fixes = scenario_floors(scenario, building.floors)
    walker = WalkerSettings(floor_height_m=building.spacing_m, pressure_drift_hpa_per_h=drift_hpa_per_h)
    climbed = sum(abs(b - a) for a, b in zip(visits, visits[1:])) * building.spacing_m
    seconds = 60.0 + 75.0 * len(visits) + climbed / RISER_M  # the route and a margin; the walker then stands
    sim = simulate_walk(route_for(visits, building.spacing_m), walker, seconds=seconds, seed=seed)
    on_level = np.abs(sim.z - np.rint(sim.z / building.spacing_m) * building.spacing_m) < 1e-6
    stays = _runs(on_level, np.rint(sim.z / building.spacing_m).astype(int), sim.t_truth)
    pipe = PdrPipeline(settings or PipelineSettings(), building.configured, start_floor=visits[0])
    if fix_offset_s is None:
        fix_offset_s = FIX_ON_STAIRS_S if scenario == "named_on_arrival" else FIX_AFTER_S
    checkpoints = sorted((stays[_visit_stay(stays, visits, i)][0] + fix_offset_s, f) for i, f in fixes.items())
    for frame in frames_of(sim.t, sim.acc, sim.gyr, sim.mag, sim.pressure_t, sim.pressure, per_frame=100):
        pipe.update(frame)
        while checkpoints and frame.t[-1] >= checkpoints[0][0] + fix_delay_s:
            t_fix, f = checkpoints.pop(0)
            pipe.anchor_floor(f, t_fix)
    pipe.finish()
    n_ok = n_all = 0
    true, seen = [], []
    for t0, t1, f in stays:
        at = sim.pressure_t[(sim.pressure_t >= t0 + SETTLE_S) & (sim.pressure_t <= t1)]
        if at.size == 0:
            continue
        got = np.array([pipe.floor_at(float(t)) for t in at])
        n_all += got.size
        n_ok += int((got == f).sum())
        true.append(f)
        values, counts = np.unique(got, return_counts=True)
        seen.append(int(values[np.argmax(counts)]))
    return FloorScore(building, scenario, n_all, n_ok, tuple(true), tuple(seen))


FIX_AFTER_S = 10.0  # s after arriving on a floor that a checkpoint names it
FIX_ON_STAIRS_S = -3.0  # s, ``named_on_arrival``: pressed about five stairs before the level


def _runs(mask: np.ndarray, floor: np.ndarray, t: np.ndarray) -> list[tuple[float, float, int]]:
    """Maximal runs of ``mask`` on one floor: (start time, end time, floor)."""
    out = []
    start = None
    for i in range(len(t)):
        if mask[i] and (start is None or floor[i] != floor[start]):
            if start is not None:
                out.append((float(t[start]), float(t[i - 1]), int(floor[start])))
            start = i
        elif not mask[i] and start is not None:
            out.append((float(t[start]), float(t[i - 1]), int(floor[start])))
            start = None
    if start is not None:
        out.append((float(t[start]), float(t[-1]), int(floor[start])))
    return [r for r in out if r[1] - r[0] > 1.0]


def _visit_stay(stays, visits: list[int], i: int) -> int:
    """Index of the stay that is the ``i``-th visit (stays on one floor are merged runs, in order)."""
    k = -1
    prev = None
    for j, (_, _, f) in enumerate(stays):
        if f != prev:
            k += 1
            prev = f
        if k == i:
            return j
    raise ValueError(f"visit {i} of {visits} not found in the simulated walk")
