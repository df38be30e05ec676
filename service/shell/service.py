"""The live service of one incident: zenoh in, one tracker per responder, poses and status out.

Data flow (keys from :mod:`service.protocol.wire`)::

    firetrack/{incident}/*/imu  ──► decode ─► FrameGate (order, duplicates, gaps) ─► ResponderTracker ─► .../pose
    firetrack/{incident}/*/fix  ──► decode ─► to local ENU (incident config) ──────────┘                  .../status (1 Hz)
    firetrack/{incident}/*/track  (queryable: the smoothed track so far)
    firetrack/{incident}/*/presence  (liveliness tokens of the wearables)

Threads. Zenoh delivers samples on its own threads; the callbacks only stamp the receive
time and queue the payload. One worker thread decodes and processes everything in arrival
order (the work is numpy and gtsam under the GIL, so more threads would not go faster), and
a timer thread publishes each responder's Status once a second. A bad payload is counted
against its responder with a reason, logged, and dropped; nothing a wearable sends can stop
the worker or reach another responder's state.
"""
from __future__ import annotations

import dataclasses
import gc
import logging
import math
import queue
import threading
import time
import zlib
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import zenoh

from pdr.events import MotionEvent, MotionState, bearing_deg
from pdr.pipeline import ImuFrame
from service.protocol import wire
from service.protocol.incident import IncidentConfig, UnknownCheckpointError
from service.core.gate import FrameGate
from service.core.tracker import CheckpointFix, PoseEstimate, ResponderTracker, TrackerSettings, tracker_settings_for

log = logging.getLogger("firetrack.service")

ALARM_MAN_DOWN = "man_down"
ALARM_LOST_CONTACT = "lost_contact"
ALARM_REJECTED = "rejected_frames"
ALARM_DISCONNECTED = "disconnected"
ALARM_RECORDING = "recording_failed"


class _Sink:
    """A publisher that keeps what it is given (the service without a session: reprocessing)."""

    def __init__(self, key: str, into: list):
        self.key, self._into = key, into

    def put(self, payload: bytes) -> None:
        self._into.append((self.key, payload))


@dataclass
class ServiceSettings:
    tracker: TrackerSettings | None = None  # None: tracker_settings_for(the incident)
    status_period_s: float = 1.0  # s between Status messages
    lost_contact_s: float = 10.0  # s without a frame -> lost-contact alarm
    rejected_window_s: float = 10.0  # s
    rejected_burst: int = 5  # rejects within the window -> alarm
    reorder_window: int = 4  # frames a late frame may be overtaken by
    entry_sigma_m: float = 50.0  # m: responders not yet placed by a checkpoint start at the origin with this σ
    max_queue: int = 200_000  # samples waiting for the worker (beyond: the callbacks block: back-pressure)
    log_rejects_per_window: int = 5  # log lines per responder and window; all are counted
    max_round: int = 5000  # messages the worker takes off the queue before it runs the trackers
    max_coalesce: int = 50  # frames of one responder run through its tracker as one batch, at most
    imu_channel: int = 20_000  # frames zenoh may hold for the worker (beyond: back-pressure to the router)
    idle_poll_s: tuple[float, float] = (0.001, 0.01)  # s the worker waits between looks when frames flow / when quiet
    warm_up: bool = True  # run a simulated responder through the whole path before subscribing (service/core/warmup.py)


@dataclass
class Responder:
    id: str
    gate: FrameGate
    tracker: ResponderTracker
    first_heard: float
    publisher_pose: object
    publisher_status: object
    seq: int = -1  # seq of the newest frame the tracker has seen
    seq_oldest: int = -1  # seq of the oldest frame in the tracker's latest batch
    backlog: list = field(default_factory=list)  # released frames waiting for the tracker (one round)
    epoch: int = 0  # the gate's stream epoch the tracker belongs to
    poses: int = 0
    rejects: deque = field(default_factory=lambda: deque(maxlen=1024))  # receive times of rejects
    fixes_rejected: dict = field(default_factory=dict)
    present: bool | None = None  # liveliness: None unknown, True token alive, False token gone
    logged: deque = field(default_factory=lambda: deque(maxlen=64))


class IncidentService:
    """The service of one incident on an open zenoh session: ``start()``, ``close()``."""

    def __init__(self, session: zenoh.Session, incident: IncidentConfig, settings: ServiceSettings | None = None,
                 recorder=None, clock=time.time, shard: tuple[int, int] = (0, 1)):
        settings = settings or ServiceSettings()
        if settings.tracker is None:  # the incident's declination and field reach the compass
            settings = dataclasses.replace(settings, tracker=tracker_settings_for(incident))
        self.session = session
        self.shard = shard  # (k, K): this worker serves the responders with in_shard(id, k, K)
        self.incident = incident
        self.id = incident.id
        self.settings = settings or ServiceSettings()
        self.recorder = recorder
        self.clock = clock
        self.responders: dict[str, Responder] = {}
        self.unattributed: dict[str, int] = {}  # rejects whose key names no valid responder
        self._queue: queue.Queue = queue.Queue(maxsize=self.settings.max_queue)
        self._stop = threading.Event()
        self._lock = threading.Lock()  # responders dict between the worker and the status/queryable threads
        self._threads: list[threading.Thread] = []
        self._decl: list = []
        self.frames_processed = 0
        self.tracker_batches = 0  # tracker calls: frames_processed / tracker_batches frames each on average
        self.received = {"imu": 0, "fix": 0}  # payloads taken by the worker, good or bad
        self.errors = 0
        self.recorder_error: str | None = None
        self.published: list[tuple[str, bytes]] = []  # offline only: (key, payload) in order
        self._rec_lock = threading.Lock()
        self._work_lock = threading.Lock()  # held by the worker per item; track queries wait for it
        self.busy_s = 0.0  # wall time the worker spent on items (the benchmark's capacity figure)
        self.pose_hook = None  # callable(responder_id, Pose, oldest seq of its batch) after each publication
        self._dirty: dict[str, Responder] = {}  # responders with frames waiting for the round's end
        self.profiler = None  # a cProfile.Profile the worker runs under, when set before start()
        self._pending_presence: dict[str, bool] = {}  # liveliness seen before the first frame
        self._imu = None  # the frames' subscriber (a zenoh FIFO channel), once started
        self._looks = 0  # times the worker looked for input ...
        self._last_busy_look = 0  # ... and the last time it found some (wait_idle)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> IncidentService:
        if self.settings.warm_up:
            from service.core.warmup import warm_up

            w = warm_up(self.incident, dataclasses.replace(self.settings, warm_up=False))
            log.info("warmed up in %.2f s (a simulated responder: %d poses, %d fixes applied)",
                     w.seconds, w.poses, w.fixes_applied)
        s = self.session
        # frames wait in zenoh's own channel until the worker takes them, with no Python
        # callback per frame: at hundreds of frames a second such callbacks queue for the GIL
        # behind the worker and hold the frames back; fixes are few and come by callback
        self._imu = s.declare_subscriber(wire.key_all(self.id, "imu"),
                                         zenoh.handlers.FifoChannel(self.settings.imu_channel))
        self._decl += [
            s.declare_subscriber(wire.key_all(self.id, "fix"), self._enqueue("fix")),
            s.declare_queryable(wire.key_all(self.id, "track"), self._on_track_query),
            s.liveliness().declare_subscriber(wire.key_all(self.id, "presence"), self._on_presence, history=True),
        ]
        # the cyclic garbage collector's full passes stall the worker for tens of ms once the
        # heap holds many trackers; what exists at start-up (modules, config) never dies, so
        # it leaves the collector's view, and young collections run less often
        gc.freeze()
        gc.set_threshold(20_000, 50, 100)
        for target, name in ((self._work, "worker"), (self._status_loop, "status")):
            th = threading.Thread(target=target, name=f"firetrack-{name}", daemon=True)
            th.start()
            self._threads.append(th)
        log.info("service for incident %r started", self.id)
        return self

    def close(self, timeout: float = 5.0) -> None:
        """Stop taking input, finish what is queued, stop the threads, undeclare everything."""
        for d in self._decl:
            try:
                d.undeclare()
            except Exception:  # already gone with a closed session
                pass
        self._decl.clear()
        self._queue.put(None)  # the worker takes the frames still in the channel first, then stops
        self._stop.set()
        for th in self._threads:
            th.join(timeout)
        self._threads.clear()
        if self._imu is not None:
            try:
                self._imu.undeclare()
            except Exception:
                pass
            self._imu = None

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until everything received so far is processed (tests, benchmarks): the worker
        has looked at its inputs since the call and found nothing left to do."""
        deadline = time.monotonic() + timeout
        seen = self._looks
        while time.monotonic() < deadline:
            if self._looks > seen + 1 and self._last_busy_look < self._looks and self._queue.unfinished_tasks == 0:
                return True
            time.sleep(0.005)
        return False

    # ------------------------------------------------------------------ zenoh callbacks
    def _enqueue(self, kind: str):
        def callback(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            if self.shard[1] > 1 and not in_shard(key, *self.shard):
                return  # another worker's responder
            self._queue.put((kind, key, sample.payload.to_bytes()))
        return callback

    def _on_presence(self, sample: zenoh.Sample) -> None:
        try:
            _, rid, _ = wire.parse_key(str(sample.key_expr))
        except ValueError:
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            r = self.responders.get(rid)
            if r is not None:
                r.present = alive
        self._pending_presence[rid] = alive
        log.info("wearable of %s %s", rid, "connected" if alive else "disconnected")

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        if self.profiler is not None:
            self.profiler.enable()
        try:
            self._work_loop()
        finally:
            if self.profiler is not None:
                self.profiler.disable()

    def _work_loop(self) -> None:
        """Rounds: take the frames waiting in zenoh's channel (up to ``max_round``), then the
        fixes and ticks queued by callbacks, then run each responder's tracker once over the
        frames it received in the round. Each message is stamped with its receive time as it
        is taken, in the order it is processed — the order a recording is read back in, so
        ``reprocess`` sees what the worker saw. Idle, a round is a frame or two; behind, the
        rounds grow and every responder's frames go through its pipeline as one batch, which
        costs far less per frame (the pipeline gives the same events for any batching), so
        the worker catches up instead of falling further behind."""
        quick, slow = self.settings.idle_poll_s
        last_frame = -math.inf
        while True:
            items = self._take_frames(self.settings.max_round)
            wait = 0.0 if items else quick if time.monotonic() - last_frame < 1.0 else slow
            taken, stop = self._take_queued(items, wait)
            self._looks += 1
            try:
                if items:
                    self._last_busy_look = self._looks
                    if items[0][0] == "imu":
                        last_frame = time.monotonic()
                    self._run_round(items)
            finally:
                for _ in range(taken):
                    self._queue.task_done()
            if stop:
                return

    def _take_queued(self, items: list, wait: float) -> tuple[int, bool]:
        """Append the fixes and ticks the callbacks queued to ``items``, waiting up to ``wait``
        s for the first. Returns how many queue entries were taken and whether one asked the
        worker to stop (the frames still in the channel are then taken too)."""
        try:
            pending = [self._queue.get(timeout=wait) if wait > 0 else self._queue.get_nowait()]
        except queue.Empty:
            return 0, False
        while len(items) + len(pending) < self.settings.max_round:
            try:
                pending.append(self._queue.get_nowait())
            except queue.Empty:
                break
        stop = None in pending
        items += [(*i[:3], self.clock()) if i[0] != "tick" else i for i in pending if i is not None]
        if stop:
            items += self._take_frames(None)
        return len(pending), stop

    def _run_round(self, items: list) -> None:
        started = time.perf_counter()
        try:
            if self.recorder is not None:
                for kind, key, payload, now in items:
                    if kind in ("imu", "fix"):
                        self._record(key, payload, now)
            with self._work_lock:
                self.feed_round(items)
        finally:
            self.busy_s += time.perf_counter() - started

    def _take_frames(self, limit: int | None) -> list:
        """Frames waiting in zenoh's channel for this worker's responders, stamped as taken."""
        out: list = []
        if self._imu is None:
            return out
        sharded = self.shard[1] > 1
        while limit is None or len(out) < limit:
            try:
                sample = self._imu.try_recv()
            except zenoh.ZError:  # undeclared (closing)
                break
            if sample is None:
                break
            key = str(sample.key_expr)
            if sharded and not in_shard(key, *self.shard):
                continue  # another worker's responder
            out.append(("imu", key, sample.payload.to_bytes(), self.clock()))
        return out

    def feed_round(self, items) -> None:
        """Messages ``(kind, key, payload, receive_time)`` taken together: each is decoded and
        gated in turn, then every responder's new frames go through its tracker as one batch
        (a fix first runs the frames that came before it). Poses are the same as from
        :meth:`feed` one message at a time, bit for bit. A message that raises is logged and
        counted in ``errors``; the others go on."""
        for item in items:
            try:
                self._take(*item)
            except Exception:  # a bug must not kill the service: log it, count it, go on
                self.errors += 1
                log.exception("error while processing %s", item[1])
        for r in self._take_dirty():
            try:
                self._run_backlog(r)
            except Exception:
                self.errors += 1
                log.exception("error while running the frames of %s", r.id)

    def _take_dirty(self) -> list[Responder]:
        dirty, self._dirty = self._dirty, {}
        return list(dirty.values())

    def feed(self, kind: str, key: str, payload: bytes, now: float) -> None:
        """Process one received message (``kind`` imu, fix or tick) synchronously: what
        ``firetrack reprocess`` calls for each recorded message (a round of one)."""
        self._take(kind, key, payload, now)
        for r in self._take_dirty():
            self._run_backlog(r)

    def _take(self, kind: str, key: str, payload: bytes, now: float) -> None:
        """Decode and gate one message; frames wait in their responder's backlog for the round's end."""
        if kind in self.received:
            self.received[kind] += 1
        if kind == "imu":
            self._handle_imu(key, payload, now)
        elif kind == "fix":
            self._handle_fix(key, payload, now)
        elif kind == "tick":
            self._expire(now)

    def _responder_of(self, key: str, now: float, reason_on_fail: str) -> Responder | None:
        try:
            _, rid, _ = wire.parse_key(key)
        except ValueError as e:
            self.unattributed[reason_on_fail] = self.unattributed.get(reason_on_fail, 0) + 1
            log.warning("rejected a sample on %r: %s", key, e)
            return None
        r = self.responders.get(rid)
        if r is None:
            r = self._new_responder(rid, now)
        return r

    def _new_responder(self, rid: str, now: float) -> Responder:
        s = self.settings
        r = Responder(
            id=rid, gate=FrameGate(reorder_window=s.reorder_window), tracker=self._tracker(rid), first_heard=now,
            publisher_pose=self._publisher(wire.key(self.id, rid, "pose")),
            publisher_status=self._publisher(wire.key(self.id, rid, "status")),
            present=self._pending_presence.get(rid),
        )
        with self._lock:
            self.responders[rid] = r
        log.info("responder %s appeared", rid)
        return r

    def _publisher(self, key: str):
        if self.session is None:  # offline (reprocess): keep what would have been published
            return _Sink(key, self.published)
        return self.session.declare_publisher(key)

    def _tracker(self, rid: str = "") -> ResponderTracker:
        """A fresh tracker; not yet placed, it starts at the incident origin with a wide σ
        until a checkpoint fix says where the responder is."""
        cfg, s = self.incident, self.settings
        entry = CheckpointFix(0.0, 0.0, 0.0, cfg.start_floor, s.entry_sigma_m, "origin (unplaced)")
        return ResponderTracker(rid, cfg.floor_elevations(), cfg.start_floor, s.tracker, entry=entry)

    def _reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A frame turned away before the gate saw it: counted there like the gate's own."""
        r.gate.count(reason, detail, now)
        self._note_reject(r, reason, detail, now)

    def _note_reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """Every reject feeds the burst alarm; the log gets at most a few lines per window."""
        r.rejects.append(now)
        while r.logged and now - r.logged[0] > self.settings.rejected_window_s:
            r.logged.popleft()
        if len(r.logged) < self.settings.log_rejects_per_window:
            r.logged.append(now)
            log.warning("%s: rejected a frame (%s): %s", r.id, reason, detail)

    def _handle_imu(self, key: str, payload: bytes, now: float) -> None:
        r = self._responder_of(key, now, "bad_key")
        if r is None:
            return
        try:
            batch = wire.decode(payload, expect=wire.ImuBatch)
        except wire.WireError as e:
            self._reject(r, e.reason, e.detail, now)
            return
        if batch.responder != r.id:
            self._reject(r, "schema", f"responder {batch.responder!r} in a frame on the key of {r.id!r}", now)
            return
        rejected_before = r.gate.rejected
        released = r.gate.offer(batch, now)
        if r.gate.rejected > rejected_before:  # the gate records why in its newest event
            _, reason, detail = r.gate.events[-1]
            self._note_reject(r, reason, f"frame {batch.seq}: {detail}", now)
        for b in released:
            self._process(r, b)

    def _process(self, r: Responder, b: wire.ImuBatch) -> None:
        if r.gate.epoch != r.epoch:  # a new stream (rebooted wearable, another device): a fresh pipeline
            self._run_backlog(r)  # the old stream's last frames end the old track
            log.warning("%s: new stream (device %s); the track restarts", r.id, b.device)
            r.epoch = r.gate.epoch
            r.tracker = self._tracker(r.id)
        if r.backlog and (not _continues(r.backlog[-1], b) or len(r.backlog) >= self.settings.max_coalesce):
            self._run_backlog(r)
        r.backlog.append(b)
        if r.tracker.fix_waiting:  # frame by frame until the fix is applied (see fix_waiting)
            self._run_backlog(r)
        else:
            self._dirty[r.id] = r

    def _run_backlog(self, r: Responder) -> None:
        """The responder's waiting frames through its tracker as one batch; poses out."""
        batches, r.backlog = r.backlog, []
        if not batches:
            return
        frame = _frame_of(batches)
        try:
            outputs = r.tracker.on_frame(frame)
        except ValueError as e:  # e.g. a frame the gate let through that the pipeline cannot take
            if len(batches) > 1:  # the check comes before any state changes: find the culprit alone
                for b in batches:
                    r.backlog = [b]
                    self._run_backlog(r)
                return
            self._reject(r, "pipeline", f"frame {batches[0].seq}: {e}", self.clock())
            return
        r.seq, r.seq_oldest = batches[-1].seq, batches[0].seq
        self.frames_processed += len(batches)
        self.tracker_batches += 1
        for o in outputs:
            if isinstance(o, PoseEstimate):
                self._publish_pose(r, o)
            elif isinstance(o, MotionEvent):
                log.info("%s is %s since device time %.1f", r.id, o.state.value, o.since)

    def _handle_fix(self, key: str, payload: bytes, now: float) -> None:
        r = self._responder_of(key, now, "bad_key")
        if r is None:
            return
        try:
            fix = wire.decode(payload, expect=wire.Fix)
            domain = self._to_domain(fix)
        except wire.WireError as e:
            self._count_fix_reject(r, e.reason, e.detail)
            return
        except (UnknownCheckpointError, KeyError, ValueError) as e:
            self._count_fix_reject(r, "unknown_reference", str(e))
            return
        if fix.responder != r.id:
            self._count_fix_reject(r, "schema", f"responder {fix.responder!r} in a fix on the key of {r.id!r}")
            return
        self._run_backlog(r)  # the frames that came before the fix go first
        pose = r.tracker.on_fix(domain)
        log.info("%s: %s fix at device time %.2f%s", r.id, fix.source, fix.t, " applied" if pose else " queued")
        if pose is not None:
            self._publish_pose(r, pose)

    def frame_accounting(self) -> dict[str, int]:
        """Over all responders: frames rejected by reason, declared lost, still held by a gate."""
        out: dict[str, int] = dict(self.unattributed)
        with self._lock:
            responders = list(self.responders.values())
        for r in responders:
            for reason, n in r.gate.counts.items():
                out[reason] = out.get(reason, 0) + n
            out["lost"] = out.get("lost", 0) + r.gate.lost
            out["held"] = out.get("held", 0) + r.gate.held + len(r.backlog)
        return {k: v for k, v in out.items() if v}

    def _count_fix_reject(self, r: Responder, reason: str, detail: str) -> None:
        r.fixes_rejected[reason] = r.fixes_rejected.get(reason, 0) + 1
        log.warning("%s: fix rejected (%s): %s", r.id, reason, detail)

    def _to_domain(self, fix: wire.Fix):
        cfg = self.incident
        if fix.source == "checkpoint":
            if fix.name is not None:
                cp = cfg.checkpoint(fix.name)
                floor = fix.floor if fix.floor is not None else cp.floor
                return CheckpointFix(fix.t, cp.x, cp.y, floor, fix.sigma or cp.sigma_m, cp.name)
            return CheckpointFix(fix.t, fix.x, fix.y, fix.floor, fix.sigma or 0.5, None)
        from service.fusion import GnssFix, UwbRange

        if fix.source == "gnss":
            x, y, _ = cfg.to_enu(fix.lat, fix.lon)
            return GnssFix(t=fix.t, x=float(x), y=float(y), accuracy=fix.accuracy)
        anchor = next((a for a in cfg.uwb_anchors if a.id == fix.anchor), None)
        if anchor is None:
            known = ", ".join(a.id for a in cfg.uwb_anchors) or "none configured"
            raise KeyError(f"UWB anchor {fix.anchor!r} is not in the incident config (known: {known})")
        return UwbRange(t=fix.t, anchor_x=anchor.x, anchor_y=anchor.y, range=fix.range, sigma=fix.sigma, anchor=anchor.id)

    # ------------------------------------------------------------------ output
    def _publish_pose(self, r: Responder, p: PoseEstimate) -> None:
        lat, lon, _ = self.incident.to_geodetic(p.x, p.y)
        cov = np.asarray(p.cov, float)
        cov = 0.5 * (cov + cov.T)
        msg = wire.Pose(
            responder=r.id, t=p.t, x=p.x, y=p.y, floor=int(p.floor), lat=float(lat), lon=float(lon),
            heading_deg=bearing_deg(p.heading) if math.isfinite(p.heading) else 0.0, cov=cov, steps=p.steps,
            source=p.source, seq=max(r.seq, 0), published_at=self.clock(),
        )
        payload = wire.encode(msg)
        r.publisher_pose.put(payload)
        r.poses += 1
        if self.pose_hook is not None:
            self.pose_hook(r.id, msg, r.seq_oldest)
        if self.recorder is not None:
            self._record(wire.key(self.id, r.id, "pose"), payload, msg.published_at)

    def status_of(self, r: Responder, now: float) -> wire.Status:
        s = self.settings
        pl = r.tracker.pipeline
        alarms = []
        if pl.state is MotionState.NO_MOTION:
            alarms.append(ALARM_MAN_DOWN)
        heard = r.gate.last_heard if r.gate.last_heard is not None else r.first_heard
        if now - heard > s.lost_contact_s:
            alarms.append(ALARM_LOST_CONTACT)
        if sum(1 for t in r.rejects if now - t <= s.rejected_window_s) >= s.rejected_burst:
            alarms.append(ALARM_REJECTED)
        if r.present is False:
            alarms.append(ALARM_DISCONNECTED)
        if self.recorder_error is not None:
            alarms.append(ALARM_RECORDING)
        t_dev = pl.last_time if math.isfinite(pl.last_time) else 0.0
        since = pl.state_since if math.isfinite(pl.state_since) else t_dev
        rejected = dict(r.gate.counts)
        for reason, n in r.fixes_rejected.items():
            rejected[f"fix_{reason}"] = n
        for reason, n in (("fix_gated", r.tracker.fixes_rejected), ("fix_unused", r.tracker.fixes_unused)):
            if n:
                rejected[reason] = n
        return wire.Status(
            responder=r.id, t=t_dev, motion=pl.state.value, motion_since=since, alarms=alarms,
            rejected=rejected, frames=r.gate.accepted, gaps=r.gate.gaps, last_heard=heard, steps=pl.steps,
        )

    def _status_loop(self) -> None:
        period = self.settings.status_period_s
        while not self._stop.wait(period):
            now = self.clock()
            with self._lock:
                responders = list(self.responders.values())
            for r in responders:
                try:
                    msg = self.status_of(r, now)
                    payload = wire.encode(msg)
                    r.publisher_status.put(payload)
                    if self.recorder is not None:
                        self._record(wire.key(self.id, r.id, "status"), payload, now)
                except Exception:
                    log.exception("status of %s", r.id)
            # frames held back for a missing seq longer than the gate allows: the worker releases them
            self._queue.put(("tick", "", b"", now))

    def _expire(self, now: float) -> None:
        for r in list(self.responders.values()):
            for b in r.gate.expire(now):
                self._process(r, b)

    # ------------------------------------------------------------------ track queryable
    def track_of(self, r: Responder) -> bytes:
        sm = r.tracker.smoothed_track()
        if sm is None or len(sm["t"]) == 0:
            pts = r.tracker.pdr_track
            arr = np.array(pts, float).reshape(-1, 4)
            sm = {"t": arr[:, 0], "x": arr[:, 1], "y": arr[:, 2], "floor": arr[:, 3],
                  "heading": np.full(arr.shape[0], np.nan)}
            smoothed = False
        else:
            smoothed = True
        return wire.encode_track(r.id, sm, smoothed)

    def _on_track_query(self, query: zenoh.Query) -> None:
        with self._lock:
            responders = list(self.responders.values())
        for r in responders:  # each worker answers for its own responders; zenoh merges the replies
            k = wire.key(self.id, r.id, "track")
            if not zenoh.KeyExpr(k).intersects(query.key_expr):
                continue
            try:
                with self._work_lock:  # the worker changes the smoother; read it between items
                    track = self.track_of(r)
                query.reply(k, track)
            except Exception:
                log.exception("track query for %s", r.id)

    def _record(self, key: str, payload: bytes, now: float) -> None:
        if self.recorder_error is not None:
            return  # reported once, and in every Status since
        try:
            with self._rec_lock:  # zenoh callbacks, the worker and the status thread all record
                self.recorder.write(key, payload, now)
                self.recorder.flush_if_due(now)
        except Exception as e:  # a full disk must be loud, not silent
            self.recorder_error = str(e)
            log.error("recording failed, the incident is no longer being recorded: %s", e)


def in_shard(key_or_id: str, k: int, n: int) -> bool:
    """Does the responder of this key (or id) belong to worker ``k`` of ``n``? A stable hash
    of the responder id (CRC-32), so every worker agrees without talking to the others."""
    parts = key_or_id.split("/")
    rid = parts[2] if len(parts) == 4 else key_or_id
    return zlib.crc32(rid.encode()) % n == k


def _continues(prev: wire.ImuBatch, b: wire.ImuBatch) -> bool:
    """Can ``b`` join ``prev`` in one pipeline batch: later samples, the same sensors."""
    return (prev.mag is None) == (b.mag is None) and len(b.t) > 0 and len(prev.t) > 0 and b.t[0] > prev.t[-1]


def _frame_of(batches: list[wire.ImuBatch]) -> ImuFrame:
    """One pipeline frame of consecutive wire frames (see :func:`_continues`)."""
    if len(batches) == 1:
        b = batches[0]
        return ImuFrame(b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure)

    def cat(name):
        parts = [getattr(b, name) for b in batches if getattr(b, name) is not None]
        return np.concatenate(parts) if parts else None

    pt = [b.pressure_t for b in batches if b.pressure_t is not None and b.pressure is not None]
    pv = [b.pressure for b in batches if b.pressure_t is not None and b.pressure is not None]
    return ImuFrame(cat("t"), cat("acc"), cat("gyr"), cat("mag"),
                    np.concatenate(pt) if pt else None, np.concatenate(pv) if pv else None)


decode_track = wire.decode_track  # the reply format lives with the wire format
