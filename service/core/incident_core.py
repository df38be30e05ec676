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
core that goes on from it (:mod:`service.review.resume`).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Iterable

import numpy as np

from pdr.fleet import PdrFleet
from pdr.floors import FloorElevations
from service.core import alarms
from service.core.core_types import (
    INBOUND_KINDS,
    CoreCounters,
    CoreSettings,
    Inbound,
    Outbound,
)
from service.core.fix_intake import FixIntake
from service.core.frame_rounds import FrameRounds
from service.core.gate import FrameGate
from service.core.held_fixes import HeldFixes
from service.core.intake import OPERATORS, Intake
from service.core.operations import OperatorDesk
from service.core.pose_output import PoseOutput
from service.core.rejectlog import RejectLog
from service.core.responder import Newcomer, Responder
from service.core.tracker import (
    CheckpointFix,
    ResponderTracker,
    tracker_settings_for,
)
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")

class IncidentCore(FrameRounds, FixIntake, HeldFixes, OperatorDesk, PoseOutput):
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
        self._blobs: dict[str, bytes] = {}  # responders' pickles of the last snapshot, while they do not change
        self._out: list[Outbound] = []
        self._pose_queue: list[tuple] = []  # poses of this round waiting for their wire form
        self._now = 0.0
        self._last_take = -math.inf  # service time of the newest message taken (lags: who was heard lately)
        self._fed = self._tick_busy = False  # input since the last tick / at the last tick (service.core.lag)
        self._presence: dict[str, bool] = {}  # liveliness seen before a responder's first frame (bounded)
        self.intake = Intake(settings.intake)
        self.reject_log = RejectLog(log, settings.rejected_window_s, settings.log_rejects_per_window,
                                    settings.log_lines_per_window)
        self._expiry_checked = -math.inf
        self._last_tick = -math.inf  # service time of the last tick (spreads idle Statuses)
        self._newcomers: dict[str, Newcomer] = {}  # admitted ids none of whose messages decoded yet (bounded)
        self._held_fixes: dict = {}  # fixes for ids with no responder yet (service.core.held_fixes)
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
            self._fed = True  # a tick right after this round: the worker was busy until then (lags grow)
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
        its alarms change), so a crowd of silent ids costs little status traffic. The idle
        ones are spread over ticks (:meth:`_idle_budget`): a crowd admitted together does not
        stay in step and answer all at once every few seconds."""
        self._now = now
        self._tick_busy, self._fed = self._fed, False
        for r in list(self.responders.values()):
            try:
                for b in r.gate.expire(now):
                    self._process(r, b)
            except Exception:
                self._error(f"while releasing the held frames of {r.id}")
        self._run_dirty()
        s = self.settings
        idle_due: list[tuple[float, Responder, list[str]]] = []
        idle = 0
        for r in list(self.responders.values()):
            try:
                current = self._alarms_now(r, now)
                if now - r.last_input < s.idle_after_s or current != r.last_alarms:
                    self._send_status(r, now, current)
                    continue
                idle += 1
                if now - r.last_status >= s.idle_status_every_s:
                    idle_due.append((r.last_status, r, current))
            except Exception:
                self._error(f"status of {r.id}")
        idle_due.sort(key=lambda e: e[0])  # the longest unanswered first
        for _, r, current in idle_due[: self._idle_budget(idle, now)]:
            try:
                self._send_status(r, now, current)
            except Exception:
                self._error(f"status of {r.id}")
        self._last_tick = now
        self._emit_poses()
        out, self._out = self._out, []
        return out

    def _idle_budget(self, idle: int, now: float) -> int:
        """Idle Statuses one tick may send: the share of ``idle`` responders that falls in the
        time since the last tick (``idle × Δt / idle_status_every_s``, rounded up, at least
        one), so that each still gets one about every ``idle_status_every_s``."""
        dt = min(max(now - self._last_tick, 0.0), self.settings.idle_status_every_s)
        return max(1, math.ceil(idle * dt / self.settings.idle_status_every_s))

    def _send_status(self, r: Responder, now: float, current: list[str]) -> None:
        st = self.status_of(r, now, current)  # built only when sent: a crowd of silent ids is cheap
        self._out.append(Outbound(wire.key(self.id, r.id, "status"), st))
        r.last_status, r.last_alarms = now, st.alarms

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
                # a bad message like any other: the burst alarm hears of it (an id with no Responder
                # yet, a newcomer, passes it on when one is made)
                if r is not None:
                    self._touch(r)
                    r.rejects.append(now)
                else:
                    self._newcomer(source, now).rejects.append(now)
                self.intake.note_reject(source, now, kind)
        return reason

    # ------------------------------------------------------------------ queries
    def _alarms_now(self, r: Responder, now: float) -> list[str]:
        """The responder's alarms at ``now``; each one's start is kept in ``r.alarm_since``."""
        current = alarms.of_responder(r, now, self.settings, self.recording_failed,
                                      flooding=self.intake.flooding(r.id, now))
        for kind in [k for k in r.alarm_since if k not in current]:
            del r.alarm_since[kind]
        for kind in current:
            r.alarm_since.setdefault(kind, now)
        return current

    def status_of(self, r: Responder, now: float, current: list[str] | None = None) -> wire.Status:
        """The responder's Status at ``now`` (``current``: its alarms, when already judged at ``now``)."""
        heard = r.gate.last_heard if r.gate.last_heard is not None else r.first_heard
        motion, since = r.tracker.motion
        rejected = dict(r.gate.counts)
        tr = r.tracker
        if current is None:
            current = self._alarms_now(r, now)
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
                   **({"flagged": r.fixes_flagged} if r.fixes_flagged else {}),
                   **({"degraded": tr.degraded} if getattr(tr, "degraded", 0) else {})}, utc_offset=r.utc_offset,
            beacons_heard={b: t - r.t_offset for b, t in getattr(r, "beacons_heard", {}).items()},
            last_fix=tr.last_fix, first_heard=r.first_heard, commands={a: dict(o) for a, o in r.commands.items()},
            lost=g.lost, gap_s=g.gap_s, streams=g.streams, device=g.device, boot=g.boot, seq=g.last_seq,
            missing=None if g.missing is None else list(g.missing), lag_s=round(self._lag_of(r, now), 3),
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
        for nc in self._newcomers.values():
            for reason, n in [*nc.frames.items(), *((f"fix_{k}", v) for k, v in nc.fixes.items())]:
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
        self._now = self._last_take = now
        self.intake.in_hand = kind  # a reject of this message is charged to its lane (service.core.intake)
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

    def _source_of(self, key: str, now: float, reason_on_fail: str) -> tuple[str | None, Responder | None]:
        """The id ``key`` names and its responder; the responder is None for a newcomer (an id
        none of whose messages has decoded yet: the responder is made once one does),
        the id None for a key the core refuses (unparsable, revoked)."""
        try:
            _, rid, _ = wire.parse_key(key)
        except ValueError as e:
            self.unattributed[reason_on_fail] = self.unattributed.get(reason_on_fail, 0) + 1
            self.reject_log.note("<bad key>", reason_on_fail, str(e), now)
            return None, None
        if rid in self._revoked:
            self._refuse_revoked(rid, key)
            return None, None
        r = self.responders.get(rid)
        if r is None:
            if self.intake.in_hand != "fix":  # a fix for nobody keeps no state (see _decode_for)
                self._newcomer(rid, now).last_input = now
            return rid, None
        self._touch(r)
        r.last_input = now
        return rid, r

    def _newcomer(self, rid: str, now: float) -> Newcomer:
        n = self._newcomers.get(rid)
        if n is None:
            if len(self._newcomers) >= self.MAX_NEWCOMERS:  # fed past an intake (reprocess): the oldest goes
                self._forget_newcomer(next(iter(self._newcomers)))
            n = self._newcomers[rid] = Newcomer(first_heard=now, last_input=now)
        return n

    def _forget_newcomer(self, rid: str) -> None:
        n = self._newcomers.pop(rid)
        self.intake.forget(rid)
        self.counters.newcomers_forgotten += 1
        for reason, k in n.frames.items():  # still in the incident's accounting
            self.unattributed[f"newcomer_{reason}"] = self.unattributed.get(f"newcomer_{reason}", 0) + k
        for reason, k in n.fixes.items():
            self.unattributed[f"newcomer_fix_{reason}"] = self.unattributed.get(f"newcomer_fix_{reason}", 0) + k

    def _decode_for(self, rid: str, r: Responder | None, payload: bytes, expect, now: float):
        """``payload`` decoded as ``expect`` (``wire.ImuBatch`` or ``wire.Fix``) for ``rid``, and its
        responder: ``(message, responder)``, the responder made now if this is the first message
        of a newcomer that decodes; ``(None, None)`` when refused (counted against the responder,
        or the newcomer, with the reason)."""
        frames = expect is wire.ImuBatch
        try:
            msg = wire.decode(payload, expect=expect)
            if msg.responder != rid:
                what = "frame" if frames else "fix"
                raise wire.WireError("schema", f"responder {msg.responder!r} in a {what} on the key of {rid!r}")
        except wire.WireError as e:
            if r is None and not frames:  # a bad fix for nobody: counted for the incident, no state made
                self._unattributed(f"fix_{e.reason}", rid, e.detail, now)
                return None, None
            if r is None:  # a newcomer: no responder is made for a message that is none of its
                self._newcomer_reject(rid, "frames" if frames else "fixes", e.reason, e.detail, now)
            elif frames:
                self._reject(r, e.reason, e.detail, now)
            else:
                self._count_fix_reject(r, e.reason, e.detail)
            return None, None
        if r is None and not frames:  # fixes make no responder: only a wearable's frames do (issue 32)
            self._hold_fix(rid, msg, now)
            return None, None
        return msg, (r if r is not None else self._new_responder(rid, now))

    def _newcomer_reject(self, rid: str, counts: str, reason: str, detail: str, now: float) -> None:
        """A newcomer's message that did not decode: counted by reason (``counts``: ``frames`` or
        ``fixes``), heard by its budget and the burst alarm, logged like a responder's."""
        n = self._newcomer(rid, now)
        book = getattr(n, counts)
        book[reason] = book.get(reason, 0) + 1
        if reason != "duplicate":
            n.rejects.append(now)
            self.intake.note_reject(rid, now, "imu" if counts == "frames" else "fix")
        self.reject_log.note(rid, reason if counts == "frames" else f"fix_{reason}", detail, now)

    def _new_responder(self, rid: str, now: float) -> Responder:
        s = self.settings
        n = self._newcomers.pop(rid, None)
        r = Responder(id=rid, gate=FrameGate(reorder_window=s.reorder_window), tracker=self._tracker(rid),
                      first_heard=now if n is None else n.first_heard, present=self._presence.pop(rid, None),
                      last_input=now)
        if n is not None:  # what it sent before this is counted as the responder's
            r.rejects.extend(n.rejects)
            r.gate.add_counts(n.frames)
            r.fixes_rejected.update(n.fixes)
        self.responders[rid] = r
        self._touch(r)
        log.info("responder %s appeared", rid)
        if self._held_fixes:
            self._take_held_fixes(r, now)
        return r

    def _expire(self, now: float) -> None:
        """Responders silent for ``expire_after_s`` (``expire_unplaced_s`` if no frame of theirs
        was ever released) leave: their memory goes, their track stays in the recording."""
        self._expiry_checked = now
        if self._held_fixes:
            self._expire_held_fixes(now)
        s = self.settings
        for rid in [rid for rid, n in self._newcomers.items() if now - n.last_input > s.expire_unplaced_s]:
            self._forget_newcomer(rid)
        for rid, r in list(self.responders.items()):
            limit = s.expire_after_s if r.gate.accepted else s.expire_unplaced_s
            if now - r.last_input > limit and now - r.first_heard > limit:
                del self.responders[rid]
                self._dirty.pop(rid, None)
                self._blobs.pop(rid, None)
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
    MAX_NEWCOMERS = 4096  # newcomers kept (the intake admits fewer; a core fed past an intake is bounded too)


    def _reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A frame turned away before the gate saw it: counted there like the gate's own."""
        r.gate.count(reason, detail, now)
        self._note_reject(r, reason, detail, now)

    def _note_reject(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """Every reject feeds the burst alarm and the source's budget (a duplicate, which
        retransmission makes, does neither; frames of a contested stream feed the alarm only:
        the budget of the key is the real stream's too); the log gets a few lines per window."""
        if reason != "duplicate":
            r.rejects.append(now)
            if reason not in ("other_stream", "old_stream"):
                self.intake.note_reject(r.id, now, "imu")
        self.reject_log.note(r.id, reason, detail, now)

    def _error(self, what: str) -> None:
        """An exception while processing: counted; logged with its traceback a few times per window."""
        self.counters.errors += 1
        self.reject_log.note("<errors>", "exception", what, self._now, level=logging.ERROR, exc_info=True)


    # ------------------------------------------------------------------ who may do what


    # ------------------------------------------------------------------ outputs


    # ------------------------------------------------------------------ snapshots


