"""Restart recovery: a service started on a recording that exists goes on where the last one stopped.

While it runs, the service writes a snapshot of its incident core beside the recording every
few seconds (:class:`StateFile`, ``x.mcap.state``): the core's bytes
(:meth:`service.core.incident_core.IncidentCore.snapshot`), the segment it was writing and how
many of that segment's messages were in the file when it was taken (the recorder is flushed
first, so every input the snapshot has seen is in the recording before the snapshot says so).

After a crash (SIGKILL, power), :func:`resume` rebuilds the core:

1. the **base**: the newest of the state file's snapshot and the base the newest segment's
   service itself resumed from (its ``firetrack.resume`` attachment), or the empty core at the
   start of the recording when there is neither (or neither can be read);
2. every recorded input after the base (``imu``, ``fix``, ``presence``, in the order written,
   with their receive times), through the core in rounds, its answers dropped (they went out
   before the crash);
3. the next segment (``x.N.mcap``) is opened with a ``firetrack.resume`` attachment holding
   the base (segment, position, snapshot), so ``reprocess`` of the whole recording rebuilds
   the same core at the same point (:func:`replay_segments`) and gives the poses the live
   service published, bit for bit.

Tracks continue with their step counts, gates (next seq, so a wearable's kept frames fill
the outage and its repeats count as duplicates), fixes and alarms. The estimators restart
their graphs from the newest pose (:mod:`service.fusion.graph`, *Snapshots*).

It never refuses to start: a state file that cannot be read (damaged, another incident, another
version of the code) is reported and the recording is replayed from its start instead; a
recording that cannot be read at all is reported and left alone, and the service starts empty
in a new segment.

Cost (``firetrack bench resume``): reading and re-running the few seconds after the newest
snapshot, plus unpickling the snapshot; replaying a whole recording costs what ``reprocess``
costs (≈ 190 responder-seconds of walking per CPU-second on the development VM).
"""
from __future__ import annotations

import logging
import os
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import msgpack

from service.core.incident_core import INBOUND_KINDS, Inbound, IncidentCore, Outbound
from service.core.snapshot import SnapshotError
from service.review.recording_reader import (
    RecordingReader,
    TruncatedRecordingWarning,
    next_segment_path,
    segment_paths,
)

log = logging.getLogger("firetrack.service")

STATE_FORMAT = "firetrack-state/1"
ROUND = 500  # recorded inputs fed together (as reprocess does)


def state_path(recording) -> Path:
    """Where the snapshots of a recording live: ``x.mcap`` -> ``x.mcap.state``."""
    recording = Path(recording)
    return recording.with_name(recording.name + ".state")


class StateFile:
    """The newest snapshot of a running service's core, beside its recording.

    Written whole and renamed into place (``os.replace``), so a crash mid-write leaves the
    previous snapshot; ``fsync`` (off by default, like the recorder's) makes it survive a power
    cut too.
    """

    def __init__(self, path, incident: str, segment: int, fsync: bool = False):
        self.path = Path(path)
        self.incident = incident
        self.segment = int(segment)
        self.fsync = fsync
        self.bytes_written = 0

    def write(self, blob: bytes, position: int, now: float) -> None:
        data = msgpack.packb({"format": STATE_FORMAT, "incident": self.incident, "segment": self.segment,
                              "position": int(position), "written_at": float(now), "snapshot": bytes(blob)},
                             use_bin_type=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0), 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            if self.fsync:
                os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, self.path)
        self.bytes_written = len(data)

    @staticmethod
    def read(path) -> dict:
        """The state as written; ValueError (naming the file) when it is not one."""
        path = Path(path)
        try:
            d = msgpack.unpackb(path.read_bytes(), raw=False)
        except Exception as e:
            raise ValueError(f"state file {path} cannot be read: {type(e).__name__}: {e}") from None
        if not isinstance(d, dict) or d.get("format") != STATE_FORMAT:
            raise ValueError(f"state file {path} is not a {STATE_FORMAT} file")
        for name, typ in (("incident", str), ("segment", int), ("position", int), ("snapshot", bytes)):
            if not isinstance(d.get(name), typ):
                raise ValueError(f"state file {path}: '{name}' is missing or not a {typ.__name__}")
        return d


@dataclass
class Base:
    """Where a core starts from: a snapshot (or None: empty) taken after ``position`` messages
    of segment ``segment``."""

    segment: int
    position: int
    snapshot: bytes | None
    origin: str  # "state file", "segment N", "start"

    def record(self) -> bytes:
        """The ``firetrack.resume`` attachment of the segment a resumed service writes."""
        return msgpack.packb({"segment": self.segment, "position": self.position, "snapshot": self.snapshot,
                              "origin": self.origin}, use_bin_type=True)

    @staticmethod
    def from_record(data: bytes) -> Base:
        d = msgpack.unpackb(data, raw=False)
        return Base(int(d["segment"]), int(d["position"]), d.get("snapshot"), str(d.get("origin", "segment")))


@dataclass
class Resumed:
    core: IncidentCore
    base: Base
    segment: int  # the number of the segment to write now
    path: Path  # its file
    replayed: int  # recorded inputs fed after the base
    seconds: float  # wall time the resume took
    problems: list[str]  # what could not be used, and what was done instead


def inputs_after(segments: list[Path], segment: int, position: int) -> Iterator[Inbound]:
    """The recorded inputs after the first ``position`` messages (file order) of ``segment``,
    then every input of the later segments, in the order written."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordingWarning)  # a cut-off segment is expected after a crash
        for k in range(segment, len(segments)):
            skip = position if k == segment else 0
            for i, m in enumerate(RecordingReader(segments[k], ordered=False)):
                if i >= skip and m.kind in INBOUND_KINDS:
                    yield Inbound(m.kind, m.key, m.payload, m.receive_time)


def feed(core: IncidentCore, inputs, out: list[Outbound] | None = None) -> int:
    """``inputs`` through ``core`` in rounds of :data:`ROUND`; the answers into ``out`` (or dropped)."""
    n = 0
    pending: list[Inbound] = []
    for item in inputs:
        pending.append(item)
        n += 1
        if len(pending) >= ROUND:
            answers = core.feed_round(pending)
            if out is not None:
                out += answers
            pending = []
    if pending:
        answers = core.feed_round(pending)
        if out is not None:
            out += answers
    return n


def core_from(base: Base, incident, settings=None) -> IncidentCore:
    return IncidentCore(incident, settings) if base.snapshot is None else IncidentCore.restore(base.snapshot, incident,
                                                                                                 settings)


def _bases(recording: Path, segments: list[Path], incident_id: str, problems: list[str]) -> list[Base]:
    """Candidate bases, newest first: the state file's, the newest segment's own resume base, the start."""
    out: list[Base] = []
    sp = state_path(recording)
    if sp.exists():
        try:
            st = StateFile.read(sp)
            if st["incident"] != incident_id:
                raise ValueError(f"state file {sp} is of incident {st['incident']!r}, not {incident_id!r}")
            if not 0 <= st["segment"] < len(segments):
                raise ValueError(f"state file {sp} is of segment {st['segment']}, and the recording has "
                                 f"{len(segments)}")
            out.append(Base(st["segment"], st["position"], st["snapshot"], "state file"))
        except ValueError as e:
            problems.append(str(e))
    for k in range(len(segments) - 1, 0, -1):
        try:
            r = RecordingReader(segments[k], ordered=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", TruncatedRecordingWarning)
                next(iter(r), None)  # reads the header records up to the first message
            if r.resume is not None:
                out.append(Base.from_record(r.resume))
                break
        except Exception as e:
            problems.append(f"segment {segments[k]}: its resume record cannot be read: {e}")
    out.sort(key=lambda b: (b.segment, b.position), reverse=True)
    out.append(Base(0, 0, None, "start"))
    return out


def resume(recording, incident, settings=None, progress: Callable[[int], None] | None = None) -> Resumed | None:
    """The core of the service that last wrote ``recording``, and the segment to write next
    (see the module docstring); None when there is no recording yet (a fresh start)."""
    recording = Path(recording)
    segments = segment_paths(recording)
    if not segments:
        return None
    started = time.monotonic()
    problems: list[str] = []
    k, path = next_segment_path(recording)
    for base in _bases(recording, segments, incident.id, problems):
        try:
            core = core_from(base, incident, settings)
            n = feed(core, _counted(inputs_after(segments, base.segment, base.position), progress))
        except (SnapshotError, ValueError, KeyError, OSError) as e:
            problems.append(f"resuming from the {base.origin} (segment {base.segment}, message {base.position}) "
                            f"failed: {e}")
            continue
        except Exception as e:  # a recording this code cannot read at all: never refuse to start
            problems.append(f"resuming from the {base.origin} failed: {type(e).__name__}: {e}")
            continue
        return Resumed(core, base, k, path, n, time.monotonic() - started, problems)
    problems.append("nothing could be resumed: the service starts empty")
    return Resumed(IncidentCore(incident, settings), Base(len(segments), 0, None, "empty"), k, path, 0,
                   time.monotonic() - started, problems)


def _counted(items, progress):
    for i, item in enumerate(items, 1):
        if progress is not None and i % 5000 == 0:
            progress(i)
        yield item


class SegmentReplay:
    """Iterate ``(RecordedMessage, [Outbound])`` over a recording the way its live services
    went: the first segment from an empty core, each later one that starts with a resume
    attachment from the base its service resumed from (the snapshot, then the inputs recorded
    after it in the segments before). Every recorded message comes out in file order; the last
    input of each round carries the core's answers for the round. ``core`` is the core in use,
    ``resumes`` the segments that started from a resume base."""

    def __init__(self, recording, incident, settings=None, round_size: int = ROUND):
        self.recording = Path(recording)
        self.segments = segment_paths(self.recording) or [self.recording]
        self.incident = incident
        self.settings = settings
        self.round_size = round_size
        self.core = IncidentCore(incident, settings)
        self.resumes: list[tuple[int, str]] = []
        self.truncated = False
        self.damage: list[tuple[str, int, str]] = []  # (segment file, byte offset, what): where it is cut or corrupt

    def __iter__(self):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedRecordingWarning)
            for k, seg in enumerate(self.segments):
                reader = RecordingReader(seg, ordered=False)
                first = True
                pending: list = []
                for m in reader:
                    if first:
                        first = False
                        if k > 0 and reader.resume is not None:
                            base = Base.from_record(reader.resume)
                            self.core = core_from(base, self._incident_of(m.incident), self.settings)
                            feed(self.core, inputs_after(self.segments[:k], base.segment, base.position))
                            self.resumes.append((k, base.origin))
                        elif self.core.id != m.incident:
                            self.core = IncidentCore(self._incident_of(m.incident), self.settings)
                    if m.kind in INBOUND_KINDS:
                        pending.append(m)
                        if len(pending) >= self.round_size:
                            yield from self._round(pending)
                            pending = []
                    else:
                        yield from self._round(pending)
                        pending = []
                        yield m, []
                yield from self._round(pending)
                self.truncated = self.truncated or reader.truncated
                self.damage += [(str(seg), offset, what) for offset, what in reader.damage]

    def _round(self, pending):
        if not pending:
            return
        answers = self.core.feed_round([Inbound(m.kind, m.key, m.payload, m.receive_time) for m in pending])
        for m in pending[:-1]:
            yield m, []
        yield pending[-1], answers

    def _incident_of(self, incident_id: str):
        cfg = self.incident
        if incident_id is None or incident_id == cfg.id:
            return cfg
        return cfg.model_copy(update={"id": incident_id})


def bench_resume(responders: int = 4, minutes: float = 20.0, seed: int = 0, workdir=None, log=print) -> dict:
    """What a restart costs: ``responders`` simulated walkers for ``minutes`` recorded as the
    live service records them (rounds of 0.1 s, snapshots every 5 s into the state file), then
    ``resume`` from the newest snapshot (the service's way) and from the start of the recording
    (the other way). Figures: snapshot size and time, resume time each way, how far the two
    resumed cores are apart."""
    import tempfile

    import numpy as np

    from pdr.simulation import WalkerFleet, WalkerSettings
    from service.protocol import wire
    from service.review.recorder import IncidentRecorder

    from service.protocol.incident import default_incident

    incident = default_incident()
    names = [f"w{i:02d}" for i in range(responders)]
    fleet = WalkerFleet(responders, WalkerSettings(rate_hz=100.0), seed, responders=names, floors=(0, 0),
                        start_t=1000.0, attitude=False)
    frames = int(minutes * 600)
    tmp = tempfile.TemporaryDirectory(prefix="firetrack-resume-") if workdir is None else None
    root = Path(workdir or tmp.name)
    path = root / "incident.mcap"
    core = IncidentCore(incident)
    sf = StateFile(state_path(path), incident.id, 0)
    snap_bytes, snap_s, live_cpu = [], [], 0.0
    t_rx = 1_000_000.0
    log(f"recording {responders} walkers for {minutes:g} min ...")
    with IncidentRecorder(path, incident.id) as rec:
        for k in range(frames):
            batches = fleet.next_batches(10)
            items = []
            for name, b in zip(names, batches):
                f = wire.ImuBatch(responder=name, device="d", seq=k, t=b.t, acc=b.acc, gyr=b.gyr, mag=b.mag,
                                  pressure_t=b.pressure_t if len(b.pressure_t) else None,
                                  pressure=b.pressure if len(b.pressure_t) else None, carry="handheld")
                items.append(Inbound("imu", wire.key(incident.id, name, "imu"), wire.encode(f), t_rx))
            t_rx += 0.1
            for m in items:
                rec.write(m.key, m.payload, m.received)
            c0 = time.process_time()
            out = core.feed_round(items)
            live_cpu += time.process_time() - c0
            for o in out:
                rec.write(o.key, wire.encode(o.message), t_rx)
            if k % 50 == 49 and k < frames - 30:  # every 5 s, but not in the last 3 s: a crash loses those
                rec.flush()
                c0 = time.perf_counter()
                blob = core.snapshot()
                sf.write(blob, rec.message_count, t_rx)
                snap_s.append(time.perf_counter() - c0)
                snap_bytes.append(len(blob))
    steps = {n: r.tracker.steps for n, r in core.responders.items()}
    log("resuming from the newest snapshot ...")
    c0 = time.perf_counter()
    from_snapshot = resume(path, incident)
    t_snapshot = time.perf_counter() - c0
    state_path(path).rename(root / "kept.state")
    log("resuming from the start of the recording ...")
    c0 = time.perf_counter()
    from_start = resume(path, incident)
    t_start = time.perf_counter() - c0

    def last_pose(c):
        return {n: (r.tracker.live.x, r.tracker.live.y) for n, r in c.responders.items() if r.tracker.live is not None}

    a, b = last_pose(from_snapshot.core), last_pose(from_start.core)
    apart = max((float(np.hypot(a[n][0] - b[n][0], a[n][1] - b[n][1])) for n in a if n in b), default=None)
    result = {
        "responders": responders, "minutes": minutes, "frames": frames * responders,
        "live_cpu_s": round(live_cpu, 2), "walked_s_per_cpu_s": round(frames * 0.1 * responders / live_cpu, 1),
        "snapshot_bytes": {"first": snap_bytes[0], "last": snap_bytes[-1]},
        "snapshot_ms": {"median": round(1e3 * float(np.median(snap_s)), 2), "max": round(1e3 * max(snap_s), 2)},
        "resume_from_snapshot_s": round(t_snapshot, 3), "replayed_after_snapshot": from_snapshot.replayed,
        "resume_from_start_s": round(t_start, 3), "replayed_from_start": from_start.replayed,
        "steps_equal": {n: (steps[n], from_snapshot.core.responders[n].tracker.steps,
                            from_start.core.responders[n].tracker.steps) for n in names},
        "resumed_cores_apart_m": None if apart is None else round(apart, 4),
    }
    if tmp is not None:
        tmp.cleanup()
    return result
