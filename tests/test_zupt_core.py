"""The boot INS through the real incident core, registered for ``carry="foot"`` from this test.

The service's wiring (service/core/motion.py) is the lead's; this shows that
:class:`pdr.zupt.ZuptMotionModel` fits the :class:`service.core.motion.MotionModel` protocol:
a synthetic boot walk goes through decode, gate, tracker and estimator and comes out as
poses on the true stances.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr.zupt import ZuptMotionModel
from pdr.zupt.synthetic import foot_walk, square_strides
from service.core import motion
from service.core.incident_core import IncidentCore, Inbound
from service.core.tracker import TrackerSettings
from service.protocol import wire
from service.protocol.incident import default_incident


@pytest.fixture
def boots_on_feet():
    saved = dict(motion._MODELS)
    motion.register_motion_model("foot", lambda settings, floors, start_floor: ZuptMotionModel(
        floors=floors, start_floor=start_floor))
    yield
    motion._MODELS.clear()
    motion._MODELS.update(saved)


@pytest.mark.parametrize("engine", ["dr", "fusion"])
def test_a_boot_walk_through_the_incident_core(boots_on_feet, engine):
    w = foot_walk(square_strides(5, 1.2), acc_noise=0.02, gyr_noise=math.radians(0.5), seed=11, t0=100.0)
    cfg = default_incident()
    core = IncidentCore(cfg, settings=None)
    core.settings = type(core.settings)(tracker=TrackerSettings(engine=engine, pipeline=core.settings.tracker.pipeline))
    x0, y0 = 10.0, -5.0
    fix = wire.Fix.checkpoint("boot", 100.5, x=x0, y=y0, floor=0, sigma=0.05)
    items = [Inbound("fix", wire.key(cfg.id, "boot", "fix"), wire.encode(fix), 0.0)]
    batches = wire.imu_batches_from_arrays("boot", "dev", w.t, w.acc, w.gyr, carry="foot", per_batch=10)
    items += [Inbound("imu", wire.key(cfg.id, "boot", "imu"), wire.encode(b), 0.0) for b in batches]
    out = core.feed_round(items)
    poses = [o.message for o in out if isinstance(o.message, wire.Pose) and o.message.responder == "boot"]
    assert isinstance(core.responders["boot"].tracker.model, ZuptMotionModel)
    assert core.counters.errors == 0
    assert [p.steps for p in poses][-1] == 20
    # the INS frame's yaw 0 is the boot's x axis at the start, east in this walk: poses land on the stances
    truth = w.stance_positions[1:, :2] + [x0, y0]
    xy = np.array([[p.x, p.y] for p in poses[-20:]])
    assert np.max(np.linalg.norm(xy - truth, axis=1)) < 0.3
    status = [o.message for o in core.tick(1.0) if isinstance(o.message, wire.Status) and o.message.responder == "boot"]
    assert len(status) == 1 and status[0].motion == "walking" and status[0].steps == 20
