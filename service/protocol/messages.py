"""The one function that turns a recording into the messages a wearable would send.

The wearable replay (``firetrack wearable --replay``), the exercise builder, ``eval ipin`` and
the tests all take a recording's messages from :func:`recording_messages`, so the accuracy
figures are measured on exactly what a wearable puts on the wire.

What a phone or IMU on a responder sends, taken from a recording (IPIN, Oxford, PyShoe or
anything :func:`pdr.io.load` reads): the IMU samples as :class:`service.protocol.wire.ImuBatch`
frames of about 1/10 s, and — where the recording has them — its landmarks as checkpoint
fixes (a tag reader at a door), its GNSS fixes and its BLE beacon readings as ``ble`` scans
(:func:`ble_scans`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr.evaluation.ipin import fix_indices
from pdr.recording import Recording
from service.protocol import wire

FRAMES_PER_SECOND = 10.0
LANDMARK_SIGMA_M = 0.3  # a surveyed landmark, the walker standing on it
BLE_SCAN_S = 2.0  # s, one ble fix per this much of a recording's beacon readings (a phone's scan window)


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
                       carry: str | None = None, ble_scan_s: float = 0.0) -> list[Outgoing]:
    """Every message a wearable would send for ``rec``, in device-time order.

    Landmarks (with an ``incident`` to put them in its ENU frame): the first always — the
    responder is placed where the walk starts — and every ``landmark_every``-th after it
    when that is positive. GNSS fixes with a finite, positive accuracy go as they are.
    ``carry`` (where the device is worn) defaults to the recording's own (``meta["carry"]``:
    ``foot`` for a boot-mounted PyShoe walk), else ``unknown``. ``ble_scan_s`` > 0 sends the
    recording's beacon readings as one ``ble`` fix per scan of that length (:func:`ble_scans`).
    """
    if carry is None:
        carry = rec.meta.get("carry") if rec.meta.get("carry") in wire.CARRY_POSITIONS else "unknown"
    imu = rec.imu_samples()
    device = device or f"replay:{responder}"
    per = frames_per_batch(rec.acc.rate_hz, frames_per_s)
    pt = rec.pressure.t if rec.pressure is not None else None
    pv = rec.pressure.values[:, 0] if rec.pressure is not None else None
    out = [Outgoing(float(b.t[-1]), "imu", b) for b in
           wire.imu_batches_from_arrays(responder, device, imu.t, imu.acc, imu.gyr, imu.mag, pt, pv, carry, per)]
    lm = rec.landmarks
    if lm is not None and len(lm) and incident is not None:
        idx = fix_indices(len(lm), landmark_every)
        x, y, _ = incident.to_enu(lm.lat[idx], lm.lon[idx])
        for j, xx, yy in zip(idx, np.atleast_1d(x), np.atleast_1d(y)):
            out.append(Outgoing(float(lm.t[j]), "fix", wire.Fix.checkpoint(
                responder, float(lm.t[j]), x=float(xx), y=float(yy), floor=int(lm.floor[j]), sigma=LANDMARK_SIGMA_M,
                operator="recording landmark")))
    if gnss and rec.gnss is not None:
        g = rec.gnss
        for k in range(len(g)):
            if np.isfinite(g.accuracy_m[k]) and g.accuracy_m[k] > 0:
                out.append(Outgoing(float(g.t[k]), "fix", wire.Fix.gnss(
                    responder, float(g.t[k]), lat=float(g.lat[k]), lon=float(g.lon[k]), accuracy=float(g.accuracy_m[k]))))
    if ble_scan_s > 0 and rec.ble is not None and len(rec.ble):
        out += [Outgoing(m.t, "fix", m) for m in ble_scans(rec.ble, responder, ble_scan_s)]
    out.sort(key=lambda o: (o.t, o.kind != "imu"))
    return out


def ble_scans(readings, responder: str, scan_s: float = BLE_SCAN_S) -> list[wire.Fix]:
    """Beacon readings (:class:`pdr.recording.BeaconReadings`) as ``ble`` fixes, one per window of
    ``scan_s`` s from the first reading: each beacon heard in the window with its mean RSSI
    (dBm), timed at the window's last reading, ``period`` the time from the window's start."""
    t = np.asarray(readings.t, float)
    window = np.floor((t - t[0]) / scan_s).astype(np.int64)
    out = []
    for w in np.unique(window):
        sel = np.flatnonzero(window == w)
        ids = readings.beacon[sel]
        names = sorted(set(ids.tolist()))[:64]
        rssi = [float(np.mean(readings.rssi[sel][ids == b])) for b in names]
        t_end = float(t[sel[-1]])
        out.append(wire.Fix(responder=responder, t=t_end, source="ble", beacons=names, rssi=rssi,
                            period=min(max(t_end - (t[0] + w * scan_s), 0.0), 60.0), operator="wearable ble scan"))
    return out

