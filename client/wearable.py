"""A wearable that publishes a real recording: ``firetrack wearable --responder ID --replay FILE``.

What a phone or IMU on a responder would send (:func:`service.protocol.messages.recording_messages`),
at the recording's own pace (or ``speed`` times faster). A liveliness token on
``.../presence`` says the wearable is connected.

Frames travel reliably with blocking congestion control: a slow network delays them, it
does not drop them. Frame ``k`` leaves at ``start + (t_end,k − t_0) / speed`` of the wall
clock, so a replay at ``speed=10`` lasts a tenth of the recording.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import zenoh

from pdr.io import load
from service.protocol import wire
from service.protocol.messages import recording_messages
from service.protocol.pacing import paced


class Wearable:
    """A zenoh client publishing one responder's messages; ``close()`` withdraws its presence."""

    def __init__(self, session: zenoh.Session, incident_id: str, responder: str):
        self.session = session
        self.responder = responder
        qos = dict(congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE)
        self._pub = {k: session.declare_publisher(wire.key(incident_id, responder, k), **qos) for k in ("imu", "fix", "truth")}
        self._token = session.liveliness().declare_token(wire.key(incident_id, responder, "presence"))
        self.sent = {"imu": 0, "fix": 0, "truth": 0}

    def send(self, kind: str, msg_or_payload) -> None:
        """Publish one message; a frame without a clock offset gets this machine's: UTC now
        minus the device time of its last sample (how a phone relates its sensor clock to UTC)."""
        msg = msg_or_payload
        if isinstance(msg, wire.ImuBatch) and msg.utc_offset is None:
            msg = msg.model_copy(update={"utc_offset": time.time() - float(msg.t[-1])})
        payload = msg if isinstance(msg, bytes) else wire.encode(msg)
        self._pub[kind].put(payload)
        self.sent[kind] += 1

    def close(self) -> None:
        self._token.undeclare()
        for p in self._pub.values():
            p.undeclare()


def replay(path, responder: str, session: zenoh.Session, incident, speed: float = 1.0, landmark_every: int = 0,
           gnss: bool = True, stop: threading.Event | None = None, on_progress: Callable[[int, int], None] | None = None) -> dict:
    """Publish recording ``path`` as responder ``responder``; returns the counts sent."""
    rec = load(path)
    msgs = recording_messages(rec, responder, incident=incident, landmark_every=landmark_every, gnss=gnss)
    w = Wearable(session, incident.id, responder)
    try:
        for i, m in enumerate(paced(msgs, speed, stop)):
            w.send(m.kind, m.msg)
            if on_progress is not None and (i % 50 == 0 or i == len(msgs) - 1):
                on_progress(i + 1, len(msgs))
    finally:
        w.close()
    return dict(w.sent)
