"""A responder's Status: its alarms judged at a time, and when a Status is answered (every tick
while it is heard, seldom once it is silent, at once when its alarms change or an order, an
acknowledgement or the wearer's answer to the man-down prompt came since the last).

A collaborator of :class:`service.core.incident_core.IncidentCore`.
"""
from __future__ import annotations

import math

from service.core import alarms
from service.core.core_types import CoreSettings, Outbound
from service.core.intake import Intake
from service.core.lag import ServiceLag
from service.core.pose_output import Outbox
from service.core.responder import STATUS_OWED, Responder
from service.protocol import wire


class StatusReporter:
    """Builds and answers Statuses; ``recording_failed`` (set by the shell) puts its alarm in every one;
    ``lags`` (the core's) gives each Status its responder's lag."""

    def __init__(self, incident_id: str, settings: CoreSettings, intake: Intake, outbox: Outbox, lags: ServiceLag):
        self.incident_id, self.settings, self.intake, self.outbox = incident_id, settings, intake, outbox
        self.lags = lags
        self.recording_failed = False
        self.last_tick = -math.inf  # service time of the last tick (spreads idle Statuses)

    def alarms_now(self, r: Responder, now: float) -> list[str]:
        """The responder's alarms at ``now``; each one's start is kept in ``r.alarm_since``."""
        current = alarms.of_responder(r, now, self.settings, self.recording_failed,
                                      flooding=self.intake.flooding(r.id, now))
        for kind in [k for k in r.alarm_since if k not in current]:
            del r.alarm_since[kind]
        for kind in current:
            r.alarm_since.setdefault(kind, now)
        return current

    def send(self, r: Responder, now: float, current: list[str] | None = None) -> None:
        """``r``'s Status at ``now`` answered (``current``: its alarms, when already judged)."""
        st = self.status_of(r, now, current)  # built only when sent: a crowd of silent ids is cheap
        self.outbox.put(Outbound(wire.key(self.incident_id, r.id, "status"), st))
        r.last_status, r.last_alarms = now, st.alarms

    def due(self, responders, now: float, on_error) -> None:
        """A tick: the Statuses due at ``now`` answered. The idle ones are spread over ticks
        (:meth:`idle_budget`): a crowd admitted together does not stay in step and answer all at
        once every few seconds. ``on_error(what)`` is told of a responder whose Status failed."""
        s = self.settings
        idle_due: list[tuple[float, Responder, list[str]]] = []
        idle = 0
        for r in responders:
            try:
                current = self.alarms_now(r, now)
                # heard lately, its alarms changed, or owed (STATUS_OWED: an order, an
                # acknowledgement or an "I'm OK" since its last Status): answered now, not budgeted
                if now - r.last_input < s.idle_after_s or current != r.last_alarms or r.last_status == STATUS_OWED:
                    self.send(r, now, current)
                    continue
                idle += 1
                if now - r.last_status >= s.idle_status_every_s:
                    idle_due.append((r.last_status, r, current))
            except Exception:
                on_error(f"status of {r.id}")
        idle_due.sort(key=lambda e: e[0])  # the longest unanswered first
        for _, r, current in idle_due[: self.idle_budget(idle, now)]:
            try:
                self.send(r, now, current)
            except Exception:
                on_error(f"status of {r.id}")
        self.last_tick = now

    def idle_budget(self, idle: int, now: float) -> int:
        """Idle Statuses one tick may send: the share of ``idle`` responders that falls in the
        time since the last tick (``idle × Δt / idle_status_every_s``, rounded up, at least
        one), so that each still gets one about every ``idle_status_every_s``."""
        dt = min(max(now - self.last_tick, 0.0), self.settings.idle_status_every_s)
        return max(1, math.ceil(idle * dt / self.settings.idle_status_every_s))

    def status_of(self, r: Responder, now: float, current: list[str] | None = None) -> wire.Status:
        """The responder's Status at ``now`` (``current``: its alarms, when already judged at ``now``)."""
        heard = r.gate.last_heard if r.gate.last_heard is not None else r.first_heard
        motion, since = r.tracker.motion
        rejected = dict(r.gate.counts)
        tr = r.tracker
        if current is None:
            current = self.alarms_now(r, now)
        for reasons in (r.fixes_rejected, tr.fix_rejects, {"unused": tr.fixes_unused}):
            for reason, n in reasons.items():
                if n:
                    rejected[f"fix_{reason}"] = rejected.get(f"fix_{reason}", 0) + n
        for reason, n in self.intake.dropped_of(r.id).items():
            rejected[reason] = rejected.get(reason, 0) + n
        g = r.gate
        alarm_at = alarms.man_down(r)[1]
        return wire.Status(
            responder=r.id, t=tr.device_time - r.t_offset, motion=motion.value, motion_since=since - r.t_offset,
            alarms=current, alarms_since={k: r.alarm_since[k] for k in current}, rejected=rejected,
            frames=g.accepted, gaps=g.gaps, last_heard=heard, steps=tr.steps,
            fixes={"applied": tr.fixes_applied, "queued": tr.fixes_queued,
                   **({"flagged": r.fixes_flagged} if r.fixes_flagged else {}),
                   **({"degraded": tr.degraded} if tr.degraded else {})}, utc_offset=r.utc_offset,
            beacons_heard={b: t - r.t_offset for b, t in r.beacons_heard.items()},
            last_fix=tr.last_fix, first_heard=r.first_heard, commands={a: dict(o) for a, o in r.commands.items()},
            lost=g.lost, gap_s=g.gap_s, streams=g.streams, device=g.device, boot=g.boot, seq=g.last_seq,
            missing=None if g.missing is None else list(g.missing),
            man_down_at=None if alarm_at is None else alarm_at - r.t_offset,
            ok_at=r.ok_at - r.t_offset if math.isfinite(r.ok_at) else None,
            lag_s=round(self.lags.of(r.lag, r.last_input, now), 3),
        )
