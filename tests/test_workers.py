"""``serve --workers K``: every worker process runs with the service's own settings, not its defaults.

A real router on loopback and a worker in its own (spawned) process: the intake's admission
budget given to the pool must hold in that worker too (a pool that dropped the settings gave
worker 0 the budget and the others the default one).
"""
from __future__ import annotations

import dataclasses
import tempfile

from service.core.incident_core import CoreSettings
from service.core.intake import IntakeSettings
from service.protocol import wire
from service.protocol.incident import default_incident
from service.shell.service import ServiceSettings
from service.shell.sharding import in_shard
from service.shell.workers import WorkerPool
from tests.security_util import matched_publisher, walking_frames
from tests.zenoh_util import client, router


def test_a_worker_process_admits_new_ids_within_the_budget_the_service_was_given():
    cfg = default_incident()
    ids = [f"w{i}" for i in range(40) if in_shard(f"w{i}", 1, 2)][:5]  # all of them worker 1's
    assert len(ids) == 5
    budget = dataclasses.replace(IntakeSettings(), admit_burst=2.0, admit_per_s=0.001)
    settings = ServiceSettings(core=CoreSettings(intake=budget), warm_up=False)
    rs, endpoint = router()
    stats_dir = tempfile.mkdtemp()
    pool = WorkerPool(endpoint, cfg, 2, stats_dir=stats_dir, settings=settings)
    cl = client(endpoint)
    try:
        assert pool.wait_ready(120), "the worker process did not start"
        for rid in ids:  # announced as a wearable does: worker 1 subscribes to its frames (shard_routes.py)
            token = cl.liveliness().declare_token(wire.key(cfg.id, rid, "presence"))
            pub = matched_publisher(cl, wire.key(cfg.id, rid, "imu"), timeout=30)
            for b in walking_frames(rid, 0.5):
                pub.put(wire.encode(b))
            pub.undeclare()
            token.undeclare()
    finally:
        stats = pool.close()
        cl.close()
        rs.close()
    (worker,) = stats
    assert worker["shard"] == 1
    assert worker["responders"] == 2, worker  # the default budget (256 at once) would have taken all 5
    assert worker["frames_not_processed"].get("not_admitted", 0) == 3 * 5, worker["frames_not_processed"]
