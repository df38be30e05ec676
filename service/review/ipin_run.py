"""Track one IPIN log through the incident core, as the service would live.

The log's samples go through in frames (as a wearable would send them), its landmarks are
checkpoint fixes at their own time (landmark 0 always: the initial position; with
``fix_every=K`` also K, 2K, …), its GNSS fixes go to the fusion unless ``use_gnss`` is off.
Everything is in the incident's local ENU frame (origin from the incident config).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr.evaluation.ipin import LandmarkErrors, fix_indices, score_track
from pdr.recording import Recording
from service.core.incident_core import CoreSettings
from service.core.tracker import TrackerSettings
from service.protocol.messages import recording_messages
from service.review.walk import run_walk

RESPONDER = "walk"


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


def run_ipin(rec: Recording, incident, fix_every: int = 0, use_gnss: bool = True,
             settings: TrackerSettings | None = None) -> IpinRun:
    """Track one IPIN walk through the incident core, from the messages a wearable would send:
    landmark 0 (and every ``fix_every``-th) as checkpoint fixes, the log's GNSS unless
    ``use_gnss`` is off, the IMU in frames of 1/10 s."""
    if rec.landmarks is None or len(rec.landmarks) == 0:
        raise ValueError(f"{rec.source}: no landmarks (POSI lines) to start from and score against")
    lm = rec.landmarks
    lx, ly, _ = incident.to_enu(lm.lat, lm.lon)
    fixes = fix_indices(len(lm), fix_every)
    settings = settings or TrackerSettings()
    gnss = use_gnss and settings.engine == "fusion"
    msgs = recording_messages(rec, RESPONDER, incident=incident, landmark_every=fix_every, gnss=gnss)
    cfg = incident.model_copy(update={"start_floor": int(lm.floor[0])})
    # the walk starts at its first landmark: no entry guess before it (entry_sigma_m=None)
    run = run_walk(msgs, cfg, RESPONDER, CoreSettings(tracker=settings, entry_sigma_m=None))
    if run.errors:
        raise RuntimeError(f"{rec.source}: the incident core hit {run.errors} errors (see the log)")
    tracker = run.tracker
    live = _columns([(p.t, p.x, p.y, p.floor) for p in run.poses])
    sm = tracker.smoothed_track()
    smoothed = None if sm is None else {k: np.asarray(sm[k]) for k in ("t", "x", "y", "floor")}
    gnss_n = sum(m.kind == "fix" and m.msg.source == "gnss" for m in msgs)
    return IpinRun(rec.source, lm.t, np.asarray(lx, float), np.asarray(ly, float), lm.floor.astype(int), fixes, live,
                   smoothed, _columns(tracker.pdr_track), gnss_n, tracker.fixes_rejected)


def _columns(rows) -> dict[str, np.ndarray]:
    a = np.array(rows, float).reshape(-1, 4)
    # a pose republished after a fix keeps its step time: the later publication wins
    return {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "floor": a[:, 3].astype(int)}
