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

    def anchor_floor(self, floor, t=None):
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


# -- a new fix type: a BLE beacon the responder passed close by ------------------------------
import dataclasses  # noqa: E402
from typing import ClassVar, Literal  # noqa: E402

from service.core import fix_types  # noqa: E402
from service.protocol import schema  # noqa: E402

BEACONS = {"b-door": (12.0, 3.0), "b-stair": (-4.0, 20.0)}  # the test's own survey, ENU m


class BeaconFixMessage(wire.Fix):
    """Wire model: the responder's phone heard beacon ``beacon`` at about ``proximity_m``."""

    SOURCE: ClassVar[str] = "beacon"
    source: Literal["beacon"] = "beacon"
    beacon: str
    proximity_m: float


@dataclasses.dataclass(frozen=True)
class BeaconFix:
    """Domain fix in the local frame, with its factor: a translation prior at the beacon."""

    t: float
    x: float
    y: float
    sigma: float
    source: str = "beacon"

    def factors(self, ctx):
        import gtsam

        p, cov = ctx.position_marginal()
        if math.hypot(p[0] - self.x, p[1] - self.y) > 50.0:  # a gate of the type's own
            ctx.reject("beacon_far", "more than 50 m from the track")
            return None
        noise = gtsam.noiseModel.Isotropic.Sigma(2, math.hypot(self.sigma, ctx.slip))
        return [gtsam.PoseTranslationPrior2D(ctx.key, np.array([self.x, self.y]), noise)]


def _beacon_to_local(msg, incident):
    if msg.beacon not in BEACONS:
        raise fix_types.FixRejected("unknown_reference", f"beacon {msg.beacon!r} is not surveyed")
    x, y = BEACONS[msg.beacon]
    return BeaconFix(msg.t, x, y, msg.proximity_m)


@pytest.fixture
def beacon_fix_type():
    saved_msgs, saved_types = dict(schema.FIX_MESSAGES), dict(fix_types._TYPES)
    schema.register_fix_message(BeaconFixMessage)
    fix_types.register_fix_type(fix_types.FixType("beacon", _beacon_to_local))
    yield
    schema.FIX_MESSAGES.clear()
    for m in saved_msgs.values():
        schema.register_fix_message(m)
    fix_types._TYPES.clear()
    fix_types._TYPES.update(saved_types)


def test_a_fix_type_registered_from_a_test_reaches_the_factor_graph(metronome_on_armband, beacon_fix_type):
    cfg = default_incident()
    core = IncidentCore(cfg)
    key = {k: wire.key(cfg.id, "arm", k) for k in ("imu", "fix")}
    start = wire.Fix.checkpoint("arm", 100.0, x=10.0, y=-5.0, floor=0, sigma=0.2)
    beacon = wire.Fix(responder="arm", t=108.0, source="beacon", beacon="b-door", proximity_m=0.5)
    assert isinstance(wire.decode(wire.encode(beacon), expect=wire.Fix), BeaconFixMessage)  # on the wire
    unknown = wire.Fix(responder="arm", t=109.0, source="beacon", beacon="b-attic", proximity_m=0.5)
    frames = _frames("arm", "armband")
    items = [Inbound("fix", key["fix"], wire.encode(start), 0.0)]
    for b in frames:
        items.append(Inbound("imu", key["imu"], wire.encode(b), 0.0))
        if b.t[-1] >= 110.0 and beacon is not None:  # the walk has passed both fix times
            items += [Inbound("fix", key["fix"], wire.encode(m), 0.0) for m in (beacon, unknown)]
            beacon = None
    poses = [o.message for o in core.feed_round(items) if isinstance(o.message, wire.Pose)]
    tracker = core.responders["arm"].tracker
    assert tracker.fixes_applied == 2  # the checkpoint that placed it, and the beacon
    assert core.responders["arm"].fixes_rejected == {"unknown_reference": 1}
    # the metronome walks north from (10, -5); the beacon at (12, 3) at t = 108 pulls the track to it
    assert poses[-1].source == "fused"
    sm = tracker.smoothed_track()
    i = int(np.argmin(np.abs(sm["t"] - 108.0)))
    fused = math.hypot(sm["x"][i] - 12.0, sm["y"][i] - 3.0)
    alone = math.hypot(10.0 - 12.0, -5.0 + 0.8 * 8 - 3.0)  # where dead reckoning alone had it at t = 108
    assert fused < 0.75 * alone
