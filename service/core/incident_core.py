"""The incident core: a pure function from the messages of an incident to the messages it answers.

::

    Inbound(kind, key, payload, received, parts)  ──►  IncidentCore  ──►  Outbound(key, Pose | Status)
        imu       firetrack/{incident}/{responder}/imu        decode ─► FrameGate ─► ResponderTracker ─► pose
        fix       firetrack/{incident}/{responder}/fix        decode ─► by role ─► to the local frame ─┘
                  firetrack/{incident}/{responder}/fix-{anchor}  (an anchor's: its own UWB ranges only)
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
A responder is made for an id only when one of its messages decodes (a frame or a fix for
that id); until then the id is a :class:`service.core.responder.Newcomer`, which keeps its
rejects for the responder to take over, and costs no tracker, fleet slot or Status.
Responders silent for ``expire_after_s`` (``expire_unplaced_s`` for one that never had a frame
released, and for a newcomer) leave the core, checked as the inputs' clock passes (so ``reprocess`` lets them go at
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
core that goes on from it (:mod:`service.review.resume`, :mod:`service.core.core_snapshot`).

**Its parts.** The core holds collaborators, each given what it uses: the :class:`Roster`
(responders, newcomers; a responder is changed only through ``roster.changing``, which drops its
kept pickle), :class:`RejectBook`, :class:`Outbox` (answers in order, poses converted a round at a
time), :class:`StatusReporter`, :class:`FrameRounds` (frames into tracks), :class:`FixDesk`
(fixes by role, and fixes held for ids with no responder yet), :class:`FixAudit` (refused
fixes audited with the identity that sent them, also those the estimator holds out at a later
step) and :class:`OperatorDesk` (presence, orders, access, operator actions). The core parses each message's key once and routes it.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterable
from typing import Self

import numpy as np

from pdr.fleet import PdrFleet
from pdr.floors import FloorElevations
from service.core import core_snapshot
from service.core.core_types import (
    INBOUND_KINDS,
    CoreClock,
    CoreCounters,
    CoreSettings,
    Inbound,
    Outbound,
)
from service.core.fix_audit import FixAudit
from service.core.fix_intake import FixDesk
from service.core.frame_rounds import FrameRounds
from service.core.gate import FrameGate
from service.core.intake import OPERATORS, Intake
from service.core.lag import ServiceLag
from service.core.operations import OperatorDesk
from service.core.pose_output import Outbox, pose_message
from service.core.rejectlog import RejectLog
from service.core.rejects import RejectBook
from service.core.responder import Responder
from service.core.roster import Roster
from service.core.status_reporter import StatusReporter
from service.core.tracker import (
    CheckpointFix,
    PoseEstimate,
    ResponderTracker,
    tracker_settings_for,
)
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")


class IncidentCore:
    """Every responder of one incident: ``outputs = core.feed_round(inbound)``, ``core.tick(now)``."""

    def __init__(self, incident: IncidentConfig, settings: CoreSettings | None = None):
        settings = settings or CoreSettings()
        if settings.tracker is None:  # the incident's declination and field reach the compass
            settings = dataclasses.replace(settings, tracker=tracker_settings_for(incident))
        self.incident = incident
        self.id = incident.id
        self.settings = settings
        self.clock = CoreClock()
        self.counters = CoreCounters()
        self.lags = ServiceLag(settings.idle_after_s)  # how late frames come in (service.core.lag)
        self.intake = Intake(settings.intake)
        self.reject_log = RejectLog(log, settings.rejected_window_s, settings.log_rejects_per_window,
                                    settings.log_lines_per_window)
        self.expiry_checked = -math.inf
        pipeline = settings.tracker.pipeline
        # the handheld pipelines of all responders, run a stage at a time over the round (pdr.fleet)
        self.fleet = (PdrFleet(pipeline, FloorElevations(incident.elevations()))
                      if settings.tracker.motion is None else None)
        self.assemble()

    def assemble(self, unattributed: dict | None = None, held_fixes: dict | None = None) -> None:
        """The core's parts, given what each uses (again when :meth:`restore` has put its state in)."""
        self.rejects = RejectBook(self.intake, self.reject_log, self.counters, unattributed)
        self.roster = Roster(self.rejects.newcomer_gone)
        self.outbox = Outbox(self.incident, self.counters)
        self.status = StatusReporter(self.id, self.settings, self.intake, self.outbox, self.lags)
        self.fix_audit = FixAudit(self.clock, self.outbox)
        self.frames = FrameRounds(self.settings, self.fleet, self.clock, self.counters, self.rejects, self.outbox,
                                  self.fix_audit)
        self.fixes = FixDesk(self.incident, self.settings, self.clock, self.rejects, self.outbox, self.frames,
                             self.fix_audit, held_fixes)
        self.desk = OperatorDesk(self.incident, self.roster, self.fixes, self.rejects, self.intake, self.outbox,
                                 self.counters)

    # ------------------------------------------------------------------ what the shell reads
    @property
    def responders(self) -> dict[str, Responder]:
        return self.roster.responders

    @property
    def unattributed(self) -> dict[str, int]:
        """Rejects whose key names no valid responder (or an id with none), by reason."""
        return self.rejects.unattributed

    @property
    def recording_failed(self) -> bool:
        return self.status.recording_failed

    @recording_failed.setter
    def recording_failed(self, failed: bool) -> None:  # set by the shell: every Status then carries the alarm
        self.status.recording_failed = failed

    # ------------------------------------------------------------------ inputs
    def feed_round(self, items: Iterable[Inbound], stamp: Callable[[], float] | None = None) -> list[Outbound]:
        """Messages taken together: each is decoded and gated in turn, then every responder's
        new frames go through its tracker as one batch (a fix first runs the frames that came
        before it). The poses are those of :meth:`feed` one message at a time, bit for bit.
        ``stamp``: the clock that stamps the poses' ``published_at`` (:meth:`PoseOutput.take`)."""
        for item in items:
            try:
                self._take(item)
            except Exception:  # a bug must not stop the incident: log it, count it, go on
                self.rejects.error(f"while processing {item.key[:200]}", self.clock.now)
        self.frames.run_dirty()
        return self.outbox.take(stamp)

    def feed(self, item: Inbound) -> list[Outbound]:
        """One message: a round of one (what ``reprocess`` of a single message does)."""
        return self.feed_round((item,))

    def tick(self, now: float, stamp: Callable[[], float] | None = None) -> list[Outbound]:
        """Time passes: frames held for a missing one beyond the gate's wait are released, and
        every responder's Status is answered: at every tick while it is heard, every
        ``idle_status_every_s`` once it has been silent for ``idle_after_s`` (and at once when
        its alarms change), so a crowd of silent ids costs little status traffic
        (:meth:`StatusReporter.due`)."""
        self.clock.now = now
        self.lags.ticked()
        for r in self.roster:
            if not r.gate.waiting:  # nothing for the gate to settle: the responder does not change
                continue
            r = self.roster.changing(r.id)
            try:
                for b in r.gate.expire(now, r.taken_late_s()):
                    self.frames.process(r, b)
            except Exception:
                self.rejects.error(f"while releasing the held frames of {r.id}", now)
        self.frames.run_dirty()
        self.status.due(self.roster, now, lambda what: self.rejects.error(what, now))
        return self.outbox.take(stamp)

    def admit(self, kind: str, key: str, size: int, now: float,
              parts: wire.KeyParts | ValueError | None = None) -> str | None:
        """May a message (of ``size`` bytes, on ``key``) enter? None, or the reason it may not
        (:data:`service.core.intake.INTAKE_REASONS`), counted and logged per source. The shell
        asks before copying, recording or feeding it (see :mod:`service.core.intake`), with the
        key's ``parts`` as it read them (the same go into the message's :class:`Inbound`); a
        caller holding only the key (a test, a benchmark) leaves them out and they are read here."""
        if kind == "op":  # an operator's action: its actor is no responder; operators share one budget
            reason, source = self.intake.admit_shared(OPERATORS, size, now), OPERATORS
        else:
            if parts is None:
                parts = wire.read_key(key)
            reason, source = self.intake.admit(parts, size, now, self.roster.responders)
        if reason is not None:
            self.reject_log.note(source, reason, f"{kind} of {size} bytes on {key[:120]!r}", now)
            r = self.roster.changing(source) if reason == "oversize" else None
            if reason == "oversize" and (r is not None or source in self.intake.sources):
                # a bad message like any other: the burst alarm hears of it (an id with no Responder
                # yet, a newcomer, passes it on when one is made)
                (r if r is not None else self.roster.newcomer(source, now)).rejects.append(now)
                self.intake.note_reject(source, now, kind)
        return reason

    # ------------------------------------------------------------------ queries
    def status_of(self, r: Responder, now: float, current: list[str] | None = None) -> wire.Status:
        """The responder's Status at ``now`` (``current``: its alarms, when already judged at ``now``)."""
        return self.status.status_of(r, now, current)

    def behind_s(self, now: float) -> float:
        """How far behind the core is at ``now``: its responders' median lag (s; :mod:`service.core.lag`)."""
        return self.lags.behind_s(self.roster, now)

    def pose_message(self, r: Responder, p: PoseEstimate) -> wire.Pose:
        """The wire form of one pose (``published_at`` the core's time)."""
        lat, lon = self.outbox.geodetic(np.array([p.x], float), np.array([p.y], float))
        return pose_message(r, p, float(lat[0]), float(lon[0]), max(r.seq, 0), self.clock.now, r.utc_offset)

    def flooding_sources(self, now: float) -> list[str]:
        """Sources throttled within the flood alarm's time: responder ids, ``<bad key>``, ``<new ids>``."""
        return self.intake.flooding_sources(now)

    def track(self, rid: str) -> dict | None:
        """The responder's track so far as columns (``t, x, y, floor, heading``) and whether it
        is the smoothed one; None for an unknown responder."""
        r = self.roster.get(rid)
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
        for nc in self.roster.newcomers.values():
            for reason, n in [*nc.frames.items(), *((f"fix_{k}", v) for k, v in nc.fixes.items())]:
                out[reason] = out.get(reason, 0) + n
        for r in self.roster:
            for reason, n in r.gate.counts.items():
                out[reason] = out.get(reason, 0) + n
            out["lost"] = out.get("lost", 0) + r.gate.lost
            out["held"] = out.get("held", 0) + r.gate.held + len(r.backlog)
        return {k: v for k, v in out.items() if v}

    # ------------------------------------------------------------------ per message
    def _take(self, item: Inbound) -> None:
        """One message: its key as the shell read it (read here only when nobody did: a replay,
        a test), then to the part that takes its kind."""
        kind, key, payload, now, parts = item
        self.clock.now = now
        self.lags.took(now)  # input: a tick right after this round counts its work in the lags
        self.intake.in_hand = kind  # a reject of this message is charged to its lane (service.core.intake)
        if now - self.expiry_checked >= 1.0 or now < self.expiry_checked:
            self._expire(now)
        if kind in self.counters.received:
            self.counters.received[kind] += 1
        if kind not in INBOUND_KINDS:
            raise ValueError(f"unknown inbound kind {kind!r}; expected one of {INBOUND_KINDS}")
        if kind == "access":
            self.desk.access_policy(payload)
            return
        if parts is None:
            parts = wire.read_key(key)
        if isinstance(parts, ValueError):
            self._bad_key(kind, key, parts, now)
            return
        rid = parts.responder
        if kind in ("imu", "fix"):
            self._from_wearable(kind, rid, key, payload, now, parts.sender)
        elif kind == "presence":
            self.desk.presence(rid, key, payload)
        elif kind in ("command", "ack"):
            self.desk.command(kind, rid, key, payload)
        else:
            self.desk.action(rid, payload, now)

    def _bad_key(self, kind: str, key: str, e: ValueError, now: float) -> None:
        if kind in ("imu", "fix"):
            self.rejects.count("bad_key")
            self.reject_log.note("<bad key>", "bad_key", str(e), now)
        elif kind in ("command", "ack"):
            self.desk.invalid(kind, key, e)
        elif kind == "op":
            self.rejects.count("bad_key")
            log.warning("rejected an action on %r: %s", key, e)

    def _from_wearable(self, kind: str, rid: str, key: str, payload: bytes, now: float, anchor: str | None) -> None:
        """A frame or a fix for ``rid``: decoded; a frame through the gate, a fix to the fix desk
        (``anchor``: the anchor an anchor's fix key names, fix-{anchor}; None for the wearable's own)."""
        if self.desk.refuses(rid, key):
            return
        r = self.roster.changing(rid)
        if r is not None:
            r.last_input = now
        elif kind != "fix":  # a fix for nobody keeps no state (see _decode_for)
            self.roster.newcomer(rid, now).last_input = now
        expect = wire.ImuBatch if kind == "imu" else wire.Fix
        msg, r = self._decode_for(rid, r, payload, expect, now, anchor)
        if msg is None:
            return
        if kind == "fix":
            self.fixes.device_fix(r, msg, anchor, self.desk.access.enforce, now)
        elif self.frames.offer(r, msg, now):  # a gap in front of held frames: its Status asks for it now
            self.status.send(r, now)

    def _decode_for(self, rid: str, r: Responder | None, payload: bytes, expect, now: float,
                    anchor: str | None = None):
        """``payload`` decoded as ``expect`` (``wire.ImuBatch`` or ``wire.Fix``) for ``rid``, and its
        responder: ``(message, responder)``, the responder made now if this is the first message
        of a newcomer that decodes; ``(None, None)`` when refused (counted against the responder,
        or the newcomer, with the reason; a fix's refusal audited with its sender, ``anchor`` or
        the wearable)."""
        frames = expect is wire.ImuBatch
        try:
            msg = wire.decode(payload, expect=expect)
            if msg.responder != rid:
                what = "frame" if frames else "fix"
                raise wire.WireError("schema", f"responder {msg.responder!r} in a {what} on the key of {rid!r}")
        except wire.WireError as e:
            if r is None and not frames:  # a bad fix for nobody: counted for the incident, no state made
                self.rejects.unknown(f"fix_{e.reason}", rid, e.detail, now)
            elif r is None:  # a newcomer: no responder is made for a message that is none of its
                self.rejects.newcomer(self.roster.newcomer(rid, now), rid, "frames", e.reason, e.detail, now)
            elif frames:
                self.rejects.frame(r, e.reason, e.detail, now)
            else:
                self.fixes.refuse(r, e.reason, e.detail, anchor or rid)
            return None, None
        if r is None and not frames:  # fixes make no responder: only a wearable's frames do (issue 32)
            self.fixes.hold(rid, msg, anchor, now)
            return None, None
        return msg, (r if r is not None else self._new_responder(rid, now))

    def _new_responder(self, rid: str, now: float) -> Responder:
        s = self.settings
        n = self.roster.newcomers.pop(rid, None)
        r = Responder(id=rid, gate=FrameGate(reorder_window=s.reorder_window, ask_from_start=s.ask_from_start),
                      tracker=self._tracker(rid),
                      first_heard=now if n is None else n.first_heard, present=self.roster.presence.pop(rid, None),
                      last_input=now)
        r.gate.who = rid
        if n is not None:  # what it sent before this is counted as the responder's
            r.rejects.extend(n.rejects)
            r.gate.add_counts(n.frames)
            r.fixes_rejected.update(n.fixes)
        self.roster.add(r)
        log.info("responder %s appeared", rid)
        if self.fixes.held:
            self.fixes.take_held(r, self.desk.access.enforce, now)
        return r

    def _expire(self, now: float) -> None:
        """Responders silent for ``expire_after_s`` (``expire_unplaced_s`` if no frame of theirs
        was ever released) leave: their memory goes, their track stays in the recording."""
        self.expiry_checked = now
        if self.fixes.held:
            self.fixes.expire_held(now)
        s = self.settings
        self.roster.expire_newcomers(now, s.expire_unplaced_s)
        for r in self.roster:
            limit = s.expire_after_s if r.gate.accepted else s.expire_unplaced_s
            if now - r.last_input > limit and now - r.first_heard > limit:
                self.roster.remove(r.id)
                self.frames.dirty.pop(r.id, None)
                self.intake.forget(r.id)
                r.tracker.release_model()  # e.g. its columnar slot goes to the next responder
                self.counters.expired += 1
                # a responder that walked is news; an id that never did is one of a crowd (a flood of ids)
                (log.warning if r.tracker.steps else log.info)(
                    "%s left the incident after %.0f s of silence (%d steps, %d poses; its track is in the recording)",
                    r.id, now - max(r.last_input, r.first_heard), r.tracker.steps, r.poses)

    def _tracker(self, rid: str) -> ResponderTracker:
        """A fresh tracker; not yet placed, it starts at the incident origin with a wide σ
        until a checkpoint fix says where the responder is."""
        cfg, s = self.incident, self.settings
        entry = (None if s.entry_sigma_m is None
                 else CheckpointFix(0.0, 0.0, 0.0, cfg.start_floor, s.entry_sigma_m, "origin (unplaced)"))
        return ResponderTracker(rid, FloorElevations(cfg.elevations()), cfg.start_floor, s.tracker, entry=entry,
                                fleet=self.fleet)

    # ------------------------------------------------------------------ snapshots
    def snapshot(self) -> bytes:
        """The core's state as bytes (between rounds): every responder (gate, motion model,
        estimator, counters), the intake's budgets and the counters. Not the incident config or
        the settings: :meth:`restore` takes those from the caller. A responder that has not
        changed since the last snapshot is not pickled again (:mod:`service.core.core_snapshot`)."""
        return core_snapshot.dump(self)

    def prepare_snapshot(self, limit: int) -> int:
        """Pickle (and keep) up to ``limit`` of the responders the next snapshot would pickle
        afresh; returns how many are left (the shell spreads a crowd's pickling over rounds)."""
        return self.roster.prepare(limit, self.frames.dirty, lambda: core_snapshot.shared_refs(self))

    def responder_blob(self, r: Responder) -> bytes:
        """``r``'s own pickle as a snapshot would hold it now (its Status bookkeeping aside)."""
        return self.roster.blob_of(r, core_snapshot.shared_refs(self))

    @classmethod
    def restore(cls, blob: bytes, incident: IncidentConfig, settings: CoreSettings | None = None) -> Self:
        """A core that goes on from :meth:`snapshot`'s bytes (taken by a core of the same incident)."""
        return core_snapshot.load(cls(incident, settings), blob)
