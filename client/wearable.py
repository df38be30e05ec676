"""A wearable that publishes a real recording: ``firetrack wearable --responder ID --replay FILE``.

What a phone or IMU on a responder would send (:func:`service.protocol.messages.recording_messages`),
at the recording's own pace (or ``speed`` times faster). A liveliness token on
``.../presence`` says the wearable is connected.

Frame ``k`` leaves at ``start + (t_end,k − t_0) / speed`` of the wall clock, so a replay at
``speed=10`` lasts a tenth of the recording.

Delivery you can count
----------------------
* **Kept frames, resent after an outage.** Frames and fixes go out through zenoh's *advanced
  publishers* (``zenoh.ext``): each keeps its last ``keep_frames`` frames (``keep_fixes``
  fixes), a bounded buffer, and announces its newest sequence number by heartbeat. The
  service's advanced subscriber notices what it missed (a Wi-Fi outage, a router restart, a
  service that started or restarted later) and fetches it from the keep, in order.
* **Resent on request.** The wearable also keeps its last ``keep_frames`` encoded frames itself.
  When the service's ``Status`` names frames it is waiting for (``missing``: a gap it could
  not fill from zenoh's recovery, e.g. after a service restart whose history reply lost the
  race with the live frames), the wearable puts them again from this keep, in order, on a
  thread of its own (a frame at most once per ``RESEND_EVERY_S``).
* **Acknowledgement.** The service's ``Status`` of this responder says the newest frame it has
  taken of this wearable's stream (``device``, ``boot``, ``seq``); the wearable reads it, so
  it knows what is still unacknowledged, and what it can no longer resend (older than its
  keep: :meth:`Wearable.delivery`).
* **Exit.** :meth:`Wearable.close` waits up to ``flush_s`` for the service to acknowledge the
  last frame sent, and returns what was not acknowledged, so an exit never loses frames
  silently.
* **Streams.** Every start of a wearable has its own ``boot`` id (:attr:`ImuBatch.boot`): the
  service continues the responder's track as a new stream after a restart, instead of taking
  the new frames for duplicates of the old.

The matching status of the frames' key says whether a service is subscribed at all
(``on_matching``); frames published while none was are counted in ``unheard`` (they are in
the keep, and a service that starts within it fetches them).
"""
from __future__ import annotations

import math
import queue
import secrets
import threading
import time
from collections.abc import Callable

import zenoh
import zenoh.ext as zext

from pdr.io import load
from service.protocol import wire
from service.protocol.messages import BLE_SCAN_S, recording_messages
from service.protocol.pacing import paced

MATCHING_WAIT_S = 1.5  # s a replay waits for a service to match its frames before it warns
KEEP_FRAMES = 3000  # frames a wearable keeps for resending (5 min at 10 frames/s; ~2.5 MB in zenoh's keep, as much in its own)
KEEP_FIXES = 200  # fixes it keeps
HEARTBEAT_S = 0.5  # s between announcements of the newest seq (only when it changed)
FLUSH_S = 5.0  # s an exiting wearable waits for the service to acknowledge its last frame
RESEND_EVERY_S = 0.5  # s before a frame is resent again (the service repeats what it misses in every Status)
RESEND_JOIN_S = 2.0  # s closing waits for the resend thread to leave its current put


class Wearable:
    """A zenoh client publishing one responder's messages; ``close()`` withdraws its presence.

    It knows whether anybody listens: zenoh's matching status of the frames' key says whether a
    subscriber (the service) matches ``firetrack/{incident}/{responder}/imu``. ``on_matching(bool)``
    is called when that changes, and frames published while nobody listened are counted in
    ``unheard``. ``delivery()`` says what the service has acknowledged.
    """

    def __init__(self, session: zenoh.Session, incident_id: str, responder: str, on_matching=None,
                 keep_frames: int = KEEP_FRAMES, keep_fixes: int = KEEP_FIXES, boot: str | None = None,
                 on_command=None, auto_ack: bool = True, zenoh_keep: bool = True):
        if keep_frames < 1 or keep_fixes < 1:
            raise ValueError("keep_frames and keep_fixes must be at least 1")
        self.session = session
        self.responder = responder
        self.boot = boot or secrets.token_hex(8)  # this start of the wearable (ImuBatch.boot)
        self.keep_frames = keep_frames
        qos = dict(congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE)
        beat = zext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S)

        def advanced(kind: str, keep: int):
            if not zenoh_keep:  # a device without zenoh's advanced publisher: only the resend on request fills gaps
                return session.declare_publisher(wire.key(incident_id, responder, kind), **qos)
            return zext.declare_advanced_publisher(session, wire.key(incident_id, responder, kind),
                                                   cache=zext.CacheConfig(keep), sample_miss_detection=beat,
                                                   publisher_detection=True, **qos)

        self._pub = {"imu": advanced("imu", keep_frames), "fix": advanced("fix", keep_fixes),
                     "truth": session.declare_publisher(wire.key(incident_id, responder, "truth"), **qos)}
        # an advanced publisher has no matching status: a plain publisher on the frames' key
        # that never publishes tells whether a service subscribes
        self._probe = session.declare_publisher(wire.key(incident_id, responder, "imu"))
        self._token = session.liveliness().declare_token(wire.key(incident_id, responder, "presence"))
        self.sent = {"imu": 0, "fix": 0, "truth": 0}
        self.unheard = {"imu": 0, "fix": 0}
        self._lock = threading.Lock()
        self._seqs: list[int] = []  # seq of every frame sent, in order (device, boot) of this wearable
        self._kept: dict[int, bytes] = {}  # the last keep_frames encoded frames by seq, oldest first
        self._kept_since = None  # seq -> frame of the frames sent by other means than send() (keep_sent)
        self._resent_at: dict[int, float] = {}  # seq -> when it was last resent (not again within RESEND_EVERY_S)
        self.resent = 0  # frames put again on the service's request
        self._resends: queue.Queue = queue.Queue(maxsize=8)
        self._closing = threading.Event()
        # started on the first resend request: a simulator with a thousand wearables keeps no idle threads
        self._resender: threading.Thread | None = None
        self._device: str | None = None
        self.acked_seq: int | None = None  # newest seq the service said it took (or counted lost)
        self.service_lost = 0  # frames the service counts lost for this responder (its Status)
        self._acked = threading.Condition(self._lock)
        self._on_matching = on_matching
        self._listener = self._probe.declare_matching_listener(self._matching_changed) if on_matching else None
        self._status = session.declare_subscriber(wire.key(incident_id, responder, "status"), self._on_status)
        self._ack = session.declare_publisher(wire.key(incident_id, responder, "ack"), **qos)
        self._on_command, self._auto_ack = on_command, auto_ack
        self.commands: list[wire.Command] = []  # orders received (roll calls, evacuation)
        self._orders = session.declare_subscriber(wire.key(incident_id, responder, "command"), self._command)

    def _command(self, sample) -> None:
        """A roll call or an evacuation order: this wearable acknowledges it (a replay or a
        simulator on its own; a real device when its wearer presses the button)."""
        try:
            cmd = wire.decode(sample.payload.to_bytes(), expect=wire.Command)
        except wire.WireError:
            return
        self.commands.append(cmd)
        if self._on_command is not None:
            self._on_command(cmd)
        if self._auto_ack:
            self.acknowledge(cmd)

    def acknowledge(self, cmd: wire.Command) -> None:
        self._ack.put(wire.encode(wire.Ack(responder=self.responder, id=cmd.id, action=cmd.action, at=time.time())))

    def answer_prompt(self, t: float, prompt: str = "man-down") -> None:
        """The wearer answered the man-down prompt ("I'm OK") at device time ``t`` (the frames'
        clock): the service starts its no-motion clock again from ``t``."""
        self._ack.put(wire.encode(wire.Ack(responder=self.responder, id=prompt, action="ok", at=time.time(), t=t)))

    @property
    def heard(self) -> bool:
        """True while a subscriber (the service) matches this wearable's frames."""
        return bool(self._probe.matching_status.matching)

    def _matching_changed(self, status) -> None:
        if self._on_matching is not None:
            self._on_matching(bool(status.matching))

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            st = wire.decode(sample.payload.to_bytes(), expect=wire.Status)
        except wire.WireError:
            return
        with self._lock:
            if st.seq is not None and st.boot == self.boot and st.device == self._device:
                if self.acked_seq is None or st.seq > self.acked_seq:
                    self.acked_seq = st.seq
                self.service_lost = st.lost
                self._acked.notify_all()
            if st.missing is not None and st.boot == self.boot and st.device == self._device:
                self._ask_resend(st.missing[0], st.missing[1])

    def _ask_resend(self, first: int, last: int) -> None:
        """Queue the kept frames ``first..last`` for the resend thread (under the lock)."""
        now = time.monotonic()
        if len(self._resent_at) > self.keep_frames:
            self._resent_at = {q: at for q, at in self._resent_at.items() if now - at < RESEND_EVERY_S}
        payloads = []
        for kept in (self._kept, self._kept_since or {}):
            due = [q for q in kept if first <= q <= last and now - self._resent_at.get(q, -math.inf) >= RESEND_EVERY_S]
            for q in due:
                self._resent_at[q] = now
                payloads.append(kept[q])
        if payloads and not self._closing.is_set():
            try:
                self._resends.put_nowait(payloads)
            except queue.Full:  # the service asks again in its next Status
                pass
            if self._resender is None:
                self._resender = threading.Thread(target=self._resend_loop, name=f"resend-{self.responder}",
                                                  daemon=True)
                self._resender.start()

    def _resend_loop(self) -> None:
        while not self._closing.is_set():
            try:
                payloads = self._resends.get(timeout=0.5)
            except queue.Empty:
                continue
            for p in payloads:
                if self._closing.is_set():
                    return
                try:
                    self._pub["imu"].put(p)
                except Exception:  # closed under us
                    return
                self.resent += 1

    def send(self, kind: str, msg_or_payload) -> None:
        """Publish one message. A frame gets this wearable's ``boot`` and, without a clock offset,
        this machine's: UTC now minus the device time of its last sample (how a phone relates
        its sensor clock to UTC)."""
        msg = msg_or_payload
        if isinstance(msg, wire.ImuBatch):
            update = {}
            if msg.utc_offset is None:
                update["utc_offset"] = time.time() - float(msg.t[-1])
            if msg.boot is None:
                update["boot"] = self.boot
            if update:
                msg = msg.model_copy(update=update)
        payload = msg if isinstance(msg, bytes) else wire.encode(msg)
        if isinstance(msg, wire.ImuBatch):
            with self._lock:
                self._device = msg.device
                self._seqs.append(msg.seq)
                if len(self._seqs) > 2 * self.keep_frames:  # bounded: what the keep could still resend, and as many more
                    del self._seqs[:self.keep_frames]
                self._kept[msg.seq] = payload
                while len(self._kept) > self.keep_frames:
                    del self._kept[next(iter(self._kept))]
        if kind in self.unheard and not self._probe.matching_status.matching:
            self.unheard[kind] += 1
        self._pub[kind].put(payload)
        self.sent[kind] += 1

    def keep_sent(self, kept) -> None:
        """Frames this wearable sent by other means than :meth:`send` (a load generator's
        :meth:`client.simulate.SimulationPublisher.run_precomputed` puts them itself): ``kept``,
        a mapping seq -> encoded frame that holds at most ``keep_frames`` of the newest, is its
        keep for resending from now on (the frames sent before it stay kept beside it)."""
        with self._lock:
            self._kept_since = kept

    def delivery(self) -> dict:
        """What the service has acknowledged of the frames sent: ``unacknowledged`` frames sent
        after its newest acknowledgement, of which ``beyond_keep`` are older than the keep (they
        can no longer be resent), and ``service_lost`` (the frames it counts lost)."""
        with self._lock:
            seqs, acked = list(self._seqs), self.acked_seq
            lost = self.service_lost
        pending = [s for s in seqs if acked is None or s > acked]
        kept = set(seqs[-self.keep_frames:])
        return {"frames_sent": self.sent["imu"], "acked_seq": acked, "unacknowledged": len(pending),
                "beyond_keep": sum(1 for s in pending if s not in kept), "service_lost": lost}

    def flush(self, timeout: float = FLUSH_S) -> bool:
        """Wait up to ``timeout`` s for the service to acknowledge the last frame sent."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while self._seqs and (self.acked_seq is None or self.acked_seq < self._seqs[-1]):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._acked.wait(min(left, 0.1))
            return True

    def close(self, flush_s: float = 0.0) -> dict:
        """Wait up to ``flush_s`` for the service to acknowledge the last frame (0: do not
        wait), withdraw the presence and the publishers (their keeps go with them); returns
        :meth:`delivery` as it stood then, with ``flushed`` (everything acknowledged)."""
        flushed = self.flush(flush_s) if flush_s > 0 else None
        report = {**self.delivery(), "flushed": flushed, "resent": self.resent}
        self._closing.set()
        # Teardown order (issue 29): first what makes zenoh's threads call into Python (the
        # subscribers, the matching listener), then the resend thread, which may be inside a
        # put; only then the publishers. A put or callback still running when the interpreter
        # finalises is ended by CPython with pthread_exit, a forced unwind that the Rust
        # frames around it cannot pass: glibc aborts ("FATAL: exception not rethrown").
        for d in (self._orders, self._status, self._listener):
            _undeclare(d)
        if self._resender is not None:
            self._resender.join(RESEND_JOIN_S)
        for d in (self._ack, self._token, self._probe, *self._pub.values()):
            _undeclare(d)
        return report


def _undeclare(entity) -> None:
    if entity is None:
        return
    try:
        entity.undeclare()
    except Exception:  # a closed session took it already
        pass


def replay(path, responder: str, session: zenoh.Session, incident, speed: float = 1.0, landmark_every: int = 0,
           gnss: bool = True, stop: threading.Event | None = None, on_progress: Callable[[int, int], None] | None = None,
           on_matching: Callable[[bool], None] | None = None, on_start: Callable[[list], None] | None = None,
           flush_s: float = FLUSH_S, keep_frames: int = KEEP_FRAMES, ble: bool = True) -> dict:
    """Publish recording ``path`` as responder ``responder``; returns the counts sent, in
    ``unheard`` how many went out while no service was subscribed, and in ``delivery`` what the
    service acknowledged (after waiting up to ``flush_s`` for the last frame)."""
    rec = load(path)
    msgs = recording_messages(rec, responder, incident=incident, landmark_every=landmark_every, gnss=gnss,
                              ble_scan_s=BLE_SCAN_S if ble else 0.0)
    w = Wearable(session, incident.id, responder, on_matching=on_matching, keep_frames=keep_frames)
    if on_start is not None:
        on_start(msgs)
    if on_matching is not None:  # the listener speaks on changes: say now if nobody listens yet
        deadline = time.monotonic() + MATCHING_WAIT_S
        while not w.heard and time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            time.sleep(0.05)
        if not w.heard:
            on_matching(False)
    report = None
    try:
        for i, m in enumerate(paced(msgs, speed, stop)):
            w.send(m.kind, m.msg)
            if on_progress is not None and (i % 50 == 0 or i == len(msgs) - 1):
                on_progress(i + 1, len(msgs))
    finally:
        report = w.close(flush_s)
    return {**w.sent, "unheard": dict(w.unheard), "delivery": report}
