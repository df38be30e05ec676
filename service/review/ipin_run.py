"""Track one IPIN log through the incident core, as the service would live, and score it.

The walk becomes the messages a wearable would send (:func:`service.protocol.messages.recording_messages`):
the IMU in frames of 1/10 s, landmark 0 (the start) and every ``fix_every``-th landmark as
checkpoint fixes at their own time, the log's GNSS unless ``use_gnss`` is off. The incident
core decodes, gates, batches and tracks them (:func:`service.review.walk.run_walk`), so the
figures are those of the code that runs at an incident. Everything is in the incident's local
ENU frame (origin from the incident config).

:func:`run_ipin` is the one entry point: a recording and settings in, an :class:`IpinRun` out.

**Replaying the dead reckoning.** Sweeps and cross-validation rerun the fusion many times with
the same PDR. The motion model's events depend only on the recording, the pipeline settings,
the floors and the checkpoints' times and floors (a checkpoint re-anchors the floor), never
on the fusion settings or GNSS; and a streaming model emits the same events by the time a
given sample has arrived, however the frames were cut. So a :class:`PdrCache` keeps, per
(walk, K, pipeline settings, floors), every event the model emitted with the time of the
newest sample it had then, and a later run with other fusion settings gives the tracker those
events at the same moments instead of running the pipeline: the same poses, bit for bit
(``tests/test_ipin_eval.py``), at the price of the fusion alone.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pdr.evaluation.ipin import LandmarkErrors, fix_indices, score_track
from pdr.events import FloorEvent, MotionEvent, MotionState, StepEvent
from pdr.pipeline import PdrPipeline
from pdr.recording import Recording
from service.core.incident_core import CoreSettings
from service.core.tracker import TrackerSettings
from service.protocol.messages import BLE_SCAN_S, recording_messages
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
    diagnostics: dict = field(default_factory=dict)  # for plots: heading evidence, floors over time
    app_to_sensor_offset_s: float = 0.0  # s: the logger's app clock (AppTs, the organisers' time) + this = the device clock
    refused: dict[str, int] = field(default_factory=dict)  # what the core turned away, by reason (e.g. GNSS before the IMU)

    def scored(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.lm_t.size), self.fixes)

    def errors(self, which: str = "live") -> LandmarkErrors | None:
        tr = {"live": self.live, "smoothed": self.smoothed, "pdr": self.pdr}[which]
        if tr is None or tr["t"].size == 0:
            return None
        return score_track(self.lm_t, self.lm_x, self.lm_y, self.lm_floor, tr["t"], tr["x"], tr["y"], tr["floor"], self.scored())


# ------------------------------------------------------------------------------------------
# The dead reckoning, recorded and replayed
# ------------------------------------------------------------------------------------------
@dataclass
class _PdrRecord:
    """Everything one walk's motion model emitted: per update, the newest sample's time, the
    events and the floor after it; and what finish() gave."""

    updates: list = field(default_factory=list)  # (t_last, [events], floor after)
    finished: list = field(default_factory=list)


class _RecordingModel:
    """Runs the real motion model and keeps what it returned, for :class:`_ReplayModel`."""

    def __init__(self, model, record: _PdrRecord):
        self._m, self._rec = model, record

    def update(self, frame):
        out = self._m.update(frame)
        self._rec.updates.append((float(frame.t[-1]), list(out), self._m.floor))
        return out

    def finish(self):
        out = self._m.finish()
        self._rec.finished = list(out)
        return out

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        self._m.anchor_floor(floor, t)

    def __getattr__(self, name):  # steps, floor, state, state_since, last_time
        return getattr(self._m, name)


class _ReplayModel:
    """A recorded walk's events, each given when a frame brings the samples it came with."""

    def __init__(self, record: _PdrRecord, start_floor: int):
        self._rec, self._next = record, 0
        self.floor, self.steps = start_floor, 0
        self.state, self.state_since, self.last_time = MotionState.STILL, math.nan, math.nan

    def update(self, frame):
        self.last_time = float(frame.t[-1])
        out = []
        ups = self._rec.updates
        while self._next < len(ups) and ups[self._next][0] <= self.last_time:
            _, events, self.floor = ups[self._next]
            out += events
            self._next += 1
        return self._seen(out)

    def finish(self):
        rest = [ev for _, events, _ in self._rec.updates[self._next:] for ev in events]
        self._next = len(self._rec.updates)
        return self._seen(rest + list(self._rec.finished))

    def anchor_floor(self, floor: int, t: float | None = None) -> None:
        """The recorded events already carry the anchoring of the run that recorded them."""

    def _seen(self, events):
        for ev in events:
            if isinstance(ev, StepEvent):
                self.steps = ev.index
            elif isinstance(ev, MotionEvent):
                self.state, self.state_since = ev.state, ev.since
        return events


class PdrCache:
    """Recorded motion-model output per (walk, K, pipeline settings, floors); see the module docstring."""

    def __init__(self):
        self._store: dict[tuple, _PdrRecord] = {}
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(rec: Recording, fix_every: int, settings: TrackerSettings, elevations: dict) -> tuple:
        return (rec.source, int(fix_every), repr(settings.pipeline), repr(sorted(elevations.items())))

    def get(self, key) -> _PdrRecord | None:
        r = self._store.get(key)
        if r is None:
            self.misses += 1
        else:
            self.hits += 1
        return r

    def put(self, key, record: _PdrRecord) -> None:
        self._store[key] = record


class _EventLog:
    """Every step and floor event the tracker was given (for the plots)."""

    def __init__(self):
        self.steps: list = []
        self.floor_events: list = []

    def wrap(self, model):
        update, finish = model.update, model.finish

        def logged(events):
            for ev in events:
                if isinstance(ev, StepEvent):
                    self.steps.append(ev)
                elif isinstance(ev, FloorEvent):
                    self.floor_events.append(ev)
            return events

        model.update = lambda frame: logged(update(frame))
        model.finish = lambda: logged(finish())
        return model

    def columns(self) -> dict[str, np.ndarray]:
        names = ("t", "length", "heading", "heading_sigma", "heading_change", "mag_heading", "mag_heading_sigma", "floor")
        return {n: np.array([getattr(e, n) for e in self.steps], float) for n in names}


# ------------------------------------------------------------------------------------------
# One walk
# ------------------------------------------------------------------------------------------
def run_ipin(rec: Recording, incident, fix_every: int = 0, use_gnss: bool = True,
             settings: TrackerSettings | None = None, pdr_cache: PdrCache | None = None,
             use_ble: bool = False) -> IpinRun:
    """Track one IPIN walk through the incident core, from the messages a wearable would send;
    see the module docstring. ``use_ble``: the log's beacon readings go as ``ble`` scans
    (:data:`service.protocol.messages.BLE_SCAN_S`) against the incident's ``beacons``."""
    if rec.landmarks is None or len(rec.landmarks) == 0:
        raise ValueError(f"{rec.source}: no landmarks (POSI lines) to start from and score against")
    lm = rec.landmarks
    lx, ly, _ = incident.to_enu(lm.lat, lm.lon)
    fixes = fix_indices(len(lm), fix_every)
    settings = settings or TrackerSettings()
    cfg = incident.model_copy(update={"start_floor": int(lm.floor[0])})
    key = PdrCache.key(rec, fix_every, settings, cfg.elevations()) if pdr_cache is not None else None
    record = pdr_cache.get(key) if pdr_cache is not None else None
    recording = _PdrRecord() if record is None else None
    log = _EventLog()

    def motion(s, floors, start_floor):
        model = (_ReplayModel(record, start_floor) if record is not None
                 else _RecordingModel(PdrPipeline(s.pipeline, floors, start_floor), recording))
        return log.wrap(model)

    gnss = use_gnss and settings.engine == "fusion"
    msgs = recording_messages(rec, RESPONDER, incident=cfg, landmark_every=fix_every, gnss=gnss,
                              ble_scan_s=BLE_SCAN_S if use_ble and settings.engine == "fusion" else 0.0)
    # the walk starts at its first landmark: no entry guess before it (entry_sigma_m=None)
    core_settings = CoreSettings(tracker=dataclasses.replace(settings, motion=motion), entry_sigma_m=None)
    run = run_walk(msgs, cfg, RESPONDER, core_settings)
    if run.errors:
        raise RuntimeError(f"{rec.source}: the incident core hit {run.errors} errors (see the log)")
    if recording is not None and pdr_cache is not None:
        pdr_cache.put(key, recording)
    tracker = run.tracker
    live = _columns([(p.t, p.x, p.y, p.floor) for p in run.poses])
    sm = tracker.smoothed_track()
    smoothed = None if sm is None else {k: np.asarray(sm[k]) for k in ("t", "x", "y", "floor")}
    if smoothed is not None and smoothed["t"].size:
        smoothed["t"] = np.maximum.accumulate(smoothed["t"])
    fusion = getattr(tracker.estimator, "fusion", None)
    diagnostics = {
        "steps": log.columns(),
        "heading": np.array([math.radians(90.0 - p.heading_deg) for p in run.poses]),
        "fusion_events": list(fusion.events) if fusion is not None else [],
        "floor_events": [(e.t, e.floor) for e in log.floor_events],
        "pressure": None if rec.pressure is None else (rec.pressure.t, rec.pressure.values[:, 0]),
    }
    gnss_n = sum(m.kind == "fix" and m.msg.source == "gnss" for m in msgs)
    return IpinRun(rec.source, lm.t, np.asarray(lx, float), np.asarray(ly, float), lm.floor.astype(int), fixes, live,
                   smoothed, _columns(tracker.pdr_track), gnss_n, tracker.fixes_rejected, diagnostics,
                   float(rec.meta.get("app_to_sensor_offset_s", 0.0) or 0.0),
                   {k: n for k, n in run.rejected.items() if n})


def _columns(rows) -> dict[str, np.ndarray]:
    """Poses in the order they were published, timed by when they could first be shown: a pose
    republished after a fix keeps its step's time, which may be earlier than a floor change
    published before it; the running maximum keeps the track causal (the later publication wins)."""
    a = np.array(rows, float).reshape(-1, 4)
    t = np.maximum.accumulate(a[:, 0]) if len(a) else a[:, 0]
    return {"t": t, "x": a[:, 1], "y": a[:, 2], "floor": a[:, 3].astype(int)}
