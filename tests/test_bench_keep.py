"""The benchmark's wearables keep what a real one keeps (issue 29): a service behind asks for
frames older than the old 10 s keep, and they come.

A real router on loopback; :class:`client.simulate.SimulationPublisher` as the benchmark runs
it (frames precomputed, then put in real time); a Status naming missing
frames, as the service's gate puts it, on the wearable's status key.
"""
from __future__ import annotations

import time

import zenoh

from client.simulate import SIM_KEEP_FRAMES, PrecomputedKeep, SimulationPublisher
from client.wearable import KEEP_FRAMES
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.zenoh_util import client, router, wait_until

SECONDS = 12.0  # of frames: 120 per walker, more than SIM_KEEP_FRAMES


def test_a_precomputed_run_resends_frames_beyond_the_old_simulator_keep():
    cfg = default_incident()
    rs, endpoint = router()
    pub_s, svc = client(endpoint), client(endpoint)
    heard: list[int] = []
    sub = svc.declare_subscriber(wire.key(cfg.id, "sim-000", "imu"),
                                 lambda s: heard.append(wire.decode(s.payload.to_bytes(), expect=wire.ImuBatch).seq))
    pub = SimulationPublisher(pub_s, cfg.id, 2, 100.0, 0, truth=False)
    try:
        assert SECONDS * 10 > SIM_KEEP_FRAMES
        # the subscriber's declaration must reach the wearable's side first, or frame 0 goes to nobody
        # (CI with three workers once heard one frame fewer than sent)
        assert wait_until(lambda: pub.wearables[0].heard), "the test's subscriber never matched the frames"
        pub.step(1)
        frames = pub.precompute(SECONDS)
        keep = PrecomputedKeep(frames, 0, 1, pub.seq, KEEP_FRAMES)
        assert len(keep) == 0  # nothing of the table is sent yet
        pub.run_precomputed(frames, frames_per_s=1000.0)  # 10 times faster than real time
        assert len(keep) == len(frames) and keep[5] is frames[4][0]  # a view of the table, not a copy
        assert wait_until(lambda: len(heard) == 1 + len(frames)), \
            (len(heard), 1 + len(frames), pub.wearables[0].unheard)
        boot = pub.wearables[0].boot
        status = wire.Status(responder="sim-000", t=0.0, motion="walking", motion_since=0.0, last_heard=time.time(),
                             device="sim:sim-000", boot=boot, seq=0, missing=[0, 20])
        svc.put(wire.key(cfg.id, "sim-000", "status"), wire.encode(status),
                congestion_control=zenoh.CongestionControl.BLOCK)
        # frame 0 (sent by step) and 1..20 (precomputed), now more than SIM_KEEP_FRAMES frames back
        assert wait_until(lambda: len(heard) == 1 + len(frames) + 21), f"{len(heard) - 1 - len(frames)} resent of 21"
        assert sorted(heard[1 + len(frames):]) == list(range(21))
    finally:
        sub.undeclare()
        pub.close()
        for s in (pub_s, svc, rs):
            s.close()
