"""The survey check: a list of beacon positions confronted with walks that have ground truth.

A survey (``BLE_Locations.csv``: id, lat, lon, floor) says where each beacon is, but not always
which one: the IPIN museum's lists six positions and the logs hear six MAC addresses, and the
obvious pairing (the n-th MAC with the n-th position) is wrong for some. Walks with landmarks
say where the walker was at every moment (the landmark positions interpolated in time,
:func:`walker_positions`); where a beacon is heard strongest is then where it is, to a few
metres. Per beacon (:func:`check_survey`):

* **heard strongest**: the centroid and the most common floor of its strongest readings (the
  top ``top_share`` of them, at least ``min_top``), and its strongest RSSI;
* **matching**: MACs and survey entries paired by the assignment that minimises the summed
  cost ``distance(heard strongest, entry) + 15 m·|floor difference|`` (the IPIN metric's floor
  penalty; Hungarian method, :func:`scipy.optimize.linear_sum_assignment`);
* **agreement** of the listed identity (the obvious pairing), of the matched entry's position
  (within ``position_tolerance_m``) and of its floor;
* **path loss**: ``P₀`` (RSSI at 1 m) fitted on same-floor readings at the matched position,
  with the path-loss exponent given, and the scatter (dB) around it: the ``tx_power_dbm`` to
  put in the incident config.

Readings between two landmarks on different floors (stairs, a lift) have no floor and are left out.
"""
from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

FLOOR_PENALTY_M = 15.0  # the IPIN metric's cost of a wrong floor


@dataclass(frozen=True)
class SurveyEntry:
    name: str
    x: float  # m, ENU
    y: float
    floor: int
    lat: float
    lon: float


@dataclass
class BeaconCheck:
    beacon: str  # the id scans name it by (MAC)
    readings: int
    strongest_rssi_dbm: float
    heard_x: float  # m, where it is heard strongest (centroid of the strongest readings)
    heard_y: float
    heard_floor: int
    listed: str | None  # the survey entry of the obvious pairing
    listed_distance_m: float | None
    matched: str | None  # the survey entry the data pair it with
    matched_distance_m: float | None
    identity_agrees: bool
    position_agrees: bool
    floor_agrees: bool
    tx_power_dbm: float | None  # P0 fitted at the matched position (same-floor readings)
    scatter_db: float | None
    same_floor_readings: int
    closest_approach_m: float | None = None  # nearest any walk came to the matched entry on its floor

    def verdict(self) -> str:
        if self.matched is None:
            return "no survey entry left for it"
        parts = ["identity ok" if self.identity_agrees else f"listed as {self.listed}, is {self.matched}",
                 "position ok" if self.position_agrees else f"heard strongest {self.matched_distance_m:.1f} m from {self.matched}",
                 "floor ok" if self.floor_agrees else f"heard strongest on floor {self.heard_floor}"]
        if not (self.position_agrees and self.floor_agrees) and self.closest_approach_m is not None:
            parts.append(f"walks on its floor pass no nearer than {self.closest_approach_m:.1f} m")
        elif not (self.position_agrees and self.floor_agrees):
            parts.append("no walk on its floor")
        return "; ".join(parts)


def read_survey(path: str | Path, incident) -> list[SurveyEntry]:
    """``bleID, Lat, Lon, floor`` rows (the IPIN supplementary file's header) -> entries in ENU."""
    path = Path(path)
    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8-sig").splitlines()))
    except OSError as e:
        raise ValueError(f"{path}: cannot read: {e}") from None
    out = []
    for i, row in enumerate(rows, start=2):
        low = {k.strip().lower(): (v or "").strip().strip('"') for k, v in row.items() if k}
        try:
            name, lat, lon, floor = low["bleid"] if "bleid" in low else low["id"], float(low["lat"]), float(low["lon"]), int(low["floor"])
        except (KeyError, ValueError) as e:
            raise ValueError(f"{path}: line {i}: needs bleID (or id), Lat, Lon, floor: {e}") from None
        x, y, _ = incident.to_enu(lat, lon)
        out.append(SurveyEntry(name, float(x), float(y), floor, lat, lon))
    if not out:
        raise ValueError(f"{path}: no survey rows")
    return out


def walker_positions(rec, incident) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, floor, usable) at each beacon reading of ``rec``: the landmarks interpolated in
    time; ``usable`` False outside the landmarks' span and between landmarks on two floors."""
    lm, b = rec.landmarks, rec.ble
    lx, ly, _ = incident.to_enu(lm.lat, lm.lon)
    lx, ly = np.atleast_1d(lx).astype(float), np.atleast_1d(ly).astype(float)
    x, y = np.interp(b.t, lm.t, lx), np.interp(b.t, lm.t, ly)
    k = np.clip(np.searchsorted(lm.t, b.t, side="right"), 1, len(lm) - 1)
    before, after = lm.floor[k - 1], lm.floor[k]
    usable = (b.t >= lm.t[0]) & (b.t <= lm.t[-1]) & (before == after) if len(lm) > 1 else np.zeros(len(b), bool)
    return x, y, before.astype(int), usable


def _pool(recordings, incident) -> dict[str, dict[str, np.ndarray]]:
    cols: dict[str, list] = {}
    for rec in recordings:
        if rec.ble is None or rec.landmarks is None or len(rec.landmarks) < 2:
            continue
        x, y, floor, ok = walker_positions(rec, incident)
        for name in ("x", "y", "floor", "rssi", "beacon"):
            v = {"x": x, "y": y, "floor": floor, "rssi": rec.ble.rssi, "beacon": rec.ble.beacon}[name]
            cols.setdefault(name, []).append(np.asarray(v)[ok])
    if not cols:
        return {}
    pooled = {k: np.concatenate(v) for k, v in cols.items()}
    return {b: {k: v[pooled["beacon"] == b] for k, v in pooled.items() if k != "beacon"}
            for b in sorted(set(pooled["beacon"].tolist()))}


def check_survey(recordings, survey: list[SurveyEntry], incident, path_loss_exponent: float = 1.7,
                 position_tolerance_m: float = 5.0, top_share: float = 0.05, min_top: int = 10,
                 near_m: float = 1.0) -> list[BeaconCheck]:
    """Every beacon heard in ``recordings`` (with landmarks) against ``survey``; module docstring."""
    from scipy.optimize import linear_sum_assignment

    heard = _pool(recordings, incident)
    names = list(heard)
    spots = {}
    for b, d in heard.items():
        n_top = min(len(d["rssi"]), max(min_top, int(math.ceil(top_share * len(d["rssi"])))))
        top = np.argsort(-d["rssi"], kind="stable")[:n_top]
        floors, counts = np.unique(d["floor"][top], return_counts=True)
        spots[b] = (float(np.mean(d["x"][top])), float(np.mean(d["y"][top])), int(floors[np.argmax(counts)]))
    cost = np.array([[math.hypot(spots[b][0] - e.x, spots[b][1] - e.y) + FLOOR_PENALTY_M * abs(spots[b][2] - e.floor)
                      for e in survey] for b in names]).reshape(len(names), len(survey))
    rows, cols = linear_sum_assignment(cost) if cost.size else ((), ())
    matched = {names[r]: survey[c] for r, c in zip(rows, cols)}
    listed = dict(zip(names, survey))  # the obvious pairing: sorted ids with the survey's order
    out = []
    for b in names:
        d, (hx, hy, hf) = heard[b], spots[b]
        m, lst = matched.get(b), listed.get(b)
        p0 = scatter = closest = None
        same = 0
        if m is not None:
            sel = d["floor"] == m.floor
            same = int(sel.sum())
            if same:
                closest = float(np.min(np.hypot(d["x"][sel] - m.x, d["y"][sel] - m.y)))
            if same >= 3:
                r = np.sqrt((d["x"][sel] - m.x) ** 2 + (d["y"][sel] - m.y) ** 2 + near_m ** 2)
                at_1m = d["rssi"][sel] + 10.0 * path_loss_exponent * np.log10(r)
                p0 = float(np.median(at_1m))
                scatter = float(1.4826 * np.median(np.abs(at_1m - p0)))
        out.append(BeaconCheck(
            beacon=b, readings=int(d["rssi"].size), strongest_rssi_dbm=float(d["rssi"].max()),
            heard_x=hx, heard_y=hy, heard_floor=hf,
            listed=None if lst is None else lst.name,
            listed_distance_m=None if lst is None else math.hypot(hx - lst.x, hy - lst.y),
            matched=None if m is None else m.name,
            matched_distance_m=None if m is None else math.hypot(hx - m.x, hy - m.y),
            identity_agrees=m is not None and lst is not None and m.name == lst.name,
            position_agrees=m is not None and math.hypot(hx - m.x, hy - m.y) <= position_tolerance_m,
            floor_agrees=m is not None and m.floor == hf,
            tx_power_dbm=p0, scatter_db=scatter, same_floor_readings=same, closest_approach_m=closest))
    return out


def config_beacons(checks: list[BeaconCheck], survey: list[SurveyEntry], with_tx_power: bool = True) -> list[dict]:
    """The incident config's ``beacons`` for the matched pairing (survey positions and floors)."""
    by_name = {e.name: e for e in survey}
    out = []
    for c in checks:
        if c.matched is None:
            continue
        e = by_name[c.matched]
        item = {"id": c.beacon, "name": e.name, "lat": e.lat, "lon": e.lon, "x": round(e.x, 3), "y": round(e.y, 3),
                "floor": e.floor}
        if with_tx_power and c.tx_power_dbm is not None:
            item["tx_power_dbm"] = round(c.tx_power_dbm, 1)
        item["note"] = f"survey check: {c.verdict()}"
        out.append(item)
    return out


def as_dicts(checks: list[BeaconCheck]) -> list[dict]:
    return [{**asdict(c), "verdict": c.verdict()} for c in checks]
