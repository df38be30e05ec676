"""``python -m client.core_bench [N] [SECONDS] [ROUND]``: CPU per frame of one worker's incident
core, without zenoh (a measure that a shared machine's load disturbs less than wall time).

N simulated walkers (the bench's crew: seed 0, starts spread over 5 s) walk SECONDS; their
frames, encoded as on the wire, are fed to :class:`service.core.incident_core.IncidentCore`
in rounds of ROUND frames, with a tick per second of data, and every answer is encoded as the
shell would. After the first quarter (responders made, detectors designed) the process's CPU
time is counted. Prints JSON: ``cpu_us_per_frame`` (and wall), poses, steps and
``answers_sha256`` (every answer's key and bytes, in order: a change meant to be bit-equal keeps it). Compare two
commits by alternating runs of the same command (A, B, A, B).
"""
from __future__ import annotations

import hashlib
import json
import sys
import time

import numpy as np


def core_bench(n: int = 250, seconds: float = 12.0, round_frames: int = 50, profiler=None) -> dict:
    """Run the measure; ``profiler`` (a ``cProfile.Profile``, optional) is enabled for the timed part only."""
    from pdr.simulation import WalkerFleet, WalkerSettings
    from service.core.incident_core import Inbound, IncidentCore
    from service.core.warmup import warm_up
    from service.protocol import wire
    from service.protocol.incident import default_incident

    cfg = default_incident()
    names = [f"sim-{i:03d}" for i in range(n)]
    fleet = WalkerFleet(n, WalkerSettings(rate_hz=100.0), 0, responders=names, floors=(0, 0), start_t=1000.0,
                        attitude=False)
    for i, w in enumerate(np.random.default_rng([0, 0x5747]).uniform(0.0, 5.0, n)):
        fleet.stand_still(i, float(w), at=1000.0)
    keys = [wire.key(cfg.id, r, "imu") for r in names]
    stream, doors = [], []
    for k in range(int(seconds * 10)):
        for i, b in enumerate(fleet.next_batches(10)):
            if k == 0:
                doors.append(Inbound("fix", wire.key(cfg.id, names[i], "fix"), wire.encode(wire.Fix.checkpoint(
                    names[i], float(b.t[0]), x=float(b.x[0]), y=float(b.y[0]), floor=int(b.floor[0]), sigma=0.3)),
                    1000.0))
            has_p = len(b.pressure_t) > 0
            stream.append((keys[i], wire.encode(wire.ImuBatch(
                responder=names[i], device=f"sim:{names[i]}", seq=k, t=b.t, utc_offset=0.0, acc=b.acc, gyr=b.gyr,
                mag=b.mag, pressure_t=b.pressure_t if has_p else None, pressure=b.pressure if has_p else None))))
    warm_up(cfg)
    core = IncidentCore(cfg)
    core.feed_round(doors)
    poses, next_tick, timed_from = 0, 1001.0, len(stream) // 4
    cpu0 = wall0 = poses0 = None
    digest = hashlib.sha256()  # every answer's key and bytes, in order: two commits that agree give the same
    for j in range(0, len(stream), round_frames):
        if j >= timed_from and cpu0 is None:
            cpu0, wall0, poses0 = time.process_time(), time.perf_counter(), poses
            if profiler is not None:
                profiler.enable()
        now = 1000.0 + j / (10.0 * n)
        out = core.feed_round([Inbound("imu", k, p, now) for k, p in stream[j:j + round_frames]])
        if now >= next_tick:
            out += core.tick(now)
            next_tick += 1.0
        for o in out:
            digest.update(o.key.encode())
            digest.update(wire.encode(o.message))
            poses += isinstance(o.message, wire.Pose)
    if profiler is not None:
        profiler.disable()
    timed = len(stream) - timed_from
    return {"responders": n, "seconds": seconds, "round_frames": round_frames, "frames_timed": timed,
            "cpu_us_per_frame": round(1e6 * (time.process_time() - cpu0) / timed, 1),
            "wall_us_per_frame": round(1e6 * (time.perf_counter() - wall0) / timed, 1),
            "poses_timed": poses - poses0, "errors": core.counters.errors, "answers_sha256": digest.hexdigest()[:16],
            "steps": sum(r.tracker.steps for r in core.responders.values())}


if __name__ == "__main__":  # pragma: no cover - a command
    args = sys.argv[1:]
    print(json.dumps(core_bench(int(args[0]) if args else 250, float(args[1]) if len(args) > 1 else 12.0,
                                int(args[2]) if len(args) > 2 else 50)))
