"""Refused fixes audited with the identity that sent them (issue 32): who sent each fix a
responder's tracker holds, and an Audit for every fix refused by role, undecodable, or held
out by the estimator's walk gate, now or later (a queued checkpoint is judged at its step).

The estimator judges a fix when it has a step to judge it against, which may be a later
round than the one the fix came in; so the sender is kept with the fix's ``(source, t)``
(``Responder.fix_senders``, the newest :data:`SENDERS_KEPT`) and looked up when the tracker
says it held the fix out (``ResponderTracker.held_out``). The wearable's own GNSS and BLE,
gated routinely indoors, are counted in Status but neither audited nor alarmed
(:data:`ROUTINE_GATED`). Every refusal sets ``Responder.last_fix_refused``, the
``fixes_refused`` alarm's clock (:mod:`service.core.alarms`). A fix the walk gate held out
and a later fix showed right (a turn: :mod:`service.fusion.walk_gate`) is audited again,
``accepted`` with reason ``fix_readmitted``, naming the same sender: the log is appended to,
never rewritten, and its newest word on a fix is the one that holds.

A collaborator of :class:`service.core.fix_intake.FixDesk` (fixes as they come) and
:class:`service.core.frame_rounds.FrameRounds` (fixes the tracker judges at a step).
"""
from __future__ import annotations

from service.core.core_types import CoreClock
from service.core.pose_output import Outbox
from service.core.responder import Responder
from service.protocol import wire

ROUTINE_GATED = ("gnss", "ble")  # sources a wearable measures itself whose gating is routine, not news
SENDERS_KEPT = 256  # fixes per responder whose sender is remembered until the estimator has judged them


class FixAudit:
    """Senders of the fixes a tracker holds, and the audits of refused fixes naming them."""

    def __init__(self, clock: CoreClock, outbox: Outbox):
        self.clock, self.outbox = clock, outbox

    def sent(self, r: Responder, source: str, t: float, sender: str) -> None:
        """``sender`` sent ``r`` the fix of ``source`` at device time ``t`` (the tracker's clock)."""
        senders = r.fix_senders
        senders[(source, float(t))] = sender
        while len(senders) > SENDERS_KEPT:
            del senders[next(iter(senders))]

    def refused(self, r: Responder, sender: str | None, reason: str, detail: str, t: float | None = None) -> None:
        """A fix for ``r`` refused (``reason`` without its ``fix_`` prefix): the alarm's clock set;
        audited naming ``sender`` when a device sent it (None: an operator's fix, whose action
        is audited by the operator desk)."""
        r.last_fix_refused = self.clock.now
        if sender is not None:
            self.outbox.audit(wire.Audit(actor=sender, action="device_fix", outcome="refused", responder=r.id,
                                         reason=f"fix_{reason}", detail=detail[:500], t=t, received=self.clock.now))

    def tracker_verdicts(self, r: Responder) -> set[tuple[str, float]]:
        """An audit for each fix the estimator held out since the last look, naming who sent it,
        and for each it took later after all; returns the held-out ones' ``(source, t)``. Called
        whenever ``r``'s tracker has run."""
        held, senders = r.tracker.held_out, r.fix_senders
        seen = set()
        while held:
            source, t, reason = held.popleft()
            seen.add((source, t))
            # a walk-gate refusal may be withdrawn by a later fix: its sender is kept to name then
            sender = senders.get((source, t), r.id) if reason == "walk_gate" else senders.pop((source, t), r.id)
            if sender == r.id and source in ROUTINE_GATED:  # the wearable's own radio fixes, gated as usual:
                continue  # counted in Status.rejected, no audit or alarm (GNSS indoors is gated all the time)
            self.refused(r, sender, reason, f"{source} fix held out by the estimator ({reason})" + (
                ": further from dead reckoning than the walk allows" if reason == "walk_gate" else ""), t=t)
        taken = r.tracker.readmitted
        while taken:
            source, t = taken.popleft()
            sender = senders.pop((source, t), r.id)
            if sender == r.id and source in ROUTINE_GATED:
                continue  # its refusal was not audited either
            self.outbox.audit(wire.Audit(actor=sender, action="device_fix", outcome="accepted", responder=r.id,
                                         reason="fix_readmitted", t=t, received=self.clock.now,
                                         detail=f"{source} fix held out by the walk gate, then shown right by a later "
                                                "fix (the walk had turned): taken into the track"))
        return seen
