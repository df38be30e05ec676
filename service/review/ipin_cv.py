"""Leave-one-route-out cross-validation of the IPIN evaluation: what the method does on walks it was not tuned on.

Every number chosen from the IPIN walks is a candidate in :data:`TUNING_GRID`; everything else
in the settings is fixed by physics, a sensor sheet or the literature (each with its reason
where it is defined). For each route (an IPIN trial number: the repetitions of one route are
one fold, since they share the place, the phone and the walker), the candidate with the lowest
pooled live p75 on the *other* routes is chosen and scored on this one; the held-out errors of
all routes, pooled, are the cross-validated figure. The in-sample figure, next to it, is the
candidate best on all routes scored on all routes: the gap between the two is what tuning on
these walks is worth to walks it has not seen.

Cost: every candidate reruns the fusion on every walk, but the dead reckoning only once per
distinct pipeline setting (``service.review.ipin_run.PdrCache``).
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pdr.evaluation.ipin import LandmarkErrors, summary
from service.review.ipin_run import IpinRun, PdrCache, run_ipin

KINDS = ("live", "smoothed", "pdr")


@dataclass(frozen=True)
class Candidate:
    """One point of the tuning grid: settings paths (``"fusion.turn_walk"``) and their values."""

    name: str
    overrides: tuple[tuple[str, Any], ...]


def _grid() -> tuple[Candidate, ...]:
    """The numbers chosen on the IPIN walks: the step-length slope b (m·s, ``L = a + b·f``), the
    stationary sigma of the PDR heading's error (rad; how far the graph may turn the dead
    reckoning's heading without a fix) and the spacing of GNSS factors (s)."""
    out = []
    for b in (0.20, 0.22, 0.24):
        for c_deg in (10.0, 15.0):
            for gnss_s in (5.0, 10.0):
                out.append(Candidate(f"b={b:.2f} pdr-heading σ={c_deg:g}° gnss every {gnss_s:g} s", (
                    ("pipeline.profile.coefficients.b", b),
                    ("fusion.pdr_heading_sigma_rad", float(np.radians(c_deg))),
                    ("fusion.gnss_min_interval_s", gnss_s))))
    return tuple(out)


TUNING_GRID: tuple[Candidate, ...] = _grid()


def apply_overrides(settings, overrides) -> Any:
    """``settings`` (nested frozen dataclasses and dicts) with each ``"a.b.c"`` path set to its value.

    A ``None`` dataclass on the way (``TrackerSettings.fusion`` = defaults) becomes its defaults first.
    """
    for path, value in overrides:
        settings = _set(settings, path.split("."), value)
    return settings


def _set(obj, parts: list[str], value):
    if not parts:
        return value
    head, rest = parts[0], parts[1:]
    if isinstance(obj, dict):
        if head not in obj:
            raise KeyError(f"no setting {head!r} (have {sorted(obj)})")
        return {**obj, head: _set(obj[head], rest, value)}
    if not dataclasses.is_dataclass(obj) or head not in {f.name for f in dataclasses.fields(obj)}:
        raise KeyError(f"no setting {head!r} in {type(obj).__name__}")
    child = getattr(obj, head)
    if child is None and rest:
        from service.fusion import FusionSettings

        child = {"fusion": FusionSettings}[head]()
    return dataclasses.replace(obj, **{head: _set(child, rest, value)})


def route_of(source: str) -> str:
    """The route of an IPIN walk: its trial number (``...TrainingTrial24_repetition03...`` -> ``"24"``);
    a file without one is a route of its own."""
    m = re.search(r"Trial(\d+)", str(source))
    return m.group(1) if m else str(source)


@dataclass
class CvResult:
    fix_every: int
    grid: tuple[Candidate, ...]
    runs: dict[str, list[IpinRun]]  # candidate name -> runs in walk order
    routes: list[str]  # per walk
    chosen: dict[str, str] = field(default_factory=dict)  # route -> candidate chosen on the others
    in_sample: str = ""  # candidate best on all routes

    def errors(self, candidate: str, kind: str, walks=None) -> list[LandmarkErrors]:
        runs = self.runs[candidate]
        idx = range(len(runs)) if walks is None else walks
        return [e for e in (runs[i].errors(kind) for i in idx) if e is not None]

    def held_out(self, kind: str) -> dict[str, list[LandmarkErrors]]:
        """Per route, its walks' errors under the candidate chosen without it."""
        out = {}
        for route, cand in self.chosen.items():
            walks = [i for i, r in enumerate(self.routes) if r == route]
            out[route] = self.errors(cand, kind, walks)
        return out

    def walk_table(self) -> list[dict]:
        """Per walk, held out: live, smoothed and dead-reckoning p75 (the acceptance table)."""
        rows = []
        for i, route in enumerate(self.routes):
            run = self.runs[self.chosen[route]][i]
            row = {"file": run.source, "route": route, "setting": self.chosen[route]}
            for kind in KINDS:
                e = run.errors(kind)
                row[f"{kind}_p75_m"] = None if e is None else summary([e])["p75_m"]
            row["live_minus_pdr_m"] = (None if row["live_p75_m"] is None or row["pdr_p75_m"] is None
                                       else row["live_p75_m"] - row["pdr_p75_m"])
            rows.append(row)
        return rows


def _p75(errors: list[LandmarkErrors]) -> float:
    v = summary(errors)["p75_m"]
    return np.inf if v is None else v


def cross_validate(recordings, incident, fix_every: int, use_gnss: bool, base_settings,
                   grid: tuple[Candidate, ...] = TUNING_GRID, cache: PdrCache | None = None,
                   progress=lambda items, what: items, use_ble: bool = False) -> CvResult:
    """Run every candidate on every walk, then choose per held-out route (module docstring)."""
    cache = cache if cache is not None else PdrCache()
    routes = [route_of(r.source) for r in recordings]
    runs: dict[str, list[IpinRun]] = {}
    for cand in progress(grid, "cross-validation grid"):
        settings = apply_overrides(base_settings, cand.overrides)
        runs[cand.name] = [run_ipin(rec, incident, fix_every, use_gnss, settings, pdr_cache=cache, use_ble=use_ble)
                           for rec in recordings]
    res = CvResult(fix_every, grid, runs, routes)
    names = [c.name for c in grid]
    for route in dict.fromkeys(routes):
        train = [i for i, r in enumerate(routes) if r != route]
        scores = [_p75(res.errors(n, "live", train)) if train else 0.0 for n in names]
        res.chosen[route] = names[int(np.argmin(scores))]  # ties: the first (grid order)
    res.in_sample = names[int(np.argmin([_p75(res.errors(n, "live")) for n in names]))]
    return res


def report(res: CvResult, default_name: str | None) -> dict:
    """The JSON block of ``eval ipin --cv``: pooled and per-route figures, held out and in sample."""
    pooled = {k: summary([e for es in res.held_out(k).values() for e in es]) for k in KINDS}
    in_sample = {k: summary(res.errors(res.in_sample, k)) for k in KINDS}
    routes = []
    for route, cand in res.chosen.items():
        walks = [i for i, r in enumerate(res.routes) if r == route]
        row = {"route": route, "walks": len(walks), "setting": cand}
        for k in KINDS:
            row[k] = summary(res.errors(cand, k, walks))
            row[f"{k}_in_sample"] = summary(res.errors(res.in_sample, k, walks))
        routes.append(row)
    out = {
        "pooled": pooled,
        "in_sample": {"setting": res.in_sample, **in_sample},
        "routes": routes,
        "walks": res.walk_table(),
        "grid": [{"name": c.name, "overrides": dict(c.overrides),
                  "live_p75_m_all_routes": summary(res.errors(c.name, "live"))["p75_m"]} for c in res.grid],
    }
    if default_name is not None:
        out["defaults"] = {"setting": default_name, **{k: summary(res.errors(default_name, k)) for k in KINDS}}
    return out


def default_candidate(base_settings, grid: tuple[Candidate, ...] = TUNING_GRID) -> str | None:
    """The grid point equal to the shipped defaults (None when the defaults are not on the grid)."""
    for cand in grid:
        if _with_defaults(apply_overrides(base_settings, cand.overrides)) == _with_defaults(base_settings):
            return cand.name
    return None


def _with_defaults(settings):
    if getattr(settings, "fusion", 0) is None:
        from service.fusion import FusionSettings

        return dataclasses.replace(settings, fusion=FusionSettings())
    return settings



def _ble_grid() -> tuple[Candidate, ...]:
    """The numbers of the beacon model chosen on the IPIN walks (``eval ipin --ble --cv --cv-grid
    ble``), at the shipped PDR and fusion settings (their own choice is ``--cv-grid pdr``): the path-loss
    exponent n, the weakest reading used (dBm; the far field is mostly multipath) and the
    shadowing sigma (dB) and the kernel (Cauchy redescends: a wild reading loses its pull, but so
    does a true large correction; Huber keeps a bounded pull). Six points: the survey check's fit
    (n 1.7, every reading, 7 dB) and steeper, near-field-only models, with either kernel."""
    points = ((1.7, -95.0, 7.0, "cauchy"), (2.2, -82.0, 7.0, "cauchy"), (2.2, -75.0, 7.0, "cauchy"),
              (2.5, -75.0, 5.0, "cauchy"), (2.2, -75.0, 7.0, "huber"), (2.5, -75.0, 5.0, "huber"))
    return tuple(Candidate(f"ble n={n:g} rssi≥{lo:g} dBm σ={sd:g} dB {kernel}", (
        ("fusion.ble.path_loss_exponent", n), ("fusion.ble.min_rssi_dbm", lo), ("fusion.ble.sigma_db", sd),
        ("fusion.ble.kernel", kernel)))
        for n, lo, sd, kernel in points)


BLE_GRID: tuple[Candidate, ...] = _ble_grid()
