"""Fixes for a responder: validation, its device clock, plausibility, then its graph; and fixes
for ids that have no responder, held a little, never a reason to make one (issue 32).

A fix names a responder by its key; anyone the router lets put fixes (an anchor, an operator's
tool) can name any id. A responder is made only by its wearable's frames, so a fix for an id
with no responder is held (at most :attr:`FixDesk.MAX_HELD_FIXES` over all ids, for
:attr:`FixDesk.HELD_FIX_S`): a wearable whose door fix went out just before its first frame
is still placed by it, and fixes for ids that never send a frame are dropped and counted
(``fix_unknown_responder``), with no responder, Status or console row made for them.

**Fixes by role** (issue 32, :meth:`FixDesk.by_role`). An anchor puts on ``{r}/fix-{anchor}``
(the router lets only that anchor's certificate put there, :mod:`service.protocol.access`) and
is taken for UWB ranges from its own anchor id only. With access enforced, a responder's own
wearable places itself only at a surveyed checkpoint it names, at the config's position. Every
refusal is counted and audited with the identity that sent it (:mod:`service.core.fix_audit`).

:class:`FixDesk` is a collaborator of :class:`service.core.incident_core.IncidentCore`.
"""
from __future__ import annotations

import dataclasses

import logging
import math

from service.core.core_types import CoreClock, CoreSettings
from service.core.fix_audit import FixAudit
from service.core.fix_types import FixRejected, fix_type_of
from service.core.frame_rounds import FrameRounds
from service.core.pose_output import Outbox
from service.core.plausibility import Reference, judge, semi_major
from service.core.rejects import RejectBook
from service.core.responder import Responder
from service.core.tracker import (
    CheckpointFix,
)
from service.protocol import wire
from service.protocol.incident import MAX_BEACONS, IncidentConfig

log = logging.getLogger("firetrack.service")


class FixDesk:
    """Fixes for a responder: validation, the device clock, plausibility, the graph; fixes
    waiting for their responder's first frame."""

    MAX_HELD_FIXES = 256  # fixes kept for ids with no responder (over all ids; beyond, the oldest go)
    HELD_FIX_S = 10.0  # s such a fix waits for its responder's first frame

    def __init__(self, incident: IncidentConfig, settings: CoreSettings, clock: CoreClock, rejects: RejectBook,
                 outbox: Outbox, frames: FrameRounds, audit: FixAudit, held: dict | None = None):
        self.incident, self.settings, self.clock = incident, settings, clock
        self.rejects, self.outbox, self.frames, self.audit = rejects, outbox, frames, audit
        # rid -> [(received, Fix, anchor or None)] before its first frame (a snapshot from before
        # senders were kept holds pairs: the wearable's own)
        self.held: dict[str, list] = {rid: [(e[0], e[1], e[2] if len(e) > 2 else None) for e in v]
                                      for rid, v in (held or {}).items()}

    def device_fix(self, r: Responder, fix: wire.Fix, anchor: str | None, enforced: bool, now: float) -> None:
        """A fix a device sent for ``r``: its wearable's (``anchor`` None) or anchor ``anchor``'s,
        judged by role (``enforced``: the access policy is enforced), then to the track; an
        implausible checkpoint is taken, flagged and audited; a refusal is audited with the sender."""
        sender = anchor or r.id
        fix, reason, detail = self.by_role(r, anchor, fix, enforced)
        if fix is None:
            self.refuse(r, reason, detail, sender)
            return
        outcome, reason, detail, verdict = self.take(r, fix, sender=sender)
        if verdict is not None and verdict.implausible:  # flagged and audited (held out or taken)
            self.outbox.audit(wire.Audit(actor=sender, action="device_fix", outcome=outcome, responder=r.id,
                                         reason=reason, detail=detail, flags=["implausible_jump"],
                                         jump_m=verdict.jump_m, walkable_m=verdict.walkable_m, t=fix.t, received=now))

    def by_role(self, r: Responder, anchor: str | None, fix: wire.Fix, enforced: bool):
        """What the sender may claim of ``r``: ``(fix, None, None)`` to go on, or ``(None, reason, detail)``.

        * An **anchor** (its key ``{r}/fix-{anchor}``) sends UWB ranges from its own anchor id
          only: nothing else is a measurement it can make.
        * The responder's own **wearable**, when access is ``enforced`` (TLS with a roster),
          places itself only at a *surveyed* checkpoint it passes: the fix names a checkpoint of
          the incident, and its position, σ and floor are the config's, whatever the message
          says. A checkpoint at ``x``, ``y`` is an operator's (the console, with a login), never
          a device's; so no device can drag a track by checkpoints, however consistent.
        """
        if anchor is not None:
            if fix.source != "uwb":
                return None, "not_an_anchor_fix", (f"anchor {anchor} sent a {fix.source} fix for {r.id}: an anchor "
                                                   "sends its own UWB ranges only")
            if fix.anchor != anchor:
                return None, "wrong_anchor", (f"anchor {anchor} sent a range from anchor {fix.anchor!r} for {r.id}: "
                                              "an anchor sends its own ranges only")
        elif fix.source == "checkpoint" and enforced:
            if fix.name is None:
                return None, "unsurveyed_checkpoint", (f"{r.id}'s wearable sent a checkpoint at x, y: a device names a "
                                                       "surveyed checkpoint of the incident (x, y are an operator's)")
            fix = fix.model_copy(update={"x": None, "y": None, "sigma": None, "floor": None})
        return fix, None, None

    def refuse(self, r: Responder, reason: str, detail: str, sender: str | None) -> None:
        """A fix for ``r`` refused: counted in its Status (:meth:`RejectBook.fix`) and audited
        with ``sender``, the device that sent it (None: an operator's, audited by its action)."""
        self.rejects.fix(r, reason, detail, self.clock.now)
        self.audit.refused(r, sender, reason, detail)

    def take(self, r: Responder, fix: wire.Fix, authoritative: bool = False, sender: str | None = None):
        """A decoded fix for ``r`` to its tracker: ``(outcome, reason, detail, verdict)``,
        outcome ``accepted`` or ``refused`` (reason and detail say why), ``verdict`` the
        plausibility of a checkpoint fix (None for other sources). An ``authoritative`` checkpoint
        (an operator who sees the responder) is flagged when implausible but not held out by the
        estimator's walk gate: it is how a commander corrects a track that has drifted far.
        ``sender`` names who sent it in the audits of its refusal (a device's fix is audited
        here; an operator's, ``authoritative``, by the operator desk's answer to its action)."""
        self.frames.run_backlog(r)  # the frames that came before the fix go first (its time is judged against them)
        device = None if authoritative else (sender or r.id)
        try:
            fix = self._on_device_clock(r, fix)
            domain = fix_type_of(fix.source).to_domain(fix, self.incident)
            if hasattr(domain, "at_height"):  # a 3D measurement: the tag is on the responder's floor
                domain = domain.at_height(self._tag_height(r))
        except FixRejected as e:
            self.refuse(r, e.reason, str(e), device)
            return "refused", e.reason, str(e), None
        except ValueError as e:  # a domain fix that checks itself (service.fusion.fixes)
            self.refuse(r, "unknown_reference", str(e), device)
            return "refused", "unknown_reference", str(e), None
        verdict = None
        if isinstance(domain, CheckpointFix):
            verdict = self._plausibility(r, domain)
            if verdict is not None and verdict.implausible:
                r.fixes_flagged += 1
                log.warning("%s: checkpoint fix %.0f m from the %s, at most %.0f m walkable: taken, flagged",
                            r.id, verdict.jump_m, verdict.against.replace("_", " "), verdict.walkable_m)
            r.last_checkpoint = Reference(domain.t, domain.x, domain.y, domain.sigma)
            if authoritative:
                domain = dataclasses.replace(domain, authoritative=True)
        if getattr(domain, "source", None) == "ble":  # when each beacon was last heard, for Status and the console
            heard = r.beacons_heard
            for reading in domain.readings:
                if reading.beacon in heard or len(heard) < MAX_BEACONS:
                    heard[reading.beacon] = max(heard.get(reading.beacon, -math.inf), domain.t)
        self.audit.sent(r, domain.source, domain.t, sender or r.id)  # for the audit of a later refusal
        pose = r.tracker.on_fix(domain)
        if (domain.source, float(domain.t)) in self.audit.tracker_verdicts(r):  # judged at once: held out
            return "refused", "walk_gate", "held out by the estimator: further than the walk allows", verdict
        log.info("%s: %s fix at device time %.2f%s", r.id, fix.source, fix.t, " applied" if pose else " queued")
        if pose is not None:
            self.outbox.pose(r, pose, self.clock.now)
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

    def hold(self, rid: str, fix: wire.Fix, anchor: str | None, now: float) -> None:
        """A fix for an id with no responder: held (bounded) for :data:`HELD_FIX_S`, so a
        wearable's door fix sent just before its first frame still places it; anything else
        (a fix for an id that never sends a frame) is dropped, counted ``fix_unknown_responder``."""
        held = self.held
        held.setdefault(rid, []).append((now, fix, anchor))
        while sum(len(v) for v in held.values()) > self.MAX_HELD_FIXES:
            old = next(iter(held))
            held[old].pop(0)
            if not held[old]:
                del held[old]
            self.rejects.unknown("fix_unknown_responder", old, "held fixes over their bound", now)

    def take_held(self, r: Responder, enforced: bool, now: float) -> None:
        """The fixes held for a responder just made, in the order they came, judged by who sent
        them (as if it had been there)."""
        for received, fix, anchor in self.held.pop(r.id, []):
            if now - received <= self.HELD_FIX_S:
                self.device_fix(r, fix, anchor, enforced, now)
            else:
                self.rejects.unknown("fix_unknown_responder", r.id, "a fix that came too long before its first frame", now)

    def expire_held(self, now: float) -> None:
        for rid in [rid for rid, v in self.held.items() if now - v[-1][0] > self.HELD_FIX_S]:
            for _, _, anchor in self.held.pop(rid):
                detail = f"no frame of {rid!r} came within {self.HELD_FIX_S:g} s of its fix"
                self.rejects.unknown("fix_unknown_responder", rid, detail, now)
                self.outbox.audit(wire.Audit(actor=anchor or rid, action="device_fix", outcome="refused", responder=rid,
                                             reason="fix_unknown_responder", detail=detail, received=now))
