"""A wearable that publishes a real recording: ``firetrack wearable --responder ID --replay FILE``.

What a phone or IMU on a responder would send, taken from a recording (IPIN, Oxford, PyShoe
or anything :func:`pdr.io.load` reads): the IMU samples as :class:`service.protocol.wire.ImuBatch`
frames of about 1/10 s, at the recording's own pace (or ``speed`` times faster), and —
where the recording has them — its landmarks as checkpoint fixes (a tag reader at a door)
and its GNSS fixes. A liveliness token on ``.../presence`` says the wearable is connected.

Frames travel reliably with blocking congestion control: a slow network delays them, it
does not drop them. Frame ``k`` leaves at ``start + (t_end,k − t_0) / speed`` of the wall
clock, so a replay at ``speed=10`` lasts a tenth of the recording.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import zenoh

from pdr.io import load
from pdr.recording import Recording
from service.protocol import wire

FRAMES_PER_SECOND = 10.0


@dataclass(frozen=True)
class Outgoing:
    """One message to send at device time ``t`` on ``kind`` (imu or fix)."""

    t: float
    kind: str
    msg: wire.WireMessage


def frames_per_batch(rate_hz: float, frames_per_s: float = FRAMES_PER_SECOND) -> int:
    return max(1, int(round(rate_hz / frames_per_s)))


def recording_messages(rec: Recording, responder: str, device: str | None = None, incident=None,
                       landmark_every: int = 0, gnss: bool = True, frames_per_s: float = FRAMES_PER_SECOND,
                       carry: str = "unknown") -> list[Outgoing]:
    """Every message a wearable would send for ``rec``, in device-time order.

    Landmarks (with an ``incident`` to put them in its ENU frame): the first always — the
    responder is placed where the walk starts — and every ``landmark_every``-th after it
    when that is positive. GNSS fixes go as they are.
    """
    imu = rec.imu_samples()
    device = device or f"replay:{responder}"
    per = frames_per_batch(rec.acc.rate_hz, frames_per_s)
    pt = rec.pressure.t if rec.pressure is not None else None
    pv = rec.pressure.values[:, 0] if rec.pressure is not None else None
    out = [Outgoing(float(b.t[-1]), "imu", b) for b in
           wire.imu_batches_from_arrays(responder, device, imu.t, imu.acc, imu.gyr, imu.mag, pt, pv, carry, per)]
    lm = rec.landmarks
    if lm is not None and len(lm) and incident is not None:
        idx = np.arange(0, len(lm), landmark_every) if landmark_every > 0 else np.array([0])
        x, y, _ = incident.to_enu(lm.lat[idx], lm.lon[idx])
        for j, xx, yy in zip(idx, np.atleast_1d(x), np.atleast_1d(y)):
            out.append(Outgoing(float(lm.t[j]), "fix", wire.Fix.checkpoint(
                responder, float(lm.t[j]), x=float(xx), y=float(yy), floor=int(lm.floor[j]), sigma=0.3,
                operator="recording landmark")))
    if gnss and rec.gnss is not None:
        g = rec.gnss
        for k in range(len(g)):
            if np.isfinite(g.accuracy_m[k]) and g.accuracy_m[k] > 0:
                out.append(Outgoing(float(g.t[k]), "fix", wire.Fix.gnss(
                    responder, float(g.t[k]), lat=float(g.lat[k]), lon=float(g.lon[k]), accuracy=float(g.accuracy_m[k]))))
    out.sort(key=lambda o: (o.t, o.kind != "imu"))
    return out


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
        payload = msg_or_payload if isinstance(msg_or_payload, bytes) else wire.encode(msg_or_payload)
        self._pub[kind].put(payload)
        self.sent[kind] += 1

    def close(self) -> None:
        self._token.undeclare()
        for p in self._pub.values():
            p.undeclare()


def paced(messages: list[Outgoing], speed: float, stop: threading.Event | None = None,
          clock: Callable[[], float] = time.monotonic) -> Iterator[Outgoing]:
    """Yield the messages at their device-time pace divided by ``speed`` (0 or inf: at once)."""
    if not messages:
        return
    t0 = messages[0].t
    start = clock()
    fast = speed <= 0 or not np.isfinite(speed)
    for m in messages:
        if stop is not None and stop.is_set():
            return
        if not fast:
            wait = start + (m.t - t0) / speed - clock()
            if wait > 0:
                if stop is not None:
                    if stop.wait(wait):
                        return
                else:
                    time.sleep(wait)
        yield m


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
