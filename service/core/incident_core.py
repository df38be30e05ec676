"""The incident core: a pure function from the messages of an incident to the messages it answers.

::

    Inbound(kind, key, payload, received)  ──►  IncidentCore  ──►  Outbound(key, Pose | Status)
        imu       firetrack/{incident}/{responder}/imu        decode ─► FrameGate ─► ResponderTracker ─► pose
        fix       firetrack/{incident}/{responder}/fix        decode ─► fix type: to the local frame ─┘
        presence  firetrack/{incident}/{responder}/presence   (b"1" connected, b"0" gone)
        op        firetrack/{incident}/{actor}/op             an operator action ─► authorised? ─► fix ─► Audit
        access    firetrack/{incident}/{service}/access       the access policy from now on (who may act, who is revoked)
    tick(now)                                                 held frames released, one Status per responder

Who may do what (:mod:`service.protocol.access`). The router's access control decides which
identity may publish on which key; the core decides what the router cannot: an operator
action (``op``) is taken only from an identity the policy lets act, and nothing at all from a
revoked identity (its frames, fixes, presence and actions are refused before any state is
made for them). Every operator action is answered with an :class:`service.protocol.wire.Audit`
on ``.../{actor}/audit``, which the shell publishes and records. A checkpoint fix that puts a
responder further than a person can walk is taken but flagged
(:mod:`service.core.plausibility`): in its Audit and in ``Status.fixes["flagged"]``.

The core has no threads, sockets or clocks: time comes in with every message (``received``,
the service's wall clock when the shell took it) and with every :meth:`IncidentCore.tick`.
Live (:class:`service.shell.service.IncidentService`), ``replay`` (the same, from a
recording), ``reprocess``, ``exercise``, ``eval ipin`` and the warm-up all feed this one
class, so they give the same poses.

**The same poses, bit for bit.** For the same inbound messages in the same order with the
same ``received`` times, the poses are identical whatever the rounds they come in:
:meth:`feed_round` joins a responder's frames of one round into one pipeline batch, and the
pipeline gives the same events for any batching (``tests/test_pipeline.py``); frames are run
one at a time only while a checkpoint fix waits for its step. Ticks are the exception: a tick
releases frames held for a missing one, so a live run whose frames waited for a tick may
differ from a replay that does not send the same ticks.

A message that cannot be used is counted against its responder with a reason (``Status``
``rejected``), logged a few times per window (:mod:`service.core.rejectlog`: a few lines per
source, then a summary per source), and dropped; nothing a wearable sends reaches another
responder's state, and an exception in one message is counted in ``errors`` and the next
message goes on.

**Isolation.** Before a message is copied, decoded or recorded, the shell asks
:meth:`IncidentCore.admit` (:mod:`service.core.intake`): its size, whether its responder id may
join the incident (an admission budget), and whether its source is within its message budget.
Responders silent for ``expire_after_s`` (``expire_unplaced_s`` for one that never had a frame
released) leave the core, checked as the inputs' clock passes (so ``reprocess`` lets them go at
the same moments); their track stays in the recording. Memory is bounded by the number of
responders the intake admits and what each keeps (bounded deques, the estimator's window).

**Streams and gaps.** A responder's track continues across streams (a restarted wearable, a new
device, a counter reset: :class:`service.core.gate.FrameGate`). A new stream whose device clock
is not the old one's continuation is put on the track's clock (``Responder.t_offset``: the
first sample after the old stream's last one by the receive-time gap); the wire stays on the
current device clock both ways (``Pose.t``, ``Status.t``, fixes with ``time_base="device"``).
A gap of more than ``gap_reanchor_s`` (lost frames, an outage, a new stream) tells the tracker
(:meth:`ResponderTracker.note_gap`): the step across it gets the position uncertainty of a
walk of ``gap_speed_mps`` for its length, so the next checkpoint, GNSS or UWB fix re-anchors
the track. Motionlessness is judged on frames only: no ``man_down`` from an interval with no
frames (``alarms.of_responder``).

**Snapshots.** :meth:`IncidentCore.snapshot` is the core's whole state as bytes (the
estimators restart their graphs from their newest pose, see
:meth:`service.fusion.graph.TrackFusion.__getstate__`); :meth:`IncidentCore.restore` makes a
core that goes on from it (:mod:`service.review.resume`).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from pdr.events import MotionEvent, bearing_deg
from pdr.fleet import FleetMember, PdrFleet
from pdr.floors import FloorElevations
from service.core import alarms
from service.core.fix_types import FixRejected, fix_type_of
from service.core import snapshot as snapshots
from service.core.gate import FrameGate
from service.core.intake import OPERATORS, Intake, IntakeSettings
from service.core.rejectlog import RejectLog
from service.core.plausibility import PlausibilitySettings, Reference, judge, semi_major
from service.core.responder import Responder, continues, frame_of
from service.core.tracker import (
    CheckpointFix,
    PoseEstimate,
    ResponderTracker,
    TrackerSettings,
    tracker_settings_for,
)
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")

INBOUND_KINDS = ("imu", "fix", "presence", "command", "ack", "op", "access")
MAX_EARLY_ACKS = 8  # acknowledgements kept per responder while their order has not arrived


class Inbound(NamedTuple):
    """A message as the shell took it: ``received`` is the service's wall clock (unix s) then."""

    kind: str
    key: str
    payload: bytes
    received: float


class Outbound(NamedTuple):
    """A message the core answers with: the shell encodes and publishes it on ``key``."""

    key: str
    message: wire.WireMessage


@dataclass(frozen=True)
class CoreSettings:
    tracker: TrackerSettings | None = None  # None: tracker_settings_for(the incident)
    lost_contact_s: float = wire.LOST_CONTACT_S  # s without a frame -> lost-contact alarm
    rejected_window_s: float = 10.0  # s
    rejected_burst: int = 5  # rejects within the window -> alarm
    reorder_window: int = 4  # frames a late frame may be overtaken by
    entry_sigma_m: float | None = 50.0  # m: responders not yet placed by a checkpoint start at the origin
    # with this σ at their first step (None: no pose until a checkpoint places them)
    log_rejects_per_window: int = 3  # full log lines per source and window; all are counted
    log_lines_per_window: int = 40  # full log lines per window over all sources (then summaries)
    max_coalesce: int = 50  # frames of one responder run through its tracker as one batch, at most
    command_answer_s: float = 30.0  # s a roll call or evacuation order may go unanswered before it alarms
    fix_future_s: float = 2.0  # s: a fix this far ahead of the newest sample is from the future (a wrong clock)
    intake: IntakeSettings = field(default_factory=IntakeSettings)  # budgets and admission (service/core/intake.py)
    expire_after_s: float = 1800.0  # s of silence after which a responder leaves the core (its track stays recorded)
    expire_unplaced_s: float = 120.0  # s of silence after which an id that never had a frame released leaves
    gap_reanchor_s: float = 2.0  # s: a gap in the frames longer than this widens the position for the next fix
    gap_speed_mps: float = 1.5  # m/s: the walk a gap may hide (a brisk pace), as position sigma per second
    same_clock_tolerance_s: float = 5.0  # s: a new stream whose first sample is within the receive gap + this
    # of the old stream's last is on the same device clock (the track's times stay the device's)
    min_stream_gap_s: float = 0.01  # s between a stream's last sample and the next stream's first, at least
    max_clock_lead_s: float = 60.0  # s a device clock may run ahead of the service's across a gap (beyond: a leap)
    idle_after_s: float = 2.0  # s without a message after which a responder's Status goes out less often ...
    idle_status_every_s: float = 5.0  # ... every this many s (and at once when its alarms change)
    columnar: bool = True  # handheld pipelines run in columnar rounds (pdr.fleet); False: one responder at a time
    plausibility: PlausibilitySettings = field(default_factory=PlausibilitySettings)


@dataclass
class CoreCounters:
    frames_processed: int = 0
    tracker_batches: int = 0  # tracker calls: frames_processed / tracker_batches frames each on average
    errors: int = 0  # exceptions caught while processing (logged a few times per window)
    received: dict = field(default_factory=lambda: {"imu": 0, "fix": 0, "op": 0})  # payloads taken, good or bad
    expired: int = 0  # responders that left after their silence


class IncidentCore:
    """Every responder of one incident: ``outputs = core.feed_round(inbound)``, ``core.tick(now)``."""

    def __init__(self, incident: IncidentConfig, settings: CoreSettings | None = None):
        settings = settings or CoreSettings()
        if settings.tracker is None:  # the incident's declination and field reach the compass
            settings = dataclasses.replace(settings, tracker=tracker_settings_for(incident))
        self.incident = incident
        self.id = incident.id
        self.settings = settings
        self.responders: dict[str, Responder] = {}
        self.unattributed: dict[str, int] = {}  # rejects whose key names no valid responder
        self.counters = CoreCounters()
        self.recording_failed = False  # set by the shell: every Status then carries the alarm
        self._dirty: dict[str, Responder] = {}  # responders with frames waiting for the round's end
        self._out: list[Outbound] = []
        self._pose_queue: list[tuple] = []  # poses of this round waiting for their wire form
        self._now = 0.0
        self._presence: dict[str, bool] = {}  # liveliness seen before a responder's first frame (bounded)
        self.intake = Intake(settings.intake)
        self.reject_log = RejectLog(log, settings.rejected_window_s, settings.log_rejects_per_window,
                                    settings.log_lines_per_window)
        self._expiry_checked = -math.inf
        self._early_rejects: dict[str, deque] = {}  # rejects at the intake of ids admitted but not made yet
        pipeline = settings.tracker.pipeline
        # the handheld pipelines of all responders, run a stage at a time over the round (pdr.fleet)
        self.fleet = (PdrFleet(pipeline, FloorElevations(incident.elevations()))
                      if settings.columnar and PdrFleet.supports(pipeline) and settings.tracker.motion is None else None)
        self.access = wire.Access(enforce=False)  # until an access message says otherwise: the open demo
        self._revoked: frozenset[str] = frozenset()
        self._refused_logged: set[str] = set()
        self.audits: int = 0

    # ------------------------------------------------------------------ inputs
    def feed_round(self, items: Iterable[Inbound]) -> list[Outbound]:
        """Messages taken together: each is decoded and gated in turn, then every responder's
        new frames go through its tracker as one batch (a fix first runs the frames that came
        before it). The poses are those of :meth:`feed` one message at a time, bit for bit."""
        for item in items:
            try:
                self._take(item)
            except Exception:  # a bug must not stop the incident: log it, count it, go on
                self._error(f"while processing {item.key[:200]}")
        self._run_dirty()
        self._emit_poses()
        out, self._out = self._out, []
        return out

    def feed(self, item: Inbound) -> list[Outbound]:
        """One message: a round of one (what ``reprocess`` of a single message does)."""
        return self.feed_round((item,))

    def tick(self, now: float) -> list[Outbound]:
        """Time passes: frames held for a missing one beyond the gate's wait are released, and
        every responder's Status is answered: at every tick while it is heard, every
        ``idle_status_every_s`` once it has been silent for ``idle_after_s`` (and at once when
        its alarms change), so a crowd of silent ids costs little status traffic."""
        self._now = now
        for r in list(self.responders.values()):
            try:
                for b in r.gate.expire(now):
                    self._process(r, b)
            except Exception:
                self._error(f"while releasing the held frames of {r.id}")
        self._run_dirty()
        s = self.settings
        for r in list(self.responders.values()):
            try:
                st = self.status_of(r, now)
                idle = now - r.last_input >= s.idle_after_s
                if not idle or st.alarms != r.last_alarms or now - r.last_status >= s.idle_status_every_s:
                    self._out.append(Outbound(wire.key(self.id, r.id, "status"), st))
                    r.last_status, r.last_alarms = now, st.alarms
            except Exception:
                self._error(f"status of {r.id}")
        self._emit_poses()
        out, self._out = self._out, []
        return out

    def admit(self, kind: str, key: str, size: int, now: float) -> str | None:
        """May a message (of ``size`` bytes, on ``key``) enter? None, or the reason it may not
        (:data:`service.core.intake.INTAKE_REASONS`), counted and logged per source. The shell
        asks before copying, recording or feeding it (see :mod:`service.core.intake`)."""
        if kind == "op":  # an operator's action: its actor is no responder; operators share one budget
            reason, source = self.intake.admit_shared(OPERATORS, size, now), OPERATORS
        else:
            reason, source = self.intake.admit(key, size, now, self.responders)
        if reason is not None:
            self.reject_log.note(source, reason, f"{kind} of {size} bytes on {key[:120]!r}", now)
            r = self.responders.get(source)
            if reason == "oversize" and (r is not None or source in self.intake.sources):
                # a bad message like any other: the burst alarm hears of it (an id admitted in the same
                # round, whose Responder the round has not made yet, gets it when it is made)
                if r is not None:
                    r.rejects.append(now)
                else:
                    self._early_rejects.setdefault(source, deque(maxlen=64)).append(now)
                self.intake.note_reject(source, now)
        return reason

    # ------------------------------------------------------------------ queries
    def status_of(self, r: Responder, now: float) -> wire.Status:
        heard = r.gate.last_heard if r.gate.last_heard is not None else r.first_heard
        motion, since = r.tracker.motion
        rejected = dict(r.gate.counts)
        tr = r.tracker
        current = alarms.of_responder(r, now, self.settings, self.recording_failed,
                                      flooding=self.intake.flooding(r.id, now))
        for kind in [k for k in r.alarm_since if k not in current]:
            del r.alarm_since[kind]
        for kind in current:
            r.alarm_since.setdefault(kind, now)
        for reasons in (r.fixes_rejected, tr.fix_rejects, {"unused": tr.fixes_unused}):
            for reason, n in reasons.items():
                if n:
                    rejected[f"fix_{reason}"] = rejected.get(f"fix_{reason}", 0) + n
        for reason, n in self.intake.dropped_of(r.id).items():
            rejected[reason] = rejected.get(reason, 0) + n
        g = r.gate
        return wire.Status(
            responder=r.id, t=tr.device_time - r.t_offset, motion=motion.value, motion_since=since - r.t_offset,
            alarms=current, alarms_since={k: r.alarm_since[k] for k in current}, rejected=rejected,
            frames=g.accepted, gaps=g.gaps, last_heard=heard, steps=tr.steps,
            fixes={"applied": tr.fixes_applied, "queued": tr.fixes_queued,
                   **({"flagged": r.fixes_flagged} if r.fixes_flagged else {})}, utc_offset=r.utc_offset,
            last_fix=tr.last_fix, first_heard=r.first_heard, commands={a: dict(o) for a, o in r.commands.items()},
            lost=g.lost, gap_s=g.gap_s, streams=g.streams, device=g.device, boot=g.boot, seq=g.last_seq,
        )

    def flooding_sources(self, now: float) -> list[str]:
        """Sources throttled within the flood alarm's time: responder ids, ``<bad key>``, ``<new ids>``."""
        return self.intake.flooding_sources(now)

    def track(self, rid: str) -> dict | None:
        """The responder's track so far as columns (``t, x, y, floor, heading``) and whether it
        is the smoothed one; None for an unknown responder."""
        r = self.responders.get(rid)
        if r is None:
            return None
        sm = r.tracker.smoothed_track()
        if sm is not None and len(sm["t"]):
            return {"track": sm, "smoothed": True}
        arr = np.array(r.tracker.pdr_track, float).reshape(-1, 4)
        cols = {"t": arr[:, 0], "x": arr[:, 1], "y": arr[:, 2], "floor": arr[:, 3], "heading": np.full(len(arr), np.nan)}
        return {"track": cols, "smoothed": False}

    def frame_accounting(self) -> dict[str, int]:
        """Over all responders: frames rejected by reason, declared lost, still held by a gate,
        and the messages the intake refused (by reason)."""
        out: dict[str, int] = dict(self.unattributed)
        for reason, n in self.intake.counts.items():
            out[reason] = out.get(reason, 0) + n
        for r in self.responders.values():
            for reason, n in r.gate.counts.items():
                out[reason] = out.get(reason, 0) + n
            out["lost"] = out.get("lost", 0) + r.gate.lost
            out["held"] = out.get("held", 0) + r.gate.held + len(r.backlog)
        return {k: v for k, v in out.items() if v}

    # ------------------------------------------------------------------ per message
    def _take(self, item: Inbound) -> None:
        kind, key, payload, now = item
        self._now = now
        if now - self._expiry_checked >= 1.0 or now < self._expiry_checked:
            self._expire(now)
        if kind in self.counters.received:
            self.counters.received[kind] += 1
        if kind == "imu":
            self._on_imu(key, payload, now)
        elif kind == "fix":
            self._on_fix(key, payload, now)
        elif kind == "presence":
            self._on_presence(key, payload)
        elif kind in ("command", "ack"):
            self._on_command(kind, key, payload, now)
        elif kind == "op":
            self._on_op(key, payload, now)
        elif kind == "access":
            self._on_access(payload)
        else:
            raise ValueError(f"unknown inbound kind {kind!r}; expected one of {INBOUND_KINDS}")

    def _responder_of(self, key: str, now: float, reason_on_fail: str) -> Responder | None:
        try:
            _, rid, _ = wire.parse_key(key)
        except ValueError as e:
            self.unattributed[reason_on_fail] = self.unattributed.get(reason_on_fail, 0) + 1
            self.reject_log.note("<bad key>", reason_on_fail, str(e), now)
            return None
        if rid in self._revoked:
            self._refuse_revoked(rid, key)
            return None
        r = self.responders.get(rid)
        if r is None:
            r = self._new_responder(rid, now)
        r.last_input = now
        return r

    def _new_responder(self, rid: str, now: float) -> Responder:
        s = self.settings
        r = Responder(id=rid, gate=FrameGate(reorder_window=s.reorder_window), tracker=self._tracker(rid),
                      first_heard=now, present=self._presence.pop(rid, None))
        r.rejects.extend(self._early_rejects.pop(rid, ()))
        self.responders[rid] = r
        log.info("responder %s appeared", rid)
        return r

    def _expire(self, now: float) -> None:
        """Responders silent for ``expire_after_s`` (``expire_unplaced_s`` if no frame of theirs
        was ever released) leave: their memory goes, their track stays in the recording."""
        self._expiry_checked = now
        s = self.settings
        for rid, r in list(self.responders.items()):
            limit = s.expire_after_s if r.gate.accepted else s.expire_unplaced_s
            if now - r.last_input > limit and now - r.first_heard > limit:
                del self.responders[rid]
                self._dirty.pop(rid, None)
                self.intake.forget(rid)
                r.tracker.release_model()  # e.g. its columnar slot goes to the next responder
                self.counters.expired += 1
                # a responder that walked is news; an id that never did is one of a crowd (a flood of ids)
                (log.warning if r.tracker.steps else log.info)(
                    "%s left the incident after %.0f s of silence (%d steps, %d poses; its track is in the recording)",
                    rid, now - max(r.last_input, r.first_heard), r.tracker.steps, r.poses)

    def _tracker(self, rid: str) -> ResponderTracker:
        """A fresh tracker; not yet placed, it starts at the incident origin with a wide σ
        until a checkpoint fix says where the responder is."""
        cfg, s = self.incident, self.settings
        entry = (None if s.entry_sigma_m is None
                 else CheckpointFix(0.0, 0.0, 0.0, cfg.start_floor, s.entry_sigma_m, "origin (unplaced)"))
        return ResponderTracker(rid, FloorElevations(cfg.elevations()), cfg.start_floor, s.tracker, entry=entry,
                                fleet=self.fleet)

    MAX_PRESENCE = 4096  # liveliness states kept for ids with no responder (beyond, the oldest go)

    def _on_presence(self, key: str, payload: bytes) -> None:
        try:
            _, rid, _ = wire.parse_key(key)
        except ValueError:
            return
        if rid in self._revoked:
            self._refuse_revoked(rid, key)
            return
        alive = payload == b"1"
        r = self.responders.get(rid)
        if r is not None:
            r.present = alive
        else:
            self._presence[rid] = alive
            while len(self._presence) > self.MAX_PRESENCE:
                del self._presence[next(iter(self._presence))]
        log.info("wearable of %s %s", rid, "connected" if alive else "disconnected")

    def _on_command(self, kind: str, key: str, payload: bytes, now: float) -> None:
        """An order to a wearable (roll call, evacuation) or its acknowledgement: kept per
        responder and action, so Status says who has not answered."""
        try:
            _, rid, _ = wire.parse_key(key)
            if kind == "ack" and rid in self._revoked:
                self._refuse_revoked(rid, key)
                return
            msg = wire.decode(payload, expect=wire.Command if kind == "command" else wire.Ack)
        except (ValueError, wire.WireError) as e:
            self.unattributed[f"{kind}_invalid"] = self.unattributed.get(f"{kind}_invalid", 0) + 1
            log.warning("rejected a %s on %r: %s", kind, key, e)
            return
        r = self.responders.get(rid)
        if r is None or msg.responder != rid:
            self.unattributed[f"{kind}_unknown_responder"] = self.unattributed.get(f"{kind}_unknown_responder", 0) + 1
            return
        if kind == "command":  # an acknowledgement may have overtaken its order (other key, other path)
            early = r.early_acks.pop((msg.action, msg.id), None)
            r.commands[msg.action] = {"id": msg.id, "issued_at": msg.issued_at, "issued_by": msg.issued_by,
                                      "acked_at": early}
            log.info("%s: %s %s issued by %s", rid, msg.action, msg.id, msg.issued_by or "?")
            return
        order = r.commands.get(msg.action)
        if order is not None and order["id"] == msg.id:
            if order["acked_at"] is None:
                order["acked_at"] = msg.at
                log.info("%s acknowledged %s %s", rid, msg.action, msg.id)
        elif len(r.early_acks) < MAX_EARLY_ACKS:
            r.early_acks[(msg.action, msg.id)] = msg.at

    def _reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A frame turned away before the gate saw it: counted there like the gate's own."""
        r.gate.count(reason, detail, now)
        self._note_reject(r, reason, detail, now)

    def _note_reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """Every reject feeds the burst alarm and the source's budget (a duplicate, which
        retransmission makes, does neither); the log gets a few lines per window."""
        if reason != "duplicate":
            r.rejects.append(now)
            self.intake.note_reject(r.id, now)
        self.reject_log.note(r.id, reason, detail, now)

    def _error(self, what: str) -> None:
        """An exception while processing: counted; logged with its traceback a few times per window."""
        self.counters.errors += 1
        self.reject_log.note("<errors>", "exception", what, self._now, level=logging.ERROR, exc_info=True)

    def _on_imu(self, key: str, payload: bytes, now: float) -> None:
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
        if batch.utc_offset is not None:
            r.utc_offset = batch.utc_offset
        rejected_before = r.gate.rejected
        released = r.gate.offer(batch, now)
        if r.gate.rejected > rejected_before:  # the gate records why in its newest event
            _, reason, detail = r.gate.events[-1]
            self._note_reject(r, reason, f"frame {batch.seq}: {detail}", now)
        for b in released:
            self._process(r, b)

    def _process(self, r: Responder, b: wire.ImuBatch) -> None:
        if b is r.gate.first_of_stream and b is not r.stream_start:
            self._new_stream(r, b)
        t0 = float(b.t[0]) + r.t_offset
        if math.isfinite(r.last_t) and t0 - r.last_t > self.settings.gap_reanchor_s:
            self._run_backlog(r)  # the frames before the gap go first
            t0 = self._bound_leap(r, b, t0)
            self._gap(r, r.last_t, t0)
        if r.backlog and (not continues(r.backlog[-1], b) or len(r.backlog) >= self.settings.max_coalesce):
            self._run_backlog(r)
        r.backlog.append(b)
        r.last_t = float(b.t[-1]) + r.t_offset
        r.last_rt = self._now
        self._dirty[r.id] = r  # run at the round's end (frame by frame while a fix waits: see _run_backlog)

    def _new_stream(self, r: Responder, b: wire.ImuBatch) -> None:
        """The gate opened a stream with ``b``: the first of the responder, or a new one (a
        restarted wearable, another device, a counter reset) that continues the same track.
        Its device clock is the track's if its first sample follows the last one within the
        receive-time gap; otherwise it is put on the track's clock after that gap."""
        self._run_backlog(r)  # the old stream's last frames end at the old clock
        r.stream_start = b
        if not math.isfinite(r.last_t):
            return
        s = self.settings
        gap = max(self._now - r.last_rt, 0.0) if r.last_rt is not None else 0.0
        t0 = float(b.t[0])
        ahead = t0 - (r.last_t - r.t_offset)
        if not 0.0 < ahead <= gap + s.same_clock_tolerance_s:
            r.t_offset = r.last_t + max(gap, s.min_stream_gap_s) - t0
        log.warning("%s: new stream (device %s, boot %s) after %.1f s; the track continues%s", r.id, b.device,
                    b.boot, gap, "" if r.t_offset == 0.0 else f" (its clock is {r.t_offset:+.3f} s from the track's)")

    def _bound_leap(self, r: Responder, b: wire.ImuBatch, t0: float) -> float:
        """A device clock that leaps further ahead than the service's clock went (by more than
        ``max_clock_lead_s``) is put back on the track's clock after the receive-time gap:
        a broken or hostile clock must not make the motion model walk through hours of
        nothing (its state grid would grow with them). Returns the frame's new track time."""
        s = self.settings
        rgap = max(self._now - r.last_rt, 0.0) if r.last_rt is not None else 0.0
        if t0 - r.last_t <= rgap + s.max_clock_lead_s:
            return t0
        leap = t0 - r.last_t
        r.t_offset -= leap - max(rgap, s.min_stream_gap_s)
        self.reject_log.note(r.id, "clock_leap", f"frame {b.seq}: device time leapt {leap:.1f} s in {rgap:.1f} s; "
                                                 "the track goes on after the receive-time gap", self._now)
        return float(b.t[0]) + r.t_offset

    def _gap(self, r: Responder, t_from: float, t_to: float) -> None:
        """No frames between ``t_from`` and ``t_to`` (track clock): the tracker widens the step
        across it, and the motionlessness before it no longer counts towards man-down."""
        r.gap_end = t_to
        r.tracker.note_gap(t_from, t_to, self.settings.gap_speed_mps * (t_to - t_from))

    def _run_dirty(self) -> None:
        """The round's end: every responder's waiting frames through its tracker; those on the
        handheld pipeline together, a stage at a time (:meth:`_run_columnar`)."""
        dirty, self._dirty = self._dirty, {}
        columns: list[Responder] = []
        for r in dirty.values():
            if r.backlog and isinstance(r.tracker.choose_model(r.backlog[0].carry), FleetMember):
                columns.append(r)
                continue
            try:
                self._run_backlog(r)
            except Exception:
                self.counters.errors += 1
                log.exception("error while running the frames of %s", r.id)
        if columns:
            self._run_columnar(columns)

    def _run_columnar(self, responders: list[Responder]) -> None:
        """Responders on the fleet's pipeline: their frames in one columnar round, then each
        one's events through its tracker. The events are those of one responder at a time, bit
        for bit (:mod:`pdr.fleet`). While a fix waits for its step a responder gives one frame
        per round (:meth:`_next_batches`), so its frames run one at a time as alone. A frame the
        pipeline refuses takes the one-at-a-time path, which finds the culprit."""
        while responders:
            items = [(r, self._next_batches(r)) for r in responders]
            try:
                results = self.fleet.run([(r.tracker.model, frame_of(batches)) for r, batches in items])
            except Exception:  # a bug in the round: each responder alone, so that one cannot stop the others
                self.counters.errors += 1
                log.exception("error in a columnar round of %d responders", len(items))
                results = [None] * len(items)
            for (r, batches), events in zip(items, results):
                try:
                    if events is None or isinstance(events, Exception):
                        r.backlog = batches + r.backlog
                        self._run_backlog(r)
                        continue
                    self._after_batches(r, batches, r.tracker.on_events(events))
                except Exception:
                    self.counters.errors += 1
                    log.exception("error while running the frames of %s", r.id)
            responders = [r for r, _ in items if r.backlog]

    @staticmethod
    def _next_batches(r: Responder) -> list:
        """The frames a responder's tracker takes next as one batch: all it has, or one while a
        checkpoint fix waits for its step (``ResponderTracker.fix_waiting``)."""
        if r.tracker.fix_waiting and len(r.backlog) > 1:
            batches, r.backlog = r.backlog[:1], r.backlog[1:]
        else:
            batches, r.backlog = r.backlog, []
        return batches

    def _run_backlog(self, r: Responder) -> None:
        """The responder's waiting frames through its tracker, as one batch (one at a time while
        a fix waits); poses out."""
        while r.backlog:
            self._run_batches(r, self._next_batches(r))

    def _run_batches(self, r: Responder, batches: list) -> None:
        try:
            outputs = r.tracker.on_frame(frame_of(batches, r.t_offset), batches[0].carry)
        except ValueError as e:  # e.g. a frame the gate let through that the pipeline cannot take
            if len(batches) > 1:  # the check comes before any state changes: find the culprit alone
                for b in batches:
                    self._run_batches(r, [b])
                return
            self._reject(r, "pipeline", f"frame {batches[0].seq}: {e}", self._now)
            return
        self._after_batches(r, batches, outputs)

    def _after_batches(self, r: Responder, batches: list, outputs: list) -> None:
        r.seq, r.seq_oldest = batches[-1].seq, batches[0].seq
        self.counters.frames_processed += len(batches)
        self.counters.tracker_batches += 1
        for o in outputs:
            if isinstance(o, PoseEstimate):
                self._answer_pose(r, o)
            elif isinstance(o, MotionEvent):
                log.info("%s is %s since device time %.1f", r.id, o.state.value, o.since)

    def _on_fix(self, key: str, payload: bytes, now: float) -> None:
        r = self._responder_of(key, now, "bad_key")
        if r is None:
            return
        try:
            fix = wire.decode(payload, expect=wire.Fix)
        except wire.WireError as e:
            self._count_fix_reject(r, e.reason, e.detail)
            return
        if fix.responder != r.id:
            self._count_fix_reject(r, "schema", f"responder {fix.responder!r} in a fix on the key of {r.id!r}")
            return
        outcome, reason, detail, verdict = self._take_fix(r, fix)
        if verdict is not None and verdict.implausible:  # a device's checkpoint fix: taken, flagged, audited
            self._audit(wire.Audit(actor=r.id, action="device_fix", outcome=outcome, responder=r.id, reason=reason,
                                   detail=detail, flags=["implausible_jump"], jump_m=verdict.jump_m,
                                   walkable_m=verdict.walkable_m, t=fix.t, received=now))

    def _take_fix(self, r: Responder, fix: wire.Fix):
        """A decoded fix for ``r`` to its tracker: ``(outcome, reason, detail, verdict)``,
        outcome ``accepted`` or ``refused`` (reason and detail say why), ``verdict`` the
        plausibility of a checkpoint fix (None for other sources)."""
        self._run_backlog(r)  # the frames that came before the fix go first (its time is judged against them)
        try:
            fix = self._on_device_clock(r, fix)
            domain = fix_type_of(fix.source).to_domain(fix, self.incident)
            if hasattr(domain, "at_height"):  # a 3D measurement: the tag is on the responder's floor
                domain = domain.at_height(self._tag_height(r))
        except FixRejected as e:
            self._count_fix_reject(r, e.reason, str(e))
            return "refused", e.reason, str(e), None
        except ValueError as e:  # a domain fix that checks itself (service.fusion.fixes)
            self._count_fix_reject(r, "unknown_reference", str(e))
            return "refused", "unknown_reference", str(e), None
        verdict = None
        if isinstance(domain, CheckpointFix):
            verdict = self._plausibility(r, domain)
            if verdict is not None and verdict.implausible:
                r.fixes_flagged += 1
                log.warning("%s: checkpoint fix %.0f m from the %s, at most %.0f m walkable: taken, flagged",
                            r.id, verdict.jump_m, verdict.against.replace("_", " "), verdict.walkable_m)
            r.last_checkpoint = Reference(domain.t, domain.x, domain.y, domain.sigma)
        pose = r.tracker.on_fix(domain)
        log.info("%s: %s fix at device time %.2f%s", r.id, fix.source, fix.t, " applied" if pose else " queued")
        if pose is not None:
            self._answer_pose(r, pose)
        return "accepted", None, None, verdict

    def _plausibility(self, r: Responder, fix: CheckpointFix):
        """The checkpoint fix against the last checkpoint and the current estimate
        (:mod:`service.core.plausibility`); None for a responder not placed yet."""
        refs = []
        if r.last_checkpoint is not None:
            refs.append(("last_fix", r.last_checkpoint))
        live = r.tracker.live
        if live is not None:
            refs.append(("estimate", Reference(live.t, live.x, live.y, semi_major(live.cov))))
        return judge(fix.t, fix.x, fix.y, fix.sigma, refs, self.settings.plausibility) if refs else None

    # ------------------------------------------------------------------ who may do what
    def _on_access(self, payload: bytes) -> None:
        try:
            acc = wire.decode(payload, expect=wire.Access)
        except wire.WireError as e:  # the service's own message: a bug, loud
            self.counters.errors += 1
            log.error("access policy not understood, the previous one stays: %s", e)
            return
        first = self.access == wire.Access(enforce=False)
        self.access = acc
        self._revoked = frozenset(acc.revoked) if acc.enforce else frozenset()
        self._refused_logged.clear()
        log.log(logging.INFO if first else logging.WARNING, "access policy%s: %s",
                f" from {acc.source}" if acc.source else "",
                    (f"operators {', '.join(acc.operators) or 'none'}; revoked {', '.join(acc.revoked) or 'none'}")
                    if acc.enforce else "open (nothing enforced)")

    def _refuse_revoked(self, ident: str, key: str) -> None:
        self.unattributed["revoked"] = self.unattributed.get("revoked", 0) + 1
        if ident not in self._refused_logged:
            self._refused_logged.add(ident)
            log.warning("refused %s: %s is revoked", key, ident)

    def _on_op(self, key: str, payload: bytes, now: float) -> None:
        """An operator action: refused unless the actor may act (and is not revoked); a fix
        goes to its responder's tracker; every action is answered with an Audit."""
        try:
            _, actor, _ = wire.parse_key(key)
        except ValueError as e:
            self.unattributed["bad_key"] = self.unattributed.get("bad_key", 0) + 1
            log.warning("rejected an action on %r: %s", key, e)
            return
        try:
            op = wire.decode(payload, expect=wire.OperatorAction)
        except wire.WireError as e:
            self.unattributed[f"op_{e.reason}"] = self.unattributed.get(f"op_{e.reason}", 0) + 1
            log.warning("rejected an action of %s: %s", actor, e)
            return
        base = dict(actor=actor, operator=op.operator, action=op.action, responder=op.responder, utc=op.utc,
                    received=now, order=op.order)
        acc = self.access
        if acc.enforce and (actor in self._revoked or actor not in acc.operators):
            reason = "revoked" if actor in self._revoked else "unauthorised"
            log.warning("refused a %s action of %s (%s): %s", op.action, actor, op.operator, reason)
            self._audit(wire.Audit(outcome="refused", reason=reason,
                                   detail=f"{actor} {'is revoked' if reason == 'revoked' else 'may not act as an operator'}",
                                   **base))
            return
        if op.action != "fix":
            log.info("%s (%s): %s %s", actor, op.operator, op.action, op.responder or op.name or op.order or "")
            self._audit(wire.Audit(outcome="recorded", **base))
            return
        try:
            fix = wire.decode(op.fix, expect=wire.Fix)
        except wire.WireError as e:
            self._audit(wire.Audit(outcome="refused", reason="schema", detail=e.detail[:500], **base))
            return
        r = self.responders.get(op.responder)
        if fix.responder != op.responder or r is None or op.responder in self._revoked:
            reason, detail = (("schema", f"the fix is for {fix.responder!r}, the action for {op.responder!r}")
                              if fix.responder != op.responder else
                              ("revoked", f"{op.responder} is revoked") if op.responder in self._revoked else
                              ("unknown_responder", f"no frame of {op.responder!r} has been taken yet"))
            self._audit(wire.Audit(outcome="refused", reason=reason, detail=detail, **base))
            return
        outcome, reason, detail, verdict = self._take_fix(r, fix)
        flagged = verdict is not None and verdict.implausible
        self._audit(wire.Audit(outcome=outcome, reason=reason, detail=detail, t=fix.t,
                               flags=["implausible_jump"] if flagged else [],
                               jump_m=verdict.jump_m if verdict is not None else None,
                               walkable_m=verdict.walkable_m if verdict is not None else None, **base))

    def _audit(self, a: wire.Audit) -> None:
        self.audits += 1
        self._out.append(Outbound(wire.key(self.id, a.actor, "audit"), a))

    def _on_device_clock(self, r: Responder, fix: wire.Fix) -> wire.Fix:
        """The fix with ``t`` on the responder's device clock, or :class:`FixRejected`: a UTC
        time before the wearable has said its clock offset (``clock_unknown``), a time ahead of
        the newest sample (``future``: a wrong clock), or older than the estimator's window
        (``too_old``)."""
        if fix.time_base == "utc":
            if r.utc_offset is None:
                raise FixRejected("clock_unknown", f"{fix.source} fix in UTC, but the wearable of {r.id} has not "
                                                   "said its clock offset yet (ImuBatch.utc_offset)")
            fix = fix.model_copy(update={"t": fix.t - r.utc_offset, "time_base": "device"})
        if r.t_offset:  # the current stream's device clock -> the track's
            fix = fix.model_copy(update={"t": fix.t + r.t_offset})
        tr = r.tracker
        if math.isfinite(tr.model.last_time):  # judged against the samples taken so far
            ahead = fix.t - tr.device_time
            if ahead > self.settings.fix_future_s:
                raise FixRejected("future", f"{fix.source} fix {ahead:.1f} s ahead of the newest sample "
                                            f"(device time {tr.device_time:.2f} s): check its clock and time_base")
            if -ahead > tr.max_fix_age_s:
                raise FixRejected("too_old", f"{fix.source} fix {-ahead:.1f} s behind the newest sample; the "
                                             f"estimator keeps {tr.max_fix_age_s:.0f} s")
        return fix

    def _tag_height(self, r: Responder) -> float:
        """m: where a responder's tag is, the floor's configured elevation + the tag height."""
        elevations = self.incident.elevations()
        floor = r.tracker.floor
        base = elevations.get(floor, floor * self.incident.floor_height_m)
        return base + self.incident.uwb_tag_height_m

    def _count_fix_reject(self, r: Responder, reason: str, detail: str) -> None:
        r.fixes_rejected[reason] = r.fixes_rejected.get(reason, 0) + 1
        if reason in wire.REJECT_REASONS:  # not a fix at all: the source's budget hears of it
            r.rejects.append(self._now)
            self.intake.note_reject(r.id, self._now)
        self.reject_log.note(r.id, f"fix_{reason}", detail, self._now)

    # ------------------------------------------------------------------ outputs
    def _answer_pose(self, r: Responder, p: PoseEstimate) -> None:
        """A pose to answer: its place in the output is kept, its wire form is made for all the
        round's poses at once (one geodetic conversion, :meth:`_emit_poses`)."""
        self._pose_queue.append((len(self._out), r, p, max(r.seq, 0), self._now, r.utc_offset))
        self._out.append(None)
        r.poses += 1

    def _emit_poses(self) -> None:
        q, self._pose_queue = self._pose_queue, []
        if not q:
            return
        try:
            lat, lon = self._geodetic(np.array([e[2].x for e in q], float), np.array([e[2].y for e in q], float))
            lat, lon = lat.tolist(), lon.tolist()
        except Exception:
            self.counters.errors += 1
            log.exception("geodetic position of %d poses", len(q))
            lat = lon = [math.nan] * len(q)
        for (i, r, p, seq, now, utc_offset), la, lo in zip(q, lat, lon):
            try:
                self._out[i] = Outbound(wire.key(self.id, r.id, "pose"), self._pose(r, p, la, lo, seq, now, utc_offset))
            except Exception:  # a pose that is not a valid message is dropped, counted and logged
                self.counters.errors += 1
                log.exception("pose of %s", r.id)
        if any(o is None for o in self._out):
            self._out = [o for o in self._out if o is not None]

    def _geodetic(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ENU -> (lat, lon) for arrays: every pose the same bits whether converted alone or among many."""
        lat, lon, _ = self.incident.to_geodetic(x, y, np.zeros_like(x))
        return np.atleast_1d(lat), np.atleast_1d(lon)

    def pose_message(self, r: Responder, p: PoseEstimate) -> wire.Pose:
        """The wire form of a pose: geodetic position, compass bearing, symmetric covariance;
        ``published_at`` is the core's time, which the shell restamps when it publishes."""
        lat, lon = self._geodetic(np.array([p.x], float), np.array([p.y], float))
        return self._pose(r, p, float(lat[0]), float(lon[0]), max(r.seq, 0), self._now, r.utc_offset)

    @staticmethod
    def _pose(r: Responder, p: PoseEstimate, lat: float, lon: float, seq: int, now: float, utc_offset) -> wire.Pose:
        cov = np.asarray(p.cov, float)
        cov = 0.5 * (cov + cov.T)
        t = p.t - r.t_offset  # on the current stream's device clock, like every time on the wire
        return wire.Pose(
            responder=r.id, t=t, x=p.x, y=p.y, floor=int(p.floor), lat=lat, lon=lon,
            heading_deg=bearing_deg(p.heading) if math.isfinite(p.heading) else 0.0, cov=cov, steps=p.steps,
            source=p.source, seq=seq, published_at=now,
            utc=None if utc_offset is None else t + utc_offset,
        )

    # ------------------------------------------------------------------ snapshots
    def snapshot(self) -> bytes:
        """The core's state as bytes (between rounds): every responder (gate, motion model,
        estimator, counters), the intake's budgets and the counters. Not the incident config or
        the settings: :meth:`restore` takes those from the caller."""
        if self._dirty or any(r.backlog for r in self.responders.values()):
            self._run_dirty()  # between rounds nothing waits; make sure
        state = {"incident": self.id, "responders": self.responders, "unattributed": self.unattributed,
                 "counters": self.counters, "presence": self._presence, "intake": self.intake, "now": self._now,
                 "access": self.access, "early_rejects": self._early_rejects, "fleet": self.fleet,
                 "expiry_checked": self._expiry_checked}
        return snapshots.dumps(state)

    @classmethod
    def restore(cls, blob: bytes, incident: IncidentConfig, settings: CoreSettings | None = None) -> IncidentCore:
        """A core that goes on from :meth:`snapshot`'s bytes (taken by a core of the same incident)."""
        core = cls(incident, settings)
        state = snapshots.loads(blob)
        if state.get("incident") != core.id:
            raise ValueError(f"the snapshot is of incident {state.get('incident')!r}, not {core.id!r}")
        core.responders = state["responders"]
        core.unattributed = state["unattributed"]
        core.counters = state["counters"]
        core._presence = state["presence"]
        intake = state["intake"]
        intake.settings = core.settings.intake  # today's budgets over yesterday's counts
        core.intake = intake
        core._now = state["now"]
        core._expiry_checked = state["expiry_checked"]
        acc = state["access"]
        core.access, core._revoked = acc, frozenset(acc.revoked) if acc.enforce else frozenset()
        core._early_rejects = state["early_rejects"]
        if state["fleet"] is not None:  # the restored handheld trackers' slots live in it: new ones join it
            core.fleet = state["fleet"]
        return core

