"""The alarms a responder's Status carries, decided from the core's state and the time given.

==================  ==========================================================================
``man_down``        the motion model reports no motion (30 s motionless: the PASS rule), and the
                    wearer has not answered "I'm OK" within that time
``lost_contact``    no frame of the wearable for ``lost_contact_s`` (the shell's time)
``rejected_frames`` ``rejected_burst`` rejects within ``rejected_window_s``
``disconnected``    the wearable's liveliness token is gone
``recording_failed`` the incident is no longer being recorded (disk full, ...)
``flooding``        the responder's key sent more than its budget (:mod:`service.core.intake`)
``stream_contested`` frames of another stream (boot) turned away, or waiting while the real one
                    spoke, within ``rejected_window_s`` (:class:`service.core.gate.FrameGate`)
``par_unanswered``  a roll call (PAR) unanswered after ``command_answer_s``
``evacuation_unacknowledged`` an evacuation order unacknowledged after ``command_answer_s``
``track_degraded``  the estimator could not take an input and restarted the track from dead
                    reckoning (:class:`service.fusion.estimators.FusionEstimator`), within the last
                    ``TRACK_DEGRADED_S`` of the responder's walk
``fixes_refused``   a fix for the responder was refused within ``rejected_window_s``: by the
                    sender's role, undecodable, or held out by the estimator as further than
                    the walk allows (:mod:`service.core.fix_audit`; the audits name who sent it;
                    the wearable's own GNSS and BLE, gated routinely indoors, raise none)
==================  ==========================================================================

The pre-alarm is not an alarm of the console's: Status carries it as ``man_down_at`` (the
device time man-down will be raised at), present from :data:`PROMPT_BEFORE_S` before, and a
wearable with a screen (the phone page) asks its wearer "Are you OK?" with a countdown to it.
A PASS device (NFPA 1982) sounds a pre-alert before its alarm, and the
wearer silences it by moving or by pressing its button, which starts the no-motion clock
again. Here the button is the phone page's "I'M OK": an :class:`service.protocol.schema.Ack`
with ``action="ok"`` and ``t`` on the device clock (``Responder.ok_at``), recorded with every
other input, so ``reprocess`` reaches the same verdict. The stillness is counted from

    start = max(motionless since, the latest answer, the end of the latest gap)

and man-down is raised once the newest sample reaches ``alarm_at = start + no_motion_after_s + state_delay_s`` (the motion
model decides its state ``state_delay_s`` behind the newest sample: without an answer this is
when it reports no motion); the prompt is on from ``alarm_at - PROMPT_BEFORE_S``. Both are
judged in device time, so a replay of the same frames and answers raises them at the same samples.

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
FIXES_REFUSED = "fixes_refused"
TRACK_DEGRADED_S = 30.0  # s of device time a restarted track stays flagged: long enough to be seen
MAN_DOWN_PROMPT = "prompt"
PROMPT_BEFORE_S = 10.0  # s: the wearer is asked this long before man-down is raised (the pre-alert)
NO_MOTION_AFTER_S = 30.0  # s of stillness that make no motion, when the motion model does not say (the PASS rule)
UNANSWERED = {"par": "par_unanswered", "evacuate": "evacuation_unacknowledged"}


def of_responder(r, now: float, settings, recording_failed: bool = False, flooding: bool = False) -> list[str]:
    """The alarms of responder ``r`` (:class:`service.core.responder.Responder`) at service time ``now``."""
    out = []
    if man_down(r)[0] == MAN_DOWN:
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
    if r.tracker.device_time - r.tracker.degraded_at <= TRACK_DEGRADED_S:
        out.append(TRACK_DEGRADED)
    if now - r.last_fix_refused <= settings.rejected_window_s:
        out.append(FIXES_REFUSED)
    for action, order in r.commands.items():
        if order["acked_at"] is None and now - order["issued_at"] > settings.command_answer_s:
            out.append(UNANSWERED[action])
    return out


def man_down(r) -> tuple[str | None, float | None]:
    """(:data:`MAN_DOWN`, :data:`MAN_DOWN_PROMPT` (the pre-alarm) or None; ``alarm_at``, the track time at
    which man-down is or will be raised, or None) for responder ``r`` as of its newest
    sample (module docstring)."""
    tr = r.tracker
    motion, since = tr.motion
    pipeline = getattr(tr.settings, "pipeline", None)
    need = getattr(pipeline, "no_motion_after_s", NO_MOTION_AFTER_S) + getattr(pipeline, "state_delay_s", 0.0)
    answered = getattr(r, "ok_at", -math.inf)
    still = getattr(tr, "motionless_since", math.nan)
    if not math.isfinite(still):  # a motion model that does not say when it last moved: no prompt, its no-motion state
        if (motion is MotionState.NO_MOTION and _still_observed(r, since)
                and (answered < since or tr.device_time >= answered + need)):
            return MAN_DOWN, max(since, answered + need)
        return None, None
    alarm_at = max(still, answered, getattr(r, "gap_end", -math.inf)) + need
    if (motion is MotionState.NO_MOTION and _still_observed(r, since)
            and (answered < since or tr.device_time >= alarm_at)):
        return MAN_DOWN, alarm_at
    if not motion.moving and tr.device_time >= alarm_at - PROMPT_BEFORE_S:
        return MAN_DOWN_PROMPT, alarm_at
    return None, None


def _still_observed(r, since: float) -> bool:
    """Was the stillness seen in frames for the no-motion time? Stillness that began before the
    latest gap counts from the gap's end only."""
    gap_end = getattr(r, "gap_end", -math.inf)
    if since >= gap_end:
        return True
    pipeline = getattr(r.tracker.settings, "pipeline", None)
    need = getattr(pipeline, "no_motion_after_s", NO_MOTION_AFTER_S)
    return r.tracker.device_time - gap_end >= need
