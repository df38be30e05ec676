"""The core's book of what it turned away: counted per responder (its Status), per newcomer, or
for the incident (``unattributed``), heard by the source's budget and the burst alarm, logged a
few times per window (:mod:`service.core.rejectlog`). A collaborator of the incident core and
its parts: each reject is one call here."""
from __future__ import annotations

import logging

from service.core.core_types import CoreCounters
from service.core.intake import Intake
from service.core.rejectlog import RejectLog
from service.core.responder import Newcomer, Responder
from service.protocol import wire


class RejectBook:
    """Counts, budgets and log lines of rejected messages, in one place."""

    def __init__(self, intake: Intake, reject_log: RejectLog, counters: CoreCounters,
                 unattributed: dict[str, int] | None = None):
        self.intake = intake
        self.log = reject_log
        self.counters = counters
        self.unattributed: dict[str, int] = {} if unattributed is None else unattributed  # no valid responder named

    def count(self, reason: str, k: int = 1) -> None:
        """A reject counted for the incident only (no responder to charge it to)."""
        self.unattributed[reason] = self.unattributed.get(reason, 0) + k

    def unknown(self, reason: str, rid: str, detail: str, now: float) -> None:
        """A message for an id with no responder, counted for the incident and logged."""
        self.count(reason)
        self.log.note("<unknown responders>", reason, f"{rid}: {detail}", now)

    def frame(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A frame turned away before the gate saw it: counted there like the gate's own."""
        r.gate.count(reason, detail, now)
        self.noted(r, reason, detail, now)

    def noted(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A frame reject already counted (by the gate): it feeds the burst alarm and the
        source's budget (a duplicate, which retransmission makes, does neither; frames of a
        contested stream feed the alarm only: the budget of the key is the real stream's too);
        the log gets a few lines per window."""
        if reason != "duplicate":
            r.rejects.append(now)
            if reason not in ("other_stream", "old_stream"):
                self.intake.note_reject(r.id, now, "imu")
        self.log.note(r.id, reason, detail, now)

    def fix(self, r: Responder, reason: str, detail: str, now: float) -> None:
        """A fix for ``r`` refused: counted in its Status; one that is no fix at all (a schema
        error, ...) is heard by the source's budget too."""
        r.fixes_rejected[reason] = r.fixes_rejected.get(reason, 0) + 1
        if reason in wire.REJECT_REASONS:
            r.rejects.append(now)
            self.intake.note_reject(r.id, now)
        self.log.note(r.id, f"fix_{reason}", detail, now)

    def newcomer(self, n: Newcomer, rid: str, counts: str, reason: str, detail: str, now: float) -> None:
        """A newcomer's message that did not decode: counted by reason (``counts``: ``frames`` or
        ``fixes``), heard by its budget and the burst alarm, logged like a responder's."""
        book = getattr(n, counts)
        book[reason] = book.get(reason, 0) + 1
        if reason != "duplicate":
            n.rejects.append(now)
            self.intake.note_reject(rid, now, "imu" if counts == "frames" else "fix")
        self.log.note(rid, reason if counts == "frames" else f"fix_{reason}", detail, now)

    def newcomer_gone(self, rid: str, n: Newcomer) -> None:
        """A newcomer that leaves without a responder: its counts stay in the incident's accounting."""
        self.intake.forget(rid)
        self.counters.newcomers_forgotten += 1
        for reason, k in n.frames.items():
            self.count(f"newcomer_{reason}", k)
        for reason, k in n.fixes.items():
            self.count(f"newcomer_fix_{reason}", k)

    def error(self, what: str, now: float) -> None:
        """An exception while processing: counted; logged with its traceback a few times per window."""
        self.counters.errors += 1
        self.log.note("<errors>", "exception", what, now, level=logging.ERROR, exc_info=True)
