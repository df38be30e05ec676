"""The zenoh shell of one incident: sessions, subscriptions, the worker thread, the recorder.

Everything an incident decides happens in :class:`service.core.incident_core.IncidentCore`;
this shell only moves messages between zenoh and the core, and stamps the time::

    firetrack/{incident}/*/imu       FIFO channel ─┐  (advanced subscribers: a wearable's kept frames
    firetrack/{incident}/*/fix       FIFO channel ─┤   are fetched on detection and after a miss)
    firetrack/{incident}/*/presence  liveliness ───┤  worker thread: intake ─► record ─► IncidentCore ─► .../pose
    firetrack/{incident}/*/command   callback ─────┤                                                  ├► .../status
    firetrack/{incident}/*/ack       callback ─────┤                                                  └► .../audit
    firetrack/{incident}/*/op        callback ─────┤
    access policy (roster) ── inject ──────────────┤
    status timer (1 Hz) ── tick ───────────────────┘
    firetrack/{incident}/*/track     queryable: the core's track of the responder

Threads. Frames and fixes wait in zenoh's own FIFO channels until the worker takes them (no
Python callback per message, so a flood of them never queues for the GIL behind the worker);
presence and the once-a-second tick come by callback through a queue. The worker asks the
core's intake about each message by its key and size before copying its payload
(:meth:`IncidentCore.admit`: size, admission of new ids, per-source budget), stamps what it
takes with the service clock, records it (the order a recording is read back in is the order
the core saw), feeds the core a round at a time and publishes what the core answers. Track
queries read the core between rounds.

Delivery. Both subscribers are zenoh's *advanced* subscribers (``zenoh.ext``): a wearable's
advanced publisher keeps its last frames (:mod:`client.wearable`), and the subscriber fetches
them when it detects the publisher (a service that starts or restarts after the wearable) and
whenever the publisher's heartbeat shows samples it missed (an outage, a router restart), in
order. What could not be fetched any more is a gap in the seq numbers, counted by the frame
gate (``Status.lost``); zenoh's own miss reports are counted in ``missed``.

Shards. With ``--workers K > 1`` a worker subscribes to its own responders' keys only, each
declared when that responder's presence token appears (:mod:`service.shell.shard_routes`);
the diagram's wildcards are then the presence and the few callback kinds.

Snapshots. With a recorder and a state file (:class:`service.review.resume.StateFile`), the
worker writes the core's snapshot beside the recording every ``snapshot_every_s`` after a
round, once what the core has seen is safely in the recording; ``serve`` resumes from it.
With a ``snapshot_feed`` it also puts them on zenoh while a standby follows, and its
``fence`` (its epoch) stops every publication once a service of a higher epoch took over
(:mod:`service.shell.standby`).
"""
from __future__ import annotations

import gc
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field

import msgpack
import zenoh

from service.core.incident_core import CoreSettings, Inbound, IncidentCore, Outbound
from service.protocol import wire
from service.protocol.incident import IncidentConfig
from service.review.recorder import as_recorded
from service.shell.round_intake import RoundIntake
from service.shell.shard_routes import ShardRoutes
from service.shell.sharding import in_shard, owns
from service.shell.snapshots import SnapshotWriter, fix_mmap_threshold, return_memory

log = logging.getLogger("firetrack.service")


@dataclass
class ServiceSettings:
    core: CoreSettings = field(default_factory=CoreSettings)
    status_period_s: float = 1.0  # s between Status messages
    max_queue: int = 100_000  # presence changes and ticks waiting for the worker (beyond: the oldest presence goes)
    max_round: int = 5000  # messages the worker takes before it runs the core
    imu_channel: int = 20_000  # frames zenoh may hold for the worker (beyond: back-pressure to the router)
    fix_channel: int = 5_000  # fixes zenoh may hold for the worker
    history_frames: int = 3000  # frames asked of a wearable's keep when it is detected or missed some
    snapshot_every_s: float = 5.0  # s between snapshots of the core beside the recording (with a state file)
    snapshot_batch: int = 32  # responders pickled afresh per round while a snapshot waits (service/shell/snapshots.py)
    idle_poll_s: tuple[float, float] = (0.001, 0.01)  # s the worker waits between looks when frames flow / when quiet
    look_every_s: float = 0.005  # s between the starts of two looks at least: a look at a worker's routes tries
    # every route's channel (500 routes: ~1 ms), so looks back to back would spend the core on empty channels
    warm_up: bool = True  # run a simulated responder through the core before subscribing (service/core/warmup.py)
    catch_all: bool = False  # --workers > 1: also the incident's wildcard, for sources without a presence token
    mmap_threshold_bytes: int | None = 128 * 1024  # bytes: larger blocks mapped alone, returned when freed (None: glibc's)
    slow_s_per_frame: float = 0.0  # s the worker idles per message it takes (tests: a worker that cannot keep up)
    behind_warn_s: float = 1.0  # s: the service's lag (service.core.lag) from which the log says it is behind


def _recorded_clock(clock):
    """``clock`` read as a recording keeps it (:func:`service.review.recorder.as_recorded`)."""
    def now() -> float:
        return as_recorded(clock())
    return now


class IncidentService(SnapshotWriter):
    """The service of one incident on an open zenoh session: ``start()``, ``close()``. It holds
    its frames' subscribers (``routes``: :class:`ShardRoutes`) and what its worker takes into a
    round (``rounds``: :class:`RoundIntake`)."""

    def __init__(self, session: zenoh.Session, incident: IncidentConfig, settings: ServiceSettings | None = None,
                 recorder=None, clock=time.time, shard: tuple[int, int] = (0, 1), core: IncidentCore | None = None,
                 state_file=None, access: wire.Access | None = None, actor: str = "service"):
        if session is None:
            raise ValueError("IncidentService needs an open zenoh session; offline, use service.core.IncidentCore")
        self.session = session
        self.settings = settings or ServiceSettings()
        self.core = core if core is not None else IncidentCore(incident, self.settings.core)
        self.state_file = state_file  # service.review.resume.StateFile: snapshots beside the recording
        self.missed = 0  # samples zenoh reported missed (its sample-miss detection)
        self.snapshots = 0
        self.snapshot_error: str | None = None
        self._last_snapshot = -math.inf
        self._snapshot_writer: threading.Thread | None = None  # writes (and fsyncs) the newest snapshot's bytes
        self.snapshots_skipped = 0  # snapshots not written because the previous one was still being written
        self.snapshots_deferred = 0  # rounds a due snapshot waited while a crowd's pickles were made
        self._expired_seen = 0
        self.queue_dropped = 0  # callbacks' messages dropped because the worker's queue was full
        self.incident = incident
        self.id = incident.id
        self.shard = shard  # (k, K): this worker serves the responders with in_shard(id, k, K)
        self.actor = actor  # this service's identity (its certificate's name with --tls): the key of its access record
        self.recorder = recorder
        self.recorder_error: str | None = None
        # what the core is told of time is what the recording will say (whole ns): live = reprocess
        self.clock = clock = _recorded_clock(clock)
        self.busy_s = 0.0  # wall time the worker spent on rounds (the benchmark's capacity figure)
        self.behind_s = 0.0  # s: how far behind the core's input is, as of the last tick (service.core.lag)
        self.behind_max_s = 0.0  # ... the most it was
        self.pose_hook = None  # callable(responder_id, Pose, oldest seq of its batch) after each publication
        self.profiler = None  # a cProfile.Profile the worker runs under, when set before start()
        self._queue: queue.Queue = queue.Queue(maxsize=self.settings.max_queue)
        self._stop = threading.Event()
        self._core_lock = threading.Lock()  # the worker holds it per round; track queries wait for it
        self._rec_lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._decl: list = []
        self._publishers: dict[str, object] = {}
        self.routes = ShardRoutes(session, self.id, self.settings, shard, self._on_miss)  # the frames' subscribers
        self.rounds = RoundIntake(self.core, clock, shard, self.routes, self._queue, self.settings.max_round)
        self.access = access  # the policy fed to the core before any input (None: the open demo)
        self.fence = None  # service.shell.standby.Fence: this service's epoch; fenced, it publishes no more
        self.snapshot_feed = None  # service.shell.standby.SnapshotFeed: snapshots to a standby that follows
        self.fenced_dropped = 0  # messages not published because a service of a higher epoch took over
        self._looks = 0  # times the worker looked for input ...
        self._last_busy_look = 0  # ... and the last time it found some (wait_idle)

    @property
    def heard(self) -> dict[str, int]:
        """Samples taken from the frames' subscribers, by owner (``own``: this worker's responders)."""
        return self.rounds.heard

    # ------------------------------------------------------------------ what the core counts
    @property
    def responders(self):
        return self.core.responders

    @property
    def frames_processed(self) -> int:
        return self.core.counters.frames_processed

    @property
    def tracker_batches(self) -> int:
        return self.core.counters.tracker_batches

    @property
    def received(self) -> dict:
        return self.core.counters.received

    @property
    def errors(self) -> int:
        return self.core.counters.errors

    def frame_accounting(self) -> dict[str, int]:
        with self._core_lock:
            return self.core.frame_accounting()

    # ------------------------------------------------------------------ lifecycle
    def start(self, cancel=None) -> IncidentService:
        """Warm up, subscribe, start the worker threads. ``cancel`` (the command's stop event)
        cuts the warm-up short: the caller looks at it again before serving."""
        fix_mmap_threshold(self.settings.mmap_threshold_bytes)  # freed big buffers go back (snapshots.py)
        if self.settings.warm_up:
            from service.core.warmup import warm_up

            w = warm_up(self.incident, self.settings.core, cancel=cancel)
            log.info("warmed up in %.2f s (a simulated responder: %d poses, %d fixes applied)",
                     w.seconds, w.poses, w.fixes_applied)
        if self.access is not None:  # the policy is the core's (and the recording's) first input
            self._run_round([Inbound("access", self._access_key(), wire.encode(self.access), self.clock())], 0)
        s = self.session
        self.routes.declare()  # the wildcard, or routes per announced responder (shard_routes.py)
        self._decl += [
            s.declare_subscriber(wire.key_all(self.id, "command"), self._enqueue),
            s.declare_subscriber(wire.key_all(self.id, "ack"), self._enqueue),
            s.declare_subscriber(wire.anchor_fix_all(self.id), self._enqueue),  # anchors' fixes: fix-{anchor}
            s.declare_subscriber(wire.key_all(self.id, "op"), self._enqueue_op),
            s.declare_queryable(wire.key_all(self.id, "track"), self._on_track_query),
            s.liveliness().declare_subscriber(wire.key_all(self.id, "presence"), self._on_presence, history=True),
        ]
        # the cyclic garbage collector's full passes stall the worker for tens of ms once the
        # heap holds many trackers; what exists at start-up (modules, config) never dies, so
        # it leaves the collector's view, and young collections run less often
        gc.freeze()
        gc.set_threshold(20_000, 50, 100)
        for target, name in ((self._work, "worker"), (self._tick_loop, "status")):
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
        if self._snapshot_writer is not None:
            self._snapshot_writer.join(timeout)
        self.routes.close()

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
    def _enqueue(self, sample: zenoh.Sample) -> None:
        """Anchors' fixes, orders and acknowledgements: few, so they come by callback. The key is
        read here, once (kind and responder from it); its parts go with the message to the core."""
        key = str(sample.key_expr)
        parts = wire.read_key(key)
        if owns(parts, *self.shard):
            if isinstance(parts, ValueError):  # not a key: its kind is the subscriber's (the intake refuses it)
                last = key.rsplit("/", 1)[-1]
                kind = "fix" if last.startswith(wire.ANCHOR_FIX) else last
            else:
                kind = parts.kind
            self._put_nowait((kind, key, sample.payload.to_bytes(), parts))

    def _put_nowait(self, item) -> None:
        """A callback's message to the worker's queue; a storm of them must not block zenoh's
        threads (and everyone's frames behind them): beyond the queue's bound it is dropped,
        counted and logged (the intake judges the rest when the worker takes them)."""
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.queue_dropped += 1
            if self.queue_dropped in (1, 10, 100) or self.queue_dropped % 10_000 == 0:
                log.warning("%d message(s) dropped (%s on %s): the worker's queue is full", self.queue_dropped,
                            item[0], item[1][:120])

    def _enqueue_op(self, sample: zenoh.Sample) -> None:
        """An operator action: the worker of the responder it is about takes it (an action
        about no responder, worker 0). Its key names the actor, so the payload says whom."""
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        if self.shard[1] > 1:
            try:
                about = msgpack.unpackb(payload, raw=False).get("responder")
            except Exception:  # not a map: the core refuses it; worker 0 records it
                about = None
            mine = in_shard(about, *self.shard) if isinstance(about, str) else self.shard[0] == 0
            if not mine:
                return
        self._put_nowait(("op", key, payload, wire.read_key(key)))

    def update_access(self, access: wire.Access) -> None:
        """A new access policy (the roster changed): the core enforces it from the next round on."""
        self.access = access
        self._queue.put(("access", self._access_key(), wire.encode(access), None))

    def _access_key(self) -> str:
        return wire.key(self.id, self.actor, "access")

    def _on_presence(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = wire.read_key(key)
        if owns(parts, *self.shard):
            try:
                self._queue.put_nowait(("presence", key, b"1" if sample.kind == zenoh.SampleKind.PUT else b"0", parts))
            except queue.Full:  # a storm of liveliness tokens must not block zenoh's threads
                log.warning("presence of %s dropped: the worker's queue is full", key[:120])

    def _on_miss(self, miss) -> None:
        self.missed += miss.nb
        log.warning("zenoh reports %d sample(s) missed from publisher %s (not recoverable from its keep; the gate "
                    "counts the frames as lost)", miss.nb, miss.source)

    def _tick_loop(self) -> None:
        while not self._stop.wait(self.settings.status_period_s):
            self._queue.put(("tick", "", b"", None))

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
        """Rounds: take the frames waiting in zenoh's channel (up to ``max_round``), then what
        the callbacks queued, stamp each with the clock as it is taken, and feed the core.
        Idle, a round is a frame or two; behind, the rounds grow and every responder's frames
        go through its pipeline as one batch, which costs far less per frame, so the worker
        catches up instead of falling further behind."""
        quick, slow = self.settings.idle_poll_s
        last_frame = last_look = -math.inf
        while True:
            if self.routes.routes:  # many channels to look at: at most one look per look_every_s
                rest = self.settings.look_every_s - (time.monotonic() - last_look)
                if rest > 0:
                    self._stop.wait(rest)
                last_look = time.monotonic()
            items = self.rounds.take_frames(self.settings.max_round)
            wait = 0.0 if items else quick if time.monotonic() - last_frame < 1.0 else slow
            taken, ticks, stop = self.rounds.take_queued(items, wait)
            self._looks += 1
            try:
                if items or ticks:
                    self._last_busy_look = self._looks
                    if items and items[0].kind == "imu":
                        last_frame = time.monotonic()
                    self._run_round(items, ticks)
            finally:
                for _ in range(taken):
                    self._queue.task_done()
            if stop:
                return


    def _run_round(self, items: list[Inbound], ticks: int) -> None:
        started = time.perf_counter()
        try:
            if self.settings.slow_s_per_frame:  # a slower machine: the round's work takes this much longer
                time.sleep(self.settings.slow_s_per_frame * len(items))
            for m in items:
                self._record(m.key, m.payload, m.received)
            with self._core_lock:
                self.core.recording_failed = self.recorder_error is not None
                out = self.core.feed_round(items, stamp=self.clock) if items else []
                if ticks:
                    out += self.core.tick(self.clock(), stamp=self.clock)
            self._publish(out)
            if ticks:
                self._note_behind(self.core.behind_s(self.clock()))
                self._forget_publishers()
                self.routes.forget(self.core.responders)
                gone = self.core.counters.expired + self.core.counters.newcomers_forgotten
                if gone != self._expired_seen:  # responders or newcomers left: their memory goes back
                    self._expired_seen = gone
                    return_memory()
            self._snapshot_if_due()
        finally:
            self.busy_s += time.perf_counter() - started

    def _note_behind(self, lag: float) -> None:
        """The service's lag after a tick; the log says when it passes ``behind_warn_s`` and when it is back."""
        warn = self.settings.behind_warn_s
        if (lag >= warn) != (self.behind_s >= warn):
            (log.warning if lag >= warn else log.info)("the service is %s: its frames come %.1f s late",
                                                       "behind" if lag >= warn else "back in time", lag)
        self.behind_s = lag
        self.behind_max_s = max(self.behind_max_s, lag)

    def _forget_publishers(self) -> None:
        """Publishers of responders the core let go (expired) are undeclared: bounded state."""
        gone = [k for k in self._publishers if k.split("/")[2] not in self.core.responders]
        for k in gone:
            try:
                self._publishers.pop(k).undeclare()
            except Exception:
                pass


    # ------------------------------------------------------------------ output
    def _publish(self, out: list[Outbound]) -> None:
        fence = self.fence
        if fence is not None and fence.fenced.is_set():  # another service publishes for these responders now
            self.fenced_dropped += len(out)
            return
        tag = fence.tag if fence is not None else None  # who published: the attachment names the epoch
        for o in out:
            msg = o.message  # a Pose carries its one stamp: the clock as the core made it (PoseOutput.take)
            payload = wire.encode(msg)
            pub = self._publishers.get(o.key)
            if pub is None:
                pub = self._publishers[o.key] = self.session.declare_publisher(o.key)
            try:
                pub.put(payload, attachment=tag)
            except Exception:
                log.exception("publishing on %s", o.key)
            if isinstance(msg, wire.Pose) and self.pose_hook is not None:
                r = self.core.responders.get(msg.responder)
                self.pose_hook(msg.responder, msg, r.seq_oldest if r is not None else -1)
            self._record(o.key, payload, msg.published_at if isinstance(msg, wire.Pose) else self.clock())

    def _on_track_query(self, query: zenoh.Query) -> None:
        with self._core_lock:
            rids = list(self.core.responders)
        for rid in rids:  # each worker answers for its own responders; zenoh merges the replies
            k = wire.key(self.id, rid, "track")
            if not zenoh.KeyExpr(k).intersects(query.key_expr):
                continue
            try:
                with self._core_lock:  # the worker changes the smoother; read it between rounds
                    t = self.core.track(rid)
                query.reply(k, wire.encode_track(rid, t["track"], t["smoothed"]))
            except Exception:
                log.exception("track query for %s", rid)

    def _record(self, key: str, payload: bytes, now: float) -> None:
        if self.recorder is None or self.recorder_error is not None:
            return  # a failure is reported once, and in every Status since
        try:
            with self._rec_lock:
                self.recorder.write(key, payload, now)
                self.recorder.flush_if_due(now)
        except Exception as e:  # a full disk must be loud, not silent
            self.recorder_error = str(e)
            log.error("recording failed, the incident is no longer being recorded: %s", e)


decode_track = wire.decode_track  # the reply format lives with the wire format
