"""One walk through the incident core, as a wearable would send it: the evaluation's driver.

``eval ipin`` (and anything else that scores a recording) measures the code that runs at an
incident: the recording becomes wire messages (:func:`service.protocol.messages.recording_messages`,
the same function the wearable replay uses), they are encoded, and the incident core decodes,
gates, batches and tracks them. The receive time of each message is its device time, so the
frame gate sees a wearable on a perfect network.
"""
from __future__ import annotations

from dataclasses import dataclass

from service.core.incident_core import CoreSettings, Inbound, IncidentCore
from service.core.tracker import ResponderTracker
from service.protocol import wire
from service.protocol.messages import Outgoing

ROUND = 50  # messages per core round: any size gives the same poses (tests/test_service.py)


@dataclass
class WalkRun:
    poses: list[wire.Pose]  # every pose the core answered, in order
    tracker: ResponderTracker  # the responder's tracker at the end (smoothed track, dead reckoning, fixes)
    errors: int  # exceptions the core caught (0 unless there is a bug)
    rejected: dict[str, int]  # what the core turned away, by reason


def run_walk(messages: list[Outgoing], incident, responder: str, settings: CoreSettings | None = None) -> WalkRun:
    """Feed ``messages`` (one responder's, in order) to a fresh incident core; collect its poses."""
    core = IncidentCore(incident, settings)
    poses: list[wire.Pose] = []
    inbound = [Inbound(m.kind, wire.key(incident.id, responder, m.kind), wire.encode(m.msg), m.t) for m in messages]
    for i in range(0, len(inbound), ROUND):
        poses += [o.message for o in core.feed_round(inbound[i:i + ROUND]) if isinstance(o.message, wire.Pose)]
    r = core.responders.get(responder)
    if r is None:
        raise ValueError(f"{responder}: the core never heard of this responder (no messages?)")
    poses += [core.pose_message(r, p) for p in r.tracker.finish() if hasattr(p, "x")]
    return WalkRun(poses, r.tracker, core.counters.errors, core.frame_accounting())
