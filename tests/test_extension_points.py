"""A new sensor plugs in through a small protocol, from one file: this one.

A motion model is registered here for a carry position, then frames that say they come from
that position travel through the real incident core (decode, gate, tracker, estimator) and
come out as poses the model decided.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr.events import MotionState, StepEvent
from service.core import motion
from service.core.incident_core import IncidentCore, Inbound
from service.core.tracker import TrackerSettings
from service.protocol import wire
from service.protocol.incident import default_incident


class MetronomeModel:
    """A motion model for the test: a 0.8 m step due north every whole second of device time."""

    def __init__(self, floors, start_floor):
        self.steps, self.floor, self.state = 0, start_floor, MotionState.STILL
        self.state_since = self.last_time = math.nan
        self.anchored: list[int] = []

    def update(self, frame):
        out = []
        t0 = self.last_time if math.isfinite(self.last_time) else float(frame.t[0])
        for sec in range(math.floor(t0) + 1, math.floor(float(frame.t[-1])) + 1):
            self.steps += 1
            out.append(StepEvent(t=float(sec), index=self.steps, length=0.8, length_sigma=0.05, heading=math.pi / 2,
                                 heading_sigma=0.01, heading_change=0.0, heading_change_sigma=0.01, dz=0.0,
                                 dz_sigma=0.1, floor=self.floor, on_stairs=False, mag_heading=math.nan,
                                 mag_heading_sigma=math.inf))
        self.last_time = float(frame.t[-1])
        self.state = MotionState.WALKING if out else self.state
        return out

    def finish(self):
        return []

    def anchor_floor(self, floor):
        self.floor = floor
        self.anchored.append(floor)


@pytest.fixture
def metronome_on_armband():
    saved = dict(motion._MODELS)
    motion.register_motion_model("armband", lambda settings, floors, start_floor: MetronomeModel(floors, start_floor))
    yield
    motion._MODELS.clear()
    motion._MODELS.update(saved)


def _frames(responder, carry, seconds=12.0, rate=50.0):
    t = 100.0 + np.arange(int(seconds * rate)) / rate
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 1))
    return list(wire.imu_batches_from_arrays(responder, "dev", t, acc, np.zeros((t.size, 3)), carry=carry,
                                             per_batch=5))


@pytest.mark.parametrize("engine", ["dr", "fusion"])
def test_a_motion_model_registered_from_a_test_tracks_its_carry_position(metronome_on_armband, engine):
    cfg = default_incident()
    core = IncidentCore(cfg, settings=None)
    core.settings = type(core.settings)(tracker=TrackerSettings(engine=engine, pipeline=core.settings.tracker.pipeline))
    fix = wire.Fix.checkpoint("arm", 100.0, x=10.0, y=-5.0, floor=0, sigma=0.2)
    items = [Inbound("fix", wire.key(cfg.id, "arm", "fix"), wire.encode(fix), 0.0)]
    items += [Inbound("imu", wire.key(cfg.id, "arm", "imu"), wire.encode(b), 0.0) for b in _frames("arm", "armband")]
    items += [Inbound("imu", wire.key(cfg.id, "hand", "imu"), wire.encode(b), 0.0) for b in _frames("hand", "handheld")]
    poses = [o.message for o in core.feed_round(items) if isinstance(o.message, wire.Pose)]
    arm = [p for p in poses if p.responder == "arm"]
    assert isinstance(core.responders["arm"].tracker.model, MetronomeModel)
    assert not isinstance(core.responders["hand"].tracker.model, MetronomeModel)  # other carries keep the PDR
    assert core.responders["arm"].tracker.model.anchored == [0]  # the checkpoint's floor reached the model
    assert [p.steps for p in arm] == list(range(1, 12))
    for p in arm:  # 0.8 m north per second from the checkpoint
        assert p.x == pytest.approx(10.0, abs=0.05) and p.y == pytest.approx(-5.0 + 0.8 * p.steps, abs=0.05)
    assert core.counters.errors == 0
