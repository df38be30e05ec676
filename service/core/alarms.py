"""The alarms a responder's Status carries, decided from the core's state and the time given.

==================  ==========================================================================
``man_down``        the motion model reports no motion (30 s motionless: the PASS rule)
``lost_contact``    no frame of the wearable for ``lost_contact_s`` (the shell's time)
``rejected_frames`` ``rejected_burst`` rejects within ``rejected_window_s``
``disconnected``    the wearable's liveliness token is gone
``recording_failed`` the incident is no longer being recorded (disk full, ...)
``flooding``        the responder's key sent more than its budget (:mod:`service.core.intake`)
``stream_contested`` frames of another stream (boot) turned away within ``rejected_window_s``
                    while the real one spoke (:class:`service.core.gate.FrameGate`)
``par_unanswered``  a roll call (PAR) unanswered after ``command_answer_s``
``evacuation_unacknowledged`` an evacuation order unacknowledged after ``command_answer_s``
``track_degraded``  the estimator could not take an input and restarted the track from dead
                    reckoning (:class:`service.fusion.estimators.FusionEstimator`), within the last
                    ``TRACK_DEGRADED_S`` of the responder's walk
==================  ==========================================================================

Man-down is judged on frames: a no-motion state whose stillness began before a gap in the
frames (an outage, lost frames, a new stream) needs the motion model's own time of stillness
after the gap before it is an alarm; the outage itself is ``lost_contact``, not ``man_down``.
"""
from __future__ import annotations

import math

from pdr.events import MotionState

MAN_DOWN = "man_down"
LOST_CONTACT = "lost_contact"
REJECTED = "rejected_frames"
DISCONNECTED = "disconnected"
RECORDING = "recording_failed"
FLOODING = "flooding"
CONTESTED = "stream_contested"
TRACK_DEGRADED = "track_degraded"
TRACK_DEGRADED_S = 30.0  # s of device time a restarted track stays flagged: long enough to be seen
NO_MOTION_AFTER_S = 30.0  # s of stillness that make no motion, when the motion model does not say (the PASS rule)
UNANSWERED = {"par": "par_unanswered", "evacuate": "evacuation_unacknowledged"}


def of_responder(r, now: float, settings, recording_failed: bool = False, flooding: bool = False) -> list[str]:
    """The alarms of responder ``r`` (:class:`service.core.responder.Responder`) at service time ``now``."""
    out = []
    motion, since = r.tracker.motion
    if motion is MotionState.NO_MOTION and _still_observed(r, since):
        out.append(MAN_DOWN)
    heard = r.gate.last_heard if r.gate.last_heard is not None else r.first_heard
    if now - heard > settings.lost_contact_s:
        out.append(LOST_CONTACT)
    if sum(1 for t in r.rejects if now - t <= settings.rejected_window_s) >= settings.rejected_burst:
        out.append(REJECTED)
    if r.present is False:
        out.append(DISCONNECTED)
    if recording_failed:
        out.append(RECORDING)
    if flooding:
        out.append(FLOODING)
    if now - r.gate.last_contested <= settings.rejected_window_s:
        out.append(CONTESTED)
    if r.tracker.device_time - getattr(r.tracker, "degraded_at", math.nan) <= TRACK_DEGRADED_S:
        out.append(TRACK_DEGRADED)
    for action, order in r.commands.items():
        if order["acked_at"] is None and now - order["issued_at"] > settings.command_answer_s:
            out.append(UNANSWERED[action])
    return out


def _still_observed(r, since: float) -> bool:
    """Was the stillness seen in frames for the no-motion time? Stillness that began before the
    latest gap counts from the gap's end only."""
    gap_end = getattr(r, "gap_end", -math.inf)
    if since >= gap_end:
        return True
    pipeline = getattr(r.tracker.settings, "pipeline", None)
    need = getattr(pipeline, "no_motion_after_s", NO_MOTION_AFTER_S)
    return r.tracker.device_time - gap_end >= need
