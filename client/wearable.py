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

MATCHING_WAIT_S = 1.5  # s a replay waits for a service to match its frames before it warns


class Wearable:
    """A zenoh client publishing one responder's messages; ``close()`` withdraws its presence.

    It knows whether anybody listens: zenoh's matching status of the frame publisher says
    whether a subscriber (the service) matches ``firetrack/{incident}/{responder}/imu``.
    ``on_matching(bool)`` is called when that changes, and frames published while nobody
    listened are counted in ``unheard`` (they went nowhere).
    """

    def __init__(self, session: zenoh.Session, incident_id: str, responder: str, on_matching=None,
                 on_command=None, auto_ack: bool = True):
        self.session = session
        self.responder = responder
        qos = dict(congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE)
        self._pub = {k: session.declare_publisher(wire.key(incident_id, responder, k), **qos) for k in ("imu", "fix", "truth")}
        self._token = session.liveliness().declare_token(wire.key(incident_id, responder, "presence"))
        self.sent = {"imu": 0, "fix": 0, "truth": 0}
        self.unheard = {"imu": 0, "fix": 0}
        self._on_matching = on_matching
        self._listener = self._pub["imu"].declare_matching_listener(self._matching_changed) if on_matching else None
        self._ack = session.declare_publisher(wire.key(incident_id, responder, "ack"), **qos)
        self._on_command, self._auto_ack = on_command, auto_ack
        self.commands: list[wire.Command] = []  # orders received (roll calls, evacuation)
        self._orders = session.declare_subscriber(wire.key(incident_id, responder, "command"), self._command)

    def _command(self, sample) -> None:
        """A roll call or an evacuation order: this wearable acknowledges it (a replay or a
        simulator on its own; a real device when its wearer presses the button)."""
        try:
            cmd = wire.decode(sample.payload.to_bytes(), expect=wire.Command)
        except wire.WireError:
            return
        self.commands.append(cmd)
        if self._on_command is not None:
            self._on_command(cmd)
        if self._auto_ack:
            self.acknowledge(cmd)

    def acknowledge(self, cmd: wire.Command) -> None:
        self._ack.put(wire.encode(wire.Ack(responder=self.responder, id=cmd.id, action=cmd.action, at=time.time())))

    @property
    def heard(self) -> bool:
        """True while a subscriber (the service) matches this wearable's frames."""
        return bool(self._pub["imu"].matching_status.matching)

    def _matching_changed(self, status) -> None:
        if self._on_matching is not None:
            self._on_matching(bool(status.matching))

    def send(self, kind: str, msg_or_payload) -> None:
        """Publish one message; a frame without a clock offset gets this machine's: UTC now
        minus the device time of its last sample (how a phone relates its sensor clock to UTC)."""
        msg = msg_or_payload
        if isinstance(msg, wire.ImuBatch) and msg.utc_offset is None:
            msg = msg.model_copy(update={"utc_offset": time.time() - float(msg.t[-1])})
        payload = msg if isinstance(msg, bytes) else wire.encode(msg)
        if kind in self.unheard and not self._pub[kind].matching_status.matching:
            self.unheard[kind] += 1
        self._pub[kind].put(payload)
        self.sent[kind] += 1

    def close(self) -> None:
        self._orders.undeclare()
        self._ack.undeclare()
        if self._listener is not None:
            self._listener.undeclare()
        self._token.undeclare()
        for p in self._pub.values():
            p.undeclare()


def replay(path, responder: str, session: zenoh.Session, incident, speed: float = 1.0, landmark_every: int = 0,
           gnss: bool = True, stop: threading.Event | None = None, on_progress: Callable[[int, int], None] | None = None,
           on_matching: Callable[[bool], None] | None = None, on_start: Callable[[list], None] | None = None) -> dict:
    """Publish recording ``path`` as responder ``responder``; returns the counts sent and, in
    ``unheard``, how many went out while no service was subscribed."""
    rec = load(path)
    msgs = recording_messages(rec, responder, incident=incident, landmark_every=landmark_every, gnss=gnss)
    w = Wearable(session, incident.id, responder, on_matching=on_matching)
    if on_start is not None:
        on_start(msgs)
    if on_matching is not None:  # the listener speaks on changes: say now if nobody listens yet
        deadline = time.monotonic() + MATCHING_WAIT_S
        while not w.heard and time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            time.sleep(0.05)
        if not w.heard:
            on_matching(False)
    try:
        for i, m in enumerate(paced(msgs, speed, stop)):
            w.send(m.kind, m.msg)
            if on_progress is not None and (i % 50 == 0 or i == len(msgs) - 1):
                on_progress(i + 1, len(msgs))
    finally:
        w.close()
    return {**w.sent, "unheard": dict(w.unheard)}
