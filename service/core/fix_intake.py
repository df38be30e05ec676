"""Fixes for a responder: validation, its device clock, plausibility, then its graph; and fixes
for ids that have no responder, held a little, never a reason to make one (issue 32).

A fix names a responder by its key; anyone the router lets put fixes (an anchor, an operator's
tool) can name any id. A responder is made only by its wearable's frames, so a fix for an id
with no responder is held (at most :attr:`FixDesk.MAX_HELD_FIXES` over all ids, for
:attr:`FixDesk.HELD_FIX_S`): a wearable whose door fix went out just before its first frame
is still placed by it, and fixes for ids that never send a frame are dropped and counted
(``fix_unknown_responder``), with no responder, Status or console row made for them.

:class:`FixDesk` is a collaborator of :class:`service.core.incident_core.IncidentCore`.
"""
from __future__ import annotations

import dataclasses

import logging
import math

from service.core.core_types import CoreClock, CoreSettings
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
                 outbox: Outbox, frames: FrameRounds, held: dict | None = None):
        self.incident, self.settings, self.clock = incident, settings, clock
        self.rejects, self.outbox, self.frames = rejects, outbox, frames
        self.held: dict[str, list] = {} if held is None else held  # rid -> [(received, Fix)] before its first frame

    def device_fix(self, r: Responder, fix: wire.Fix, now: float) -> None:
        """A fix a device sent for ``r``; an implausible checkpoint is taken, flagged and audited."""
        outcome, reason, detail, verdict = self.take(r, fix)
        if verdict is not None and verdict.implausible:  # a device's checkpoint fix: taken, flagged, audited
            self.outbox.audit(wire.Audit(actor=r.id, action="device_fix", outcome=outcome, responder=r.id, reason=reason,
                                   detail=detail, flags=["implausible_jump"], jump_m=verdict.jump_m,
                                   walkable_m=verdict.walkable_m, t=fix.t, received=now))

    def take(self, r: Responder, fix: wire.Fix, authoritative: bool = False):
        """A decoded fix for ``r`` to its tracker: ``(outcome, reason, detail, verdict)``,
        outcome ``accepted`` or ``refused`` (reason and detail say why), ``verdict`` the
        plausibility of a checkpoint fix (None for other sources). An ``authoritative`` checkpoint
        (an operator who sees the responder) is flagged when implausible but not held out by the
        estimator's walk gate: it is how a commander corrects a track that has drifted far."""
        self.frames.run_backlog(r)  # the frames that came before the fix go first (its time is judged against them)
        try:
            fix = self._on_device_clock(r, fix)
            domain = fix_type_of(fix.source).to_domain(fix, self.incident)
            if hasattr(domain, "at_height"):  # a 3D measurement: the tag is on the responder's floor
                domain = domain.at_height(self._tag_height(r))
        except FixRejected as e:
            self.rejects.fix(r, e.reason, str(e), self.clock.now)
            return "refused", e.reason, str(e), None
        except ValueError as e:  # a domain fix that checks itself (service.fusion.fixes)
            self.rejects.fix(r, "unknown_reference", str(e), self.clock.now)
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
        pose = r.tracker.on_fix(domain)
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

    def hold(self, rid: str, fix: wire.Fix, now: float) -> None:
        """A fix for an id with no responder: held (bounded) for :data:`HELD_FIX_S`, so a
        wearable's door fix sent just before its first frame still places it; anything else
        (a fix for an id that never sends a frame) is dropped, counted ``fix_unknown_responder``."""
        held = self.held
        held.setdefault(rid, []).append((now, fix))
        while sum(len(v) for v in held.values()) > self.MAX_HELD_FIXES:
            old = next(iter(held))
            held[old].pop(0)
            if not held[old]:
                del held[old]
            self.rejects.unknown("fix_unknown_responder", old, "held fixes over their bound", now)

    def take_held(self, r: Responder, now: float) -> None:
        """The fixes held for a responder just made, in the order they came (as if it had been there)."""
        for received, fix in self.held.pop(r.id, []):
            if now - received <= self.HELD_FIX_S:
                self.take(r, fix)
            else:
                self.rejects.unknown("fix_unknown_responder", r.id, "a fix that came too long before its first frame", now)

    def expire_held(self, now: float) -> None:
        for rid in [rid for rid, v in self.held.items() if now - v[-1][0] > self.HELD_FIX_S]:
            for _ in self.held.pop(rid):
                self.rejects.unknown("fix_unknown_responder", rid, f"no frame of {rid!r} came within "
                                                              f"{self.HELD_FIX_S:g} s of its fix", now)
