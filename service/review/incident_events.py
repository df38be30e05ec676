"""What happened at an incident besides the tracks: alarms and operator actions, as log events.

Used by the exports (:mod:`service.review.foxglove_export` turns them into ``foxglove.Log``).
"""
from __future__ import annotations

from service.protocol import wire


def review_events(published: list[tuple[float, object]]) -> list[dict]:
    """Alarms and operator actions of a reprocessed incident as log events.

    ``published``: (receive time of the input that made it, message) for every Status and
    Audit the core answered. An alarm is logged when a responder's Status first carries it
    (warning) and when it no longer does (info), at the time of that Status's input; an
    Audit at the time the service took the action.
    """
    events, alarms = [], {}
    for when, m in published:
        if isinstance(m, wire.Status):
            now, before = set(m.alarms), alarms.get(m.responder, set())
            for a in sorted(now - before):
                events.append({"unix": when, "topic": "alarms", "level": "warning", "name": m.responder,
                               "message": f"{m.responder}: {a}"})
            for a in sorted(before - now):
                events.append({"unix": when, "topic": "alarms", "level": "info", "name": m.responder,
                               "message": f"{m.responder}: {a} ended"})
            alarms[m.responder] = now
        elif isinstance(m, wire.Audit):
            who = m.operator or m.actor
            text = f"{who}: {m.action}" + (f" for {m.responder}" if m.responder else "") + f" {m.outcome}"
            if m.reason:
                text += f" ({m.reason})"
            if m.detail:
                text += f": {m.detail}"
            if m.flags:
                text += f" [{', '.join(m.flags)}]"
            events.append({"unix": m.received, "topic": "operator",
                           "level": "warning" if m.outcome == "refused" or m.flags else "info", "name": m.actor,
                           "message": text})
    return events
