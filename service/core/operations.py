"""Presence, orders and acknowledgements, the access policy, operator actions and their audit.

:class:`OperatorDesk` is a collaborator of :class:`service.core.incident_core.IncidentCore`;
the core parses each message's key and hands the desk the id it names.
"""
from __future__ import annotations

import logging

from service.core.core_types import MAX_EARLY_ACKS, CoreCounters
from service.core.fix_intake import FixDesk
from service.core.intake import Intake
from service.core.pose_output import Outbox
from service.core.rejects import RejectBook
from service.core.responder import STATUS_OWED
from service.core.roster import Roster
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")


class OperatorDesk:
    """Presence, orders and acknowledgements, access policy and operator actions with their audit."""

    def __init__(self, incident: IncidentConfig, roster: Roster, fixes: FixDesk, rejects: RejectBook, intake: Intake,
                 outbox: Outbox, counters: CoreCounters):
        self.incident, self.roster, self.fixes, self.rejects = incident, roster, fixes, rejects
        self.intake, self.outbox, self.counters = intake, outbox, counters
        self.access = wire.Access(enforce=False)  # until an access message says otherwise: the open demo
        self.revoked: frozenset[str] = frozenset()
        self._refused_logged: set[str] = set()

    def refuses(self, ident: str, key: str) -> bool:
        """Is ``ident`` revoked? Its message on ``key`` is then refused (counted, logged once)."""
        if ident not in self.revoked:
            return False
        self.rejects.count("revoked")
        if ident not in self._refused_logged:
            self._refused_logged.add(ident)
            log.warning("refused %s: %s is revoked", key, ident)
        return True

    def presence(self, rid: str, key: str, payload: bytes) -> None:
        """The liveliness of a wearable (``b"1"`` connected, ``b"0"`` gone)."""
        if self.refuses(rid, key):
            return
        alive = payload == b"1"
        self.roster.note_presence(rid, alive)
        log.info("wearable of %s %s", rid, "connected" if alive else "disconnected")

    def command(self, kind: str, rid: str, key: str, payload: bytes) -> None:
        """An order to a wearable (roll call, evacuation) or its acknowledgement: kept per
        responder and action, so Status says who has not answered."""
        if kind == "ack" and self.refuses(rid, key):
            return
        try:
            msg = wire.decode(payload, expect=wire.Command if kind == "command" else wire.Ack)
        except wire.WireError as e:
            self.invalid(kind, key, e)
            return
        r = self.roster.changing(rid) if msg.responder == rid else None
        if r is None:
            self.rejects.count(f"{kind}_unknown_responder")
            return
        if kind == "ack" and msg.action == "ok":  # the wearer answered the man-down prompt: the clock starts again
            t = msg.t + r.t_offset  # the current stream's device clock -> the track's
            if t > r.ok_at:
                r.ok_at = t
                r.last_status = STATUS_OWED  # the answer goes out at the next tick, not with an idle Status seconds later
                log.info("%s answered the man-down prompt: I'm OK (device t %.1f s)", rid, msg.t)
            return
        if kind == "command":  # an acknowledgement may have overtaken its order (other key, other path)
            early = r.early_acks.pop((msg.action, msg.id), None)
            r.commands[msg.action] = {"id": msg.id, "issued_at": msg.issued_at, "issued_by": msg.issued_by,
                                      "acked_at": early}
            r.last_status = STATUS_OWED  # the console sees the order (who is waiting) at the next tick
            log.info("%s: %s %s issued by %s", rid, msg.action, msg.id, msg.issued_by or "?")
            return
        order = r.commands.get(msg.action)
        if order is not None and order["id"] == msg.id:
            if order["acked_at"] is None:
                order["acked_at"] = msg.at
                r.last_status = STATUS_OWED  # the console sees the answer at the next tick
                log.info("%s acknowledged %s %s", rid, msg.action, msg.id)
        elif len(r.early_acks) < MAX_EARLY_ACKS:
            r.early_acks[(msg.action, msg.id)] = msg.at

    def restore_policy(self, acc: wire.Access) -> None:
        """The policy a snapshot held, with today's roster of wearables added to the intake's."""
        self.access = acc
        self.revoked = frozenset(acc.revoked) if acc.enforce else frozenset()
        self.intake.set_roster(frozenset(acc.wearables))

    def invalid(self, kind: str, key: str, e: Exception) -> None:
        """An order or acknowledgement on a bad key, or one that is none: counted, logged."""
        self.rejects.count(f"{kind}_invalid")
        log.warning("rejected a %s on %r: %s", kind, key, e)

    def access_policy(self, payload: bytes) -> None:
        """The access policy from now on (who may act, who is revoked, the wearables' roster)."""
        try:
            acc = wire.decode(payload, expect=wire.Access)
        except wire.WireError as e:  # the service's own message: a bug, loud
            self.counters.errors += 1
            log.error("access policy not understood, the previous one stays: %s", e)
            return
        first = self.access == wire.Access(enforce=False)
        self.access = acc
        self.revoked = frozenset(acc.revoked) if acc.enforce else frozenset()
        self.intake.set_roster(frozenset(acc.wearables))  # a wearable added to the roster is admitted from now on
        self._refused_logged.clear()
        log.log(logging.INFO if first else logging.WARNING, "access policy%s: %s",
                f" from {acc.source}" if acc.source else "",
                    (f"operators {', '.join(acc.operators) or 'none'}; revoked {', '.join(acc.revoked) or 'none'}")
                    if acc.enforce else "open (nothing enforced)")

    def action(self, actor: str, payload: bytes, now: float) -> None:
        """An operator action: refused unless the actor may act (and is not revoked); a fix
        goes to its responder's tracker; every action is answered with an Audit."""
        try:
            op = wire.decode(payload, expect=wire.OperatorAction)
        except wire.WireError as e:
            self.rejects.count(f"op_{e.reason}")
            log.warning("rejected an action of %s: %s", actor, e)
            return
        base = dict(actor=actor, operator=op.operator, action=op.action, responder=op.responder, utc=op.utc,
                    received=now, order=op.order)
        acc = self.access
        if acc.enforce and (actor in self.revoked or actor not in acc.operators):
            reason = "revoked" if actor in self.revoked else "unauthorised"
            log.warning("refused a %s action of %s (%s): %s", op.action, actor, op.operator, reason)
            self.outbox.audit(wire.Audit(outcome="refused", reason=reason,
                                   detail=f"{actor} {'is revoked' if reason == 'revoked' else 'may not act as an operator'}",
                                   **base))
            return
        if op.action == "beacon":
            self._drop_beacon(op, base)
            return
        if op.action != "fix":
            log.info("%s (%s): %s %s", actor, op.operator, op.action, op.responder or op.name or op.order or "")
            self.outbox.audit(wire.Audit(outcome="recorded", **base))
            return
        try:
            fix = wire.decode(op.fix, expect=wire.Fix)
        except wire.WireError as e:
            self.outbox.audit(wire.Audit(outcome="refused", reason="schema", detail=e.detail[:500], **base))
            return
        r = self.roster.get(op.responder)
        if fix.responder != op.responder or r is None or op.responder in self.revoked:
            reason, detail = (("schema", f"the fix is for {fix.responder!r}, the action for {op.responder!r}")
                              if fix.responder != op.responder else
                              ("revoked", f"{op.responder} is revoked") if op.responder in self.revoked else
                              ("unknown_responder", f"no frame of {op.responder!r} has been taken yet"))
            self.outbox.audit(wire.Audit(outcome="refused", reason=reason, detail=detail, **base))
            return
        x, y = getattr(fix, "x", None), getattr(fix, "y", None)
        if x is not None and y is not None and not self.incident.within_extent(x, y):  # a slip of the hand
            self.outbox.audit(wire.Audit(outcome="refused", reason="outside_extent", t=fix.t, **base,
                                   detail=f"({x:.6g}, {y:.6g}) m is outside the incident's extent "
                                          f"({self.incident.extent_m:g} m from the origin)"))
            return
        r = self.roster.changing(op.responder)
        outcome, reason, detail, verdict = self.fixes.take(r, fix, authoritative=True, sender=actor)
        flagged = verdict is not None and verdict.implausible
        self.outbox.audit(wire.Audit(outcome=outcome, reason=reason, detail=detail, t=fix.t,
                               flags=["implausible_jump"] if flagged else [],
                               jump_m=verdict.jump_m if verdict is not None else None,
                               walkable_m=verdict.walkable_m if verdict is not None else None, **base))

    def _drop_beacon(self, op, base: dict) -> None:
        """A breadcrumb: beacon ``op.name`` is where ``op.responder`` is estimated now, on their
        floor, its sigma their position's largest 1-sigma (m); it joins the incident's beacons."""
        from service.core.plausibility import semi_major
        from service.protocol.incident import MAX_BEACONS, Beacon

        r = self.roster.get(op.responder)
        live = r.tracker.live if r is not None else None
        refuse = (("unknown_responder", f"{op.responder} has no position yet") if live is None else
                  ("duplicate", f"beacon {op.name!r} is placed already") if self.incident.beacon(op.name) is not None else
                  ("full", f"the incident has {MAX_BEACONS} beacons already") if len(self.incident.beacons) >= MAX_BEACONS
                  else None)
        if refuse is None:
            try:
                b = Beacon(id=op.name, x=live.x, y=live.y, floor=live.floor, sigma_m=max(semi_major(live.cov), 0.1),
                           note=f"dropped by {op.responder} at device time {live.t:.1f} s ({op.operator})")
                self.incident.resolve_point(b)
            except ValueError as e:  # an id a beacon cannot have
                refuse = ("schema", str(e).splitlines()[-1][:500])
        if refuse is not None:
            self.outbox.audit(wire.Audit(outcome="refused", reason=refuse[0], detail=refuse[1], **base))
            return
        self.incident.beacons.append(b)
        log.info("%s (%s): beacon %s dropped by %s at (%.1f, %.1f) floor %d, sigma %.1f m", base["actor"],
                 op.operator, b.id, op.responder, b.x, b.y, b.floor, b.sigma_m)
        self.outbox.audit(wire.Audit(outcome="accepted", t=live.t, detail=f"beacon {b.id} at ({b.x:.1f}, {b.y:.1f}) m, floor "
                                                                     f"{b.floor}, sigma {b.sigma_m:.1f} m", **base))
