"""After-action review: an incident recording run through the service again, offline.

``reprocess`` feeds every recorded input (imu, fix and presence messages, in the order and
with the receive times they were recorded with) to an :class:`service.core.IncidentCore` —
the same core the live service runs, in the same rounds — and
compares the poses it publishes with the poses recorded live, pose by pose. Frames held by
the reorder gate are released on the recorded receive times, as live; a live run whose
frames waited for the once-a-second timer (a frame lost for good) may differ there.

``exercise`` turns single-person recordings (IPIN logs, PyShoe walks, ...) into one
multi-person exercise: each becomes a responder's messages, their start times aligned.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from service.core.incident_core import INBOUND_KINDS, Inbound, IncidentCore
from service.protocol import wire
from service.review.recorder import IncidentRecorder, read_recording


@dataclass
class ResponderReview:
    steps: int = 0
    distance_m: float = 0.0  # of the live track, as published (with its jumps at fixes)
    poses: int = 0
    recorded_poses: int = 0
    max_deviation_m: float | None = None
    xy: list = field(default_factory=list)
    live: list = field(default_factory=list)  # (t, x, y, floor, yaw, cov_xx, cov_xy, cov_yy) per published pose
    utc_offset: float | None = None


def reprocess(path: Path, incident_cfg, progress=None) -> dict:
    check_is_recording(path)
    core = IncidentCore(incident_cfg)
    published: list = []
    recorded: dict[str, list[tuple[float, float, float]]] = {}
    n_inputs = 0
    cpu0 = time.process_time()
    pending: list = []
    for m in read_recording(path):
        if m.incident != core.id:
            _feed(core, pending, published)
            core = _retarget(core, incident_cfg, m.incident)
        if m.kind in INBOUND_KINDS:
            pending.append(Inbound(m.kind, m.key, m.payload, m.receive_time))
            n_inputs += 1
            if len(pending) >= ROUND:
                _feed(core, pending, published)
            if progress is not None and n_inputs % 2000 == 0:
                progress(n_inputs)
        elif m.kind == "pose":
            p = wire.decode(m.payload, expect=wire.Pose)
            recorded.setdefault(p.responder, []).append((p.t, p.x, p.y))
    _feed(core, pending, published)
    cpu = time.process_time() - cpu0
    out: dict[str, ResponderReview] = {}
    for o in published:
        p = o.message
        if not isinstance(p, wire.Pose):
            continue
        rid = p.responder
        r = out.setdefault(rid, ResponderReview())
        if r.xy:
            r.distance_m += math.hypot(p.x - r.xy[-1][1], p.y - r.xy[-1][2])
        r.xy.append((p.t, p.x, p.y))
        c = p.cov
        r.live.append((p.t, p.x, p.y, p.floor, math.radians(90.0 - p.heading_deg), c[0, 0], c[0, 1], c[1, 1]))
        if p.utc is not None:
            r.utc_offset = p.utc - p.t  # the offset the service used for this pose
        r.steps = max(r.steps, p.steps)
    for rid, resp in core.responders.items():
        r = out.setdefault(rid, ResponderReview())
        r.steps = max(r.steps, resp.tracker.steps)
    worst = None
    for rid, r in out.items():
        r.poses = len(r.xy)
        live = recorded.get(rid)
        if live is None:
            continue
        r.recorded_poses = len(live)
        if len(live) != len(r.xy):
            r.max_deviation_m = math.inf
        else:
            a, b = np.array(live), np.array(r.xy)
            r.max_deviation_m = float(np.max(np.hypot(a[:, 1] - b[:, 1], a[:, 2] - b[:, 2]))) if len(a) else 0.0
        worst = r.max_deviation_m if worst is None else max(worst, r.max_deviation_m)
    duration = _duration(path)
    tracks = {}
    for rid, resp in core.responders.items():
        tr = resp.tracker.smoothed_track()
        if tr is not None and len(tr["t"]):
            tracks[rid] = {k: np.asarray(tr[k]) for k in ("t", "x", "y", "floor", "heading")}
            tracks[rid]["utc_offset"] = resp.utc_offset
    return {
        "tracks": tracks,
        "live_tracks": {rid: _live_track(r.live, r.utc_offset) for rid, r in out.items() if r.live},
        "responders": {rid: {"steps": r.steps, "distance_live_m": r.distance_m,
                             "distance_smoothed_m": _walked(tracks.get(rid)), "poses": r.poses,
                             "recorded_poses": r.recorded_poses, "max_deviation_m": r.max_deviation_m}
                       for rid, r in sorted(out.items())},
        "max_deviation_m": worst,
        "audits": [o.message.model_dump() for o in published if isinstance(o.message, wire.Audit)],  # who did what
        "inputs": n_inputs,
        "errors": core.counters.errors,
        "cpu_s": cpu,
        "recording_s": duration,
        "realtime_factor": duration / cpu if cpu > 0 and duration else None,
    }


def _live_track(rows: list, utc_offset) -> dict:
    """The poses as the service published them, with their covariance (m², ENU), as a track."""
    a = np.array(rows, dtype=np.float64)
    a = a[np.concatenate(([True], np.diff(a[:, 0]) > 0))] if len(a) else a  # one pose per time: the last fix's jump
    cols = ("t", "x", "y", "floor", "heading", "cov_xx", "cov_xy", "cov_yy")
    track = {k: a[:, j] for j, k in enumerate(cols)}
    track["floor"] = track["floor"].astype(np.int64)
    track["utc_offset"] = utc_offset
    return track


def _walked(track: dict | None) -> float | None:
    """Length (m) of a smoothed track's horizontal path (None without one)."""
    if track is None or len(track["t"]) < 2:
        return None
    return float(np.sum(np.hypot(np.diff(track["x"]), np.diff(track["y"]))))


def check_is_recording(path: Path) -> None:
    """ValueError unless ``path`` starts like an MCAP file (what firetrack records)."""
    from mcap.writer import MCAP0_MAGIC

    with open(path, "rb") as f:
        head = f.read(len(MCAP0_MAGIC))
    if head != MCAP0_MAGIC:
        raise ValueError(f"{path} is not a firetrack recording (not an MCAP file: it does not start with the MCAP "
                         "magic bytes); record one with `firetrack serve --record` or `firetrack record`")


ROUND = 500  # recorded messages fed together: what the live worker does when it has a backlog


def _feed(core: IncidentCore, pending: list, published: list) -> None:
    """The messages read so far through the core in one round, as the live worker does with a
    backlog: each responder's frames go through its pipeline as one batch, with the same
    poses, bit for bit, as one message at a time (tests/test_service.py), at a fraction of
    the cost."""
    if pending:
        published += core.feed_round(pending)
        pending.clear()


def _duration(path: Path) -> float | None:
    from service.review.recorder import recording_summary

    return recording_summary(path)["duration"]


def _retarget(core: IncidentCore, cfg, incident: str) -> IncidentCore:
    """A recording of another incident id: serve it under that id (same building config)."""
    if core.responders:
        raise ValueError(f"the recording mixes incidents ({cfg.id!r} and {incident!r})")
    return IncidentCore(cfg.model_copy(update={"id": incident}))


def build_exercise(members: list[tuple[str, Path]], out: Path, incident_cfg, start: float | None = None,
                   landmark_every: int = 0, gnss: bool = True, overwrite: bool = False) -> dict:
    """One exercise file from single-person recordings: responder ``rid`` walks ``path``; all
    start together at ``start`` (unix s, default now); messages are stamped as received then."""
    from pdr.io import load
    from service.protocol.messages import recording_messages

    start = time.time() if start is None else start
    streams = []
    for rid, path in members:
        if not wire.is_valid_id(rid):
            raise ValueError(f"responder id {rid!r}: use 1-64 letters, digits, '_', '.' or '-'")
        msgs = recording_messages(load(path), rid, incident=incident_cfg, landmark_every=landmark_every, gnss=gnss)
        if not msgs:
            raise ValueError(f"{path}: no IMU samples")
        t0 = msgs[0].t
        streams += [(start + (m.t - t0), rid, m) for m in msgs]
    streams.sort(key=lambda s: (s[0], s[1], s[2].kind != "imu"))
    counts: dict[str, int] = {}
    with IncidentRecorder(out, incident_cfg.id, overwrite=overwrite) as rec:
        for when, rid, m in streams:
            rec.write(wire.key(incident_cfg.id, rid, m.kind), wire.encode(m.msg), when)
            counts[rid] = counts.get(rid, 0) + 1
    return {"file": str(out), "responders": counts, "duration_s": streams[-1][0] - start if streams else 0.0}
