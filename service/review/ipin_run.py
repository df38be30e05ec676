"""Drive a :class:`service.core.tracker.ResponderTracker` over one IPIN log, as the service would live.

The log's samples go through in frames (as a wearable would send them), its landmarks are
checkpoint fixes at their own time (landmark 0 always: the initial position; with
``fix_every=K`` also K, 2K, …), its GNSS fixes go to the fusion unless ``use_gnss`` is off.
Everything is in the incident's local ENU frame (origin from the incident config).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d

from pdr.evaluation.ipin import LandmarkErrors, fix_indices, score_track
from pdr.floors import FloorElevations
from pdr.pipeline import frames_of
from pdr.recording import Recording
from service.core.tracker import CheckpointFix, ResponderTracker, TrackerSettings

LANDMARK_SIGMA_M = 0.3  # surveyed landmark, walker standing on it


@dataclass
class IpinRun:
    source: str
    lm_t: np.ndarray
    lm_x: np.ndarray
    lm_y: np.ndarray
    lm_floor: np.ndarray
    fixes: np.ndarray  # landmark indices handed to the tracker
    live: dict[str, np.ndarray]  # t, x, y, floor of every published pose
    smoothed: dict[str, np.ndarray] | None
    pdr: dict[str, np.ndarray]  # dead reckoning alone (with the same fixes as resets)
    gnss_used: int
    gnss_rejected: int

    def scored(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.lm_t.size), self.fixes)

    def errors(self, which: str = "live") -> LandmarkErrors | None:
        tr = {"live": self.live, "smoothed": self.smoothed, "pdr": self.pdr}[which]
        if tr is None or tr["t"].size == 0:
            return None
        return score_track(self.lm_t, self.lm_x, self.lm_y, self.lm_floor, tr["t"], tr["x"], tr["y"], tr["floor"], self.scored())


def run_ipin(rec: Recording, origin: tuple[float, float, float], floors: FloorElevations, fix_every: int = 0,
             use_gnss: bool = True, settings: TrackerSettings | None = None, per_frame: int = 50) -> IpinRun:
    if rec.landmarks is None or len(rec.landmarks) == 0:
        raise ValueError(f"{rec.source}: no landmarks (POSI lines) to start from and score against")
    lm = rec.landmarks
    lat0, lon0, alt0 = origin
    lx, ly, _ = pymap3d.geodetic2enu(lm.lat, lm.lon, np.zeros(len(lm)), lat0, lon0, alt0)
    fixes = fix_indices(len(lm), fix_every)
    settings = settings or TrackerSettings()
    tracker = ResponderTracker(rec.source, floors, int(lm.floor[0]), settings)
    for j in fixes:
        tracker.on_fix(CheckpointFix(float(lm.t[j]), float(lx[j]), float(ly[j]), int(lm.floor[j]), LANDMARK_SIGMA_M))
    gnss_n = 0
    if use_gnss and rec.gnss is not None and len(rec.gnss) and settings.engine == "fusion":
        from service.fusion import GnssFix

        gx, gy, _ = pymap3d.geodetic2enu(rec.gnss.lat, rec.gnss.lon, np.zeros(len(rec.gnss)), lat0, lon0, alt0)
        for k in range(len(rec.gnss)):
            if rec.gnss.t[k] >= lm.t[0]:
                tracker.on_fix(GnssFix(t=float(rec.gnss.t[k]), x=float(gx[k]), y=float(gy[k]),
                                       accuracy=float(rec.gnss.accuracy_m[k])))
                gnss_n += 1
    imu = rec.imu_samples()
    pt = rec.pressure.t if rec.pressure is not None else None
    pv = rec.pressure.values[:, 0] if rec.pressure is not None else None
    poses = []
    for frame in frames_of(imu.t, imu.acc, imu.gyr, imu.mag, pt, pv, per_frame=per_frame):
        poses += [p for p in tracker.on_frame(frame) if hasattr(p, "x")]
    poses += [p for p in tracker.finish() if hasattr(p, "x")]
    live = _columns([(p.t, p.x, p.y, p.floor) for p in poses])
    sm = tracker.smoothed_track()
    smoothed = None if sm is None else {k: np.asarray(sm[k]) for k in ("t", "x", "y", "floor")}
    return IpinRun(rec.source, lm.t, np.asarray(lx), np.asarray(ly), lm.floor.astype(int), fixes, live, smoothed,
                   _columns(tracker.pdr_track), gnss_n, tracker.fixes_rejected)


def _columns(rows) -> dict[str, np.ndarray]:
    a = np.array(rows, float).reshape(-1, 4)
    # a pose republished after a fix keeps its step time: the later publication wins
    return {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "floor": a[:, 3].astype(int)}
