"""Drive a :class:`service.tracker.ResponderTracker` over one IPIN log, as the service would live.

The log's samples go through in frames (as a wearable would send them), its landmarks are
checkpoint fixes at their own time (landmark 0 always: the initial position; with
``fix_every=K`` also K, 2K, …), its GNSS fixes go to the fusion unless ``use_gnss`` is off.
Everything is in the incident's local ENU frame (origin from the incident config).

:func:`run_ipin` is the one entry point: a recording and settings in, an :class:`IpinRun` out.

**Replaying the dead reckoning.** Sweeps and cross-validation rerun the fusion many times with
the same PDR. The pipeline's events depend only on the recording, the pipeline settings, the
floors and the checkpoints' times and floors (a checkpoint re-anchors the floor), never on the
fusion settings or GNSS; and the tracker acts on the concatenated event stream in order,
however the frames were cut. So a :class:`PdrCache` keeps, per (walk, K, pipeline settings,
floors, frame size), every event the pipeline emitted, and a later run with other fusion
settings feeds them to the tracker instead of the frames: the same poses, bit for bit
(tests/test_ipin_eval.py), at the price of the fusion alone.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pymap3d

from pdr.evaluation.ipin import LandmarkErrors, fix_indices, score_track
from pdr.events import FloorEvent, StepEvent
from pdr.floors import FloorElevations
from pdr.pipeline import frames_of
from pdr.recording import Recording
from service.tracker import CheckpointFix, ResponderTracker, TrackerSettings

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
    diagnostics: dict = field(default_factory=dict)  # for plots: heading evidence, floors over time

    def scored(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.lm_t.size), self.fixes)

    def errors(self, which: str = "live") -> LandmarkErrors | None:
        tr = {"live": self.live, "smoothed": self.smoothed, "pdr": self.pdr}[which]
        if tr is None or tr["t"].size == 0:
            return None
        return score_track(self.lm_t, self.lm_x, self.lm_y, self.lm_floor, tr["t"], tr["x"], tr["y"], tr["floor"], self.scored())


@dataclass
class _PdrRecord:
    """Everything one walk's pipeline emitted, in order, and what the tracker reads of it."""

    events: list = field(default_factory=list)  # from update() calls, concatenated
    finished: list = field(default_factory=list)  # from finish()
    floors: list = field(default_factory=list)  # the pipeline's floor after each call
    heights: dict = field(default_factory=dict)  # diagnostics of the altimeter and floor tracker


class _RecordingPipeline:
    """Stands in for the tracker's pipeline: forwards every call and keeps what it returned."""

    def __init__(self, pipeline, record: _PdrRecord):
        self._p, self._rec = pipeline, record

    def update(self, frame):
        out = self._p.update(frame)
        self._rec.events += out
        self._rec.floors.append(self._p.floor)
        return out

    def finish(self):
        out = self._p.finish()
        self._rec.finished = list(out)
        self._rec.floors.append(self._p.floor)
        return out

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        self._p.anchor_floor(floor, t)

    def __getattr__(self, name):
        return getattr(self._p, name)


class _ReplayPipeline:
    """Gives the tracker a recorded walk's events: all of them at the first update."""

    def __init__(self, record: _PdrRecord):
        self._rec, self._sent = record, False
        self.floor = record.floors[-1] if record.floors else 0

    def update(self, frame):
        if self._sent:
            return []
        self._sent = True
        return list(self._rec.events)

    def finish(self):
        return list(self._rec.finished)

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """The recorded events already carry the anchoring of the run that recorded them."""


class PdrCache:
    """Recorded pipeline output per (walk, K, pipeline settings, floors, frame size); see the module docstring."""

    def __init__(self):
        self._store: dict[tuple, _PdrRecord] = {}
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(rec: Recording, fix_every: int, settings: TrackerSettings, floors: FloorElevations, per_frame: int) -> tuple:
        return (rec.source, int(fix_every), repr(settings.pipeline), repr(sorted(floors.elevations.items())), int(per_frame))

    def get(self, key) -> _PdrRecord | None:
        r = self._store.get(key)
        if r is None:
            self.misses += 1
        else:
            self.hits += 1
        return r

    def put(self, key, record: _PdrRecord) -> None:
        self._store[key] = record


def run_ipin(rec: Recording, origin: tuple[float, float, float], floors: FloorElevations, fix_every: int = 0,
             use_gnss: bool = True, settings: TrackerSettings | None = None, per_frame: int = 50,
             pdr_cache: PdrCache | None = None) -> IpinRun:
    """Track one IPIN walk from its first landmark; see the module docstring."""
    if rec.landmarks is None or len(rec.landmarks) == 0:
        raise ValueError(f"{rec.source}: no landmarks (POSI lines) to start from and score against")
    lm = rec.landmarks
    lat0, lon0, alt0 = origin
    lx, ly, _ = pymap3d.geodetic2enu(lm.lat, lm.lon, np.zeros(len(lm)), lat0, lon0, alt0)
    fixes = fix_indices(len(lm), fix_every)
    settings = settings or TrackerSettings()
    tracker = ResponderTracker(rec.source, floors, int(lm.floor[0]), settings)
    key = PdrCache.key(rec, fix_every, settings, floors, per_frame) if pdr_cache is not None else None
    record = pdr_cache.get(key) if pdr_cache is not None else None
    recording = None
    if record is not None:
        tracker.pipeline = _ReplayPipeline(record)
    else:
        recording = _PdrRecord()
        tracker.pipeline = _RecordingPipeline(tracker.pipeline, recording)
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
    poses = []
    steps = _StepLog(tracker)
    if record is not None:
        poses += [p for p in tracker.on_frame(None) if hasattr(p, "x")]
    else:
        imu = rec.imu_samples()
        pt = rec.pressure.t if rec.pressure is not None else None
        pv = rec.pressure.values[:, 0] if rec.pressure is not None else None
        for frame in frames_of(imu.t, imu.acc, imu.gyr, imu.mag, pt, pv, per_frame=per_frame):
            poses += [p for p in tracker.on_frame(frame) if hasattr(p, "x")]
    poses += [p for p in tracker.finish() if hasattr(p, "x")]
    if recording is not None and pdr_cache is not None:
        pdr_cache.put(key, recording)
    live = _columns([(p.t, p.x, p.y, p.floor) for p in poses])
    diagnostics = {
        "steps": steps.columns(),
        "heading": np.array([p.heading for p in poses]),
        "fusion_events": list(tracker.engine.events) if tracker.engine is not None and hasattr(tracker.engine, "events") else [],
        "floor_events": [(e.t, e.floor) for e in steps.floor_events],
        "pressure": None if rec.pressure is None else (rec.pressure.t, rec.pressure.values[:, 0]),
    }
    sm = tracker.smoothed_track()
    smoothed = None if sm is None else {k: np.asarray(sm[k]) for k in ("t", "x", "y", "floor")}
    if smoothed is not None:
        smoothed["t"] = np.maximum.accumulate(smoothed["t"]) if smoothed["t"].size else smoothed["t"]
    return IpinRun(rec.source, lm.t, np.asarray(lx), np.asarray(ly), lm.floor.astype(int), fixes, live, smoothed,
                   _columns(tracker.pdr_track), gnss_n, tracker.fixes_rejected, diagnostics)


class _StepLog:
    """Keeps every step event the tracker consumes (wrapping its ``_consume``), for plots."""

    def __init__(self, tracker: ResponderTracker):
        self.steps: list = []
        self.floor_events: list = []
        inner = tracker._consume

        def consume(events):
            for ev in events:
                if isinstance(ev, StepEvent):
                    self.steps.append(ev)
                elif isinstance(ev, FloorEvent):
                    self.floor_events.append(ev)
            return inner(events)

        tracker._consume = consume

    def columns(self) -> dict[str, np.ndarray]:
        names = ("t", "length", "heading", "heading_sigma", "heading_change", "mag_heading", "mag_heading_sigma", "floor")
        return {n: np.array([getattr(e, n) for e in self.steps], float) for n in names}


def _columns(rows) -> dict[str, np.ndarray]:
    """Poses in the order they were published, timed by when they could first be shown: a pose
    republished after a fix keeps its step's time, which may be earlier than a floor change
    published before it; the running maximum keeps the track causal (the later publication wins)."""
    a = np.array(rows, float).reshape(-1, 4)
    t = np.maximum.accumulate(a[:, 0]) if len(a) else a[:, 0]
    return {"t": t, "x": a[:, 1], "y": a[:, 2], "floor": a[:, 3].astype(int)}
