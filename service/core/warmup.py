"""Warm the service up before it takes real frames.

The first use of each compiled kernel (numba's cache is read per process), of gtsam's factor
types and of the geodetic conversion costs tens of milliseconds, once. Without a warm-up the
first responders pay it: at an incident where a crew enters together, every tracker reaches
its first step, first compass epoch and first fix within the same seconds, the worker stalls
for some hundreds of milliseconds and every frame queued behind it waits. So before the
service subscribes, a simulated walker goes through the very path live frames take —
decode, gate, pipeline, fusion, every kind of fix the incident can use, pose and status
encoding, the track reply, a snapshot — on a throwaway incident core whose output is dropped.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

WARMUP_SECONDS = 14.0  # of walking: past the rate estimate, first steps, compass epochs and a fix of each kind


@dataclass(frozen=True)
class WarmUp:
    seconds: float  # wall time it took
    poses: int  # poses the simulated responder got
    fixes_applied: int
    errors: int  # exceptions the offline service caught (0, or the live one would hit them too)


def warm_up(incident, settings=None, seconds: float = WARMUP_SECONDS, cancel=None) -> WarmUp:
    """Run a simulated responder through a throwaway incident core (``settings``: its
    :class:`service.core.incident_core.CoreSettings`). ``cancel`` (an event, e.g. the command's
    Ctrl-C): looked at before each frame, and the warm-up ends there when it is set (it takes
    seconds, and a fire officer's Ctrl-C must not wait for it)."""
    started = time.perf_counter()
    quiet = logging.getLogger("firetrack.service")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # the throwaway responder is nobody's business
    try:
        return _walk(incident, settings, seconds, started, cancel)
    finally:
        quiet.setLevel(level)


def _walk(incident, settings, seconds: float, started: float, cancel) -> WarmUp:
    from pdr.simulation import SimulatedWalker
    from service.core.incident_core import Inbound, IncidentCore
    from service.protocol import wire

    core = IncidentCore(incident, settings)
    rid = "warm-up"
    walker = SimulatedWalker(rid, attitude=False)
    key = {k: wire.key(incident.id, rid, k) for k in ("imu", "fix")}
    parts = {k: wire.read_key(v) for k, v in key.items()}  # each key read once, as the shell reads a message's
    frames = int(seconds * 10)
    for k in range(frames):
        if cancel is not None and cancel.is_set():
            r = core.responders.get(rid)
            return WarmUp(time.perf_counter() - started, r.poses if r else 0, r.tracker.fixes_applied if r else 0,
                          core.counters.errors)
        b = walker.next_batch(int(round(walker.settings.rate_hz / 10)))
        msg = wire.ImuBatch(responder=rid, device="warm-up", seq=k, t=b.t, acc=b.acc, gyr=b.gyr, mag=b.mag,
                            pressure_t=b.pressure_t, pressure=b.pressure)
        core.feed(Inbound("imu", key["imu"], wire.encode(msg), 0.0, parts["imu"]))
        t, x, y = float(b.t[-1]), float(b.x[-1]), float(b.y[-1])
        if k == 0:
            fix = wire.Fix.checkpoint(rid, float(b.t[0]), x=float(b.x[0]), y=float(b.y[0]), floor=incident.start_floor,
                                      sigma=0.3)
        elif k == frames // 2:
            lat, lon, _ = incident.to_geodetic(x, y)
            fix = wire.Fix.gnss(rid, t, lat=float(lat), lon=float(lon), accuracy=5.0)
        elif k == frames // 2 + 5 and incident.uwb_anchors:
            a = incident.uwb_anchors[0]
            fix = wire.Fix.uwb(rid, t, anchor=a.id, range=max(float(((a.x - x) ** 2 + (a.y - y) ** 2) ** 0.5), 0.1),
                               sigma=0.3)
        elif k == frames - 10:
            fix = wire.Fix.checkpoint(rid, t, x=x, y=y, floor=incident.start_floor, sigma=0.5)
        else:
            continue
        core.feed(Inbound("fix", key["fix"], wire.encode(fix), 0.0, parts["fix"]))
    for o in core.tick(1.0):
        wire.encode(o.message)
    t = core.track(rid)
    wire.encode_track(rid, t["track"], t["smoothed"])
    core.snapshot()  # the snapshot's compiled packing (pdr.fleet) is loaded before the first live one
    r = core.responders[rid]
    return WarmUp(time.perf_counter() - started, r.poses, r.tracker.fixes_applied, core.counters.errors)


__all__ = ["WarmUp", "warm_up"]
