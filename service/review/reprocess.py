"""After-action review: an incident recording run through the service again, offline.

``reprocess`` feeds every recorded input (imu, fix and presence messages, in the order and
with the receive times they were recorded with) to an :class:`service.core.IncidentCore` —
the same core the live service runs, in the same rounds — and
compares the poses it publishes with the poses recorded live, pose by pose. Frames held by
the reorder gate are released on the recorded receive times, as live; a live run whose
frames waited for the once-a-second timer (a frame lost for good) may differ there.

A recording of several segments (a service that restarted, :mod:`service.review.resume`) is
reprocessed the way the live services went (:class:`service.review.resume.SegmentReplay`):
each resumed segment from the snapshot its service resumed from. Live poses are matched to
reprocessed ones by responder, time and step count; poses computed live whose record was lost
in a crash (the unfinished chunk) only exist in the reprocessed run, and are counted, not
compared.

``exercise`` turns single-person recordings (IPIN logs, PyShoe walks, ...) into one
multi-person exercise: each becomes a responder's messages, their start times aligned.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from service.core import alarms
from service.core.incident_core import INBOUND_KINDS
from service.protocol import wire
from service.review.incident_events import review_events
from service.review.recorder import IncidentRecorder
from service.review.resume import SegmentReplay


@dataclass
class ResponderReview:
    steps: int = 0
    distance_m: float = 0.0  # of the live track, as published (with its jumps at fixes)
    poses: int = 0
    recorded_poses: int = 0
    max_deviation_m: float | None = None
    worst_pose: tuple | None = None  # (t, steps, live x, y, reprocessed x, y) where the deviation is largest
    unmatched: int = 0
    xy: list = field(default_factory=list)
    live: list = field(default_factory=list)  # (t, x, y, floor, yaw, cov_xx, cov_xy, cov_yy, unix) per published pose
    utc_offset: float | None = None


def reprocess(path: Path, incident_cfg, progress=None) -> dict:
    check_is_recording(path)
    replay = SegmentReplay(path, incident_cfg)
    published: list = []
    timed: list = []  # (time, Status recorded live or Audit answered now) for the event log
    recorded: dict[str, list[tuple[float, int, float, float]]] = {}
    n_inputs = 0
    cpu0 = time.process_time()
    for m, answers in replay:
        if m.kind in INBOUND_KINDS:
            n_inputs += 1
            if progress is not None and n_inputs % 2000 == 0:
                progress(n_inputs)
        elif m.kind == "pose":
            p = wire.decode(m.payload, expect=wire.Pose)
            recorded.setdefault(p.responder, []).append((p.t, p.steps, p.x, p.y))
        elif m.kind == "status":  # the alarms as raised live (offline there is no timer: no Status is answered)
            try:
                timed.append((m.receive_time, wire.decode(m.payload, expect=wire.Status)))
            except wire.WireError:
                pass  # a record the reader could not decode: the alarms of the others still count
        published += answers
        timed += [(m.receive_time, o.message) for o in answers if isinstance(o.message, wire.Audit)]
    core = replay.core
    cpu = time.process_time() - cpu0
    out: dict[str, ResponderReview] = {}
    mine: dict[str, list[tuple[float, int, float, float]]] = {}
    for o in published:
        p = o.message
        if not isinstance(p, wire.Pose):
            continue
        rid = p.responder
        r = out.setdefault(rid, ResponderReview())
        if r.xy:
            r.distance_m += math.hypot(p.x - r.xy[-1][1], p.y - r.xy[-1][2])
        r.xy.append((p.t, p.x, p.y))
        mine.setdefault(rid, []).append((p.t, p.steps, p.x, p.y))
        c = p.cov
        r.live.append((p.t, p.x, p.y, p.floor, math.radians(90.0 - p.heading_deg), c[0, 0], c[0, 1], c[1, 1],
                       p.utc if p.utc is not None else p.published_at))
        if p.utc is not None:
            r.utc_offset = p.utc - p.t  # the offset the service used for this pose
        r.steps = max(r.steps, p.steps)
    answers = {}
    for rid, resp in core.responders.items():
        r = out.setdefault(rid, ResponderReview())
        r.steps = max(r.steps, resp.tracker.steps)
        answers[rid] = _answers(resp)
    worst = None
    for rid, r in out.items():
        r.poses = len(r.xy)
        live = recorded.get(rid)
        if live is None:
            continue
        r.recorded_poses = len(live)
        r.max_deviation_m, r.unmatched, r.worst_pose = _compare(live, mine.get(rid, []))
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
                             "recorded_poses": r.recorded_poses, "max_deviation_m": r.max_deviation_m,
                             "worst_pose": r.worst_pose,
                             "unmatched_live_poses": r.unmatched, **answers.get(rid, {})}
                       for rid, r in sorted(out.items())},
        "max_deviation_m": worst,
        "audits": [o.message.model_dump() for o in published if isinstance(o.message, wire.Audit)],  # who did what
        "events": review_events(timed),  # alarms began and ended, operator actions: for the exports
        "inputs": n_inputs,
        "errors": core.counters.errors,
        "cpu_s": cpu,
        "recording_s": duration,
        "realtime_factor": duration / cpu if cpu > 0 and duration else None,
        "segments": len(replay.segments),
        "resumed_segments": [k for k, _ in replay.resumes],
        # where the recording is cut or corrupt (chunk CRCs are checked): what lay there was not reprocessed
        "damage": [{"file": f, "offset": off, "problem": what} for f, off, what in replay.damage],
    }


def _answers(r) -> dict:
    """What the responder was asked and answered, as the reprocessed core ends: the newest order
    of each action with its acknowledgement (UTC s, the wearable's), the wearer's latest "I'm
    OK" to the man-down prompt and the man-down verdict at the last sample (device clock of the
    current stream): the same as the last live Status when the recording is whole."""
    verdict, at = alarms.man_down(r)
    return {"commands": {a: dict(o) for a, o in r.commands.items()},
            "ok_at": r.ok_at - r.t_offset if math.isfinite(r.ok_at) else None,
            "man_down": verdict, "man_down_at": None if at is None else at - r.t_offset}


def _compare(live: list, mine: list) -> tuple[float, int, tuple | None]:
    """Each live pose against the reprocessed pose of the same time and step count, in order:
    the largest distance (m), how many live poses had none (inf when any had none), and where
    the largest is (t, steps, live x, y, reprocessed x, y; None when every pose is equal).
    Extra reprocessed poses (their live record lost with a crashed chunk) are skipped."""
    worst, unmatched, j, at = 0.0, 0, 0, None
    for t, steps, x, y in live:
        k = j
        while k < len(mine) and (mine[k][0], mine[k][1]) != (t, steps):
            k += 1
        if k == len(mine):
            unmatched += 1
            continue
        d = math.hypot(mine[k][2] - x, mine[k][3] - y)
        if d > worst:
            worst, at = d, (t, steps, x, y, mine[k][2], mine[k][3])
        j = k + 1
    return (math.inf if unmatched else worst), unmatched, at


def _live_track(rows: list, utc_offset) -> dict:
    """The poses as the service published them, with their covariance (m², ENU) and the UTC
    time each is at (``unix``: its device time + the wearable's UTC offset; without one, +
    the median of publication time − device time, so times keep the device clock's order),
    as a track."""
    a = np.array(rows, dtype=np.float64)
    a = a[np.concatenate(([True], np.diff(a[:, 0]) > 0))] if len(a) else a  # one pose per time: the last fix's jump
    cols = ("t", "x", "y", "floor", "heading", "cov_xx", "cov_xy", "cov_yy", "unix")
    track = {k: a[:, j] for j, k in enumerate(cols)}
    track["floor"] = track["floor"].astype(np.int64)
    track["utc_offset"] = utc_offset
    if len(a):  # one clock for the whole track: the wearable's offset, else the typical publication delay
        off = utc_offset if utc_offset is not None else float(np.median(track["unix"] - track["t"]))
        track["unix"] = track["t"] + off
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


def _duration(path: Path) -> float | None:
    from service.review.recorder import recording_summary

    return recording_summary(path)["duration"]


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
