"""Fixes for a responder: validation, its device clock, plausibility, then its graph.

A mixin of :class:`service.core.incident_core.IncidentCore` (its state and settings).
"""
from __future__ import annotations

import dataclasses

import logging
import math

from service.core.fix_types import FixRejected, fix_type_of
from service.core.plausibility import Reference, judge, semi_major
from service.core.responder import Responder
from service.core.tracker import (
    CheckpointFix,
)
from service.protocol import wire
from service.protocol.incident import MAX_BEACONS

log = logging.getLogger("firetrack.service")


class FixIntake:
    """Fixes for a responder: validation, the device clock, plausibility, the graph."""

    def _on_fix(self, key: str, payload: bytes, now: float) -> None:
        rid, r = self._source_of(key, now, "bad_key")
        if rid is None:
            return
        fix, r = self._decode_for(rid, r, payload, wire.Fix, now)
        if fix is None:
            return
        outcome, reason, detail, verdict = self._take_fix(r, fix)
        if verdict is not None and verdict.implausible:  # a device's checkpoint fix: taken, flagged, audited
            self._audit(wire.Audit(actor=r.id, action="device_fix", outcome=outcome, responder=r.id, reason=reason,
                                   detail=detail, flags=["implausible_jump"], jump_m=verdict.jump_m,
                                   walkable_m=verdict.walkable_m, t=fix.t, received=now))

    def _take_fix(self, r: Responder, fix: wire.Fix, authoritative: bool = False):
        """A decoded fix for ``r`` to its tracker: ``(outcome, reason, detail, verdict)``,
        outcome ``accepted`` or ``refused`` (reason and detail say why), ``verdict`` the
        plausibility of a checkpoint fix (None for other sources). An ``authoritative`` checkpoint
        (an operator who sees the responder) is flagged when implausible but not held out by the
        estimator's walk gate: it is how a commander corrects a track that has drifted far."""
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
            if authoritative:
                domain = dataclasses.replace(domain, authoritative=True)
        if getattr(domain, "source", None) == "ble":  # when each beacon was last heard, for Status and the console
            heard = r.__dict__.setdefault("beacons_heard", {})
            for reading in domain.readings:
                if reading.beacon in heard or len(heard) < MAX_BEACONS:
                    heard[reading.beacon] = max(heard.get(reading.beacon, -math.inf), domain.t)
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
