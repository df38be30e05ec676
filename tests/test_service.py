"""The live service on a real zenoh router on loopback: equivalence with the offline path,
several responders, fixes, status, the track queryable and bad input at the edge."""
from __future__ import annotations

import threading
import time
import warnings

import msgpack
import numpy as np
from pdr.floors import FloorElevations
import pytest

from client.wearable import Wearable
from pdr.synthetic import static_imu
from service.core.incident_core import Inbound, IncidentCore
from service.core.tracker import (
    CheckpointFix,
    PoseEstimate,
    ResponderTracker,
    tracker_settings_for,
)
from service.protocol import wire
from service.protocol.incident import default_incident
from service.protocol.messages import recording_messages
from service.protocol.pacing import paced
from service.shell.service import IncidentService, ServiceSettings, decode_track
from tests.zenoh_util import client, router, wait_until

IPIN_TRIAL52 = "ipin2023/IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"


@pytest.fixture
def live():
    """A router on a free port with the service of the demo incident on it, and a client session."""
    session, endpoint = router()
    cfg = default_incident()
    svc = IncidentService(session, cfg, ServiceSettings()).start()
    cl = client(endpoint)
    yield svc, cl, cfg
    cl.close()
    svc.close()
    session.close()


class Collector:
    def __init__(self, session, key):
        self.items: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample):
        with self._lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def decoded(self, responder=None):
        with self._lock:
            items = list(self.items)
        msgs = [wire.decode(p) for _, p in items]
        return [m for m in msgs if responder is None or m.responder == responder]


def offline_poses(cfg, msgs, responder):
    """The same messages through a ResponderTracker without any network: the reference."""
    s = ServiceSettings().core
    tracker = ResponderTracker(responder, FloorElevations(cfg.elevations()), cfg.start_floor, tracker_settings_for(cfg),
                               entry=CheckpointFix(0.0, 0.0, 0.0, cfg.start_floor, s.entry_sigma_m))
    from pdr.pipeline import ImuFrame

    poses = []
    for m in msgs:
        if m.kind == "imu":
            b = m.msg
            out = tracker.on_frame(ImuFrame(b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure))
        else:
            f = m.msg
            p = tracker.on_fix(CheckpointFix(f.t, f.x, f.y, f.floor, f.sigma))
            out = [p] if p is not None else []
        poses += [o for o in out if isinstance(o, PoseEstimate)]
    return poses


@pytest.mark.bitexact
@pytest.mark.recording
def test_replay_through_zenoh_equals_the_offline_pipeline(live, shared_data):
    svc, cl, cfg = live
    from pdr.io import load

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = load(shared_data(IPIN_TRIAL52))
    msgs = recording_messages(rec, "r52", incident=cfg, landmark_every=3, gnss=False)
    msgs = [m for m in msgs if m.t <= msgs[0].t + 150.0]  # 150 s of the walk keeps the test short
    expected = offline_poses(cfg, msgs, "r52")
    assert len(expected) > 100
    poses = Collector(cl, wire.key(cfg.id, "r52", "pose"))
    w = Wearable(cl, cfg.id, "r52")
    sent = {"imu": 0, "fix": 0}
    for m in paced(msgs, speed=0):
        if m.kind == "fix":  # zenoh orders per key, not across keys: let the frames before a fix land first
            assert wait_until(lambda: svc.received["imu"] >= sent["imu"], 30)
        w.send(m.kind, m.msg)
        sent[m.kind] += 1
        if m.kind == "fix":
            assert wait_until(lambda: svc.received["fix"] >= sent["fix"], 30)
    n_frames = sum(m.kind == "imu" for m in msgs)
    assert wait_until(lambda: svc.frames_processed >= n_frames, 60)
    assert wait_until(lambda: len(poses.items) >= len(expected), 10)
    got = poses.decoded("r52")
    w.close()
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        assert g.t == e.t and g.steps == e.steps and g.floor == e.floor and g.source == e.source
        # the same code on the same frames: bit for bit, whatever the batching on the way
        assert (g.x, g.y) == (e.x, e.y)
        assert np.array_equal(g.cov, e.cov)
    assert got[-1].source == "fused"


def _walker_frames(responder, seconds=40.0, rate=50.0, seed=0, still=False):
    from pdr.synthetic import static_imu as _static

    imu = _static(seconds=seconds, rate_hz=rate, seed=seed)
    acc = imu.acc.copy()
    if not still:  # a bounce at 1.8 Hz on the vertical: steps for the norm detector
        acc[:, 2] += 2.5 * np.sin(2 * np.pi * 1.8 * imu.t)
    return list(wire.imu_batches_from_arrays(responder, f"dev-{responder}", imu.t + 1000.0, acc, imu.gyr, imu.mag,
                                             per_batch=5))


def test_several_responders_each_get_their_poses_and_status(live):
    svc, cl, cfg = live
    poses = Collector(cl, wire.key_all(cfg.id, "pose"))
    status = Collector(cl, wire.key_all(cfg.id, "status"))
    ids = ["alpha", "bravo", "charlie"]
    frames = {r: _walker_frames(r, seed=i, still=(r == "charlie")) for i, r in enumerate(ids)}
    wearables = {r: Wearable(cl, cfg.id, r) for r in ids}
    for k in range(len(frames["alpha"])):  # interleaved, as live
        for r in ids:
            wearables[r].send("imu", frames[r][k])
    assert wait_until(lambda: svc.frames_processed >= 3 * len(frames["alpha"]), 30)
    assert wait_until(lambda: {s.responder for s in status.decoded()} >= set(ids), 5)
    by = {r: poses.decoded(r) for r in ids}
    assert len(by["alpha"]) > 40 and len(by["bravo"]) > 40
    assert by["charlie"] == []  # standing still: no steps, no poses
    for r in ("alpha", "bravo"):
        steps = [p.steps for p in by[r]]
        assert steps == sorted(steps) and steps[-1] == svc.responders[r].tracker.steps
    st = {s.responder: s for s in status.decoded()}
    assert st["charlie"].motion in ("still", "no_motion") and st["alpha"].frames > 0
    # the track queryable answers per responder
    replies = list(cl.get(wire.key(cfg.id, "alpha", "track"), timeout=5.0))
    tracks = [decode_track(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
    assert len(tracks) == 1 and tracks[0]["responder"] == "alpha" and tracks[0]["t"].size >= len(by["alpha"])
    for w in wearables.values():
        w.close()


def test_bad_frames_are_counted_and_harm_no_one(live):
    svc, cl, cfg = live
    good = _walker_frames("good", seconds=20.0)
    bad_frames = _walker_frames("bad", seconds=20.0)
    wg, wb = Wearable(cl, cfg.id, "good"), Wearable(cl, cfg.id, "bad")
    nan_batch = bad_frames[3].to_wire()
    acc = np.frombuffer(nan_batch["acc"], "<f8").copy()
    acc[4] = np.nan
    nan_batch["acc"] = acc.tobytes()
    attacks = [
        b"\xc1not msgpack",  # malformed
        msgpack.packb({"v": 1, "kind": "imu", "responder": "bad"}),  # schema violation
        msgpack.packb(nan_batch, use_bin_type=True),  # NaN
        b"\x00" * (wire.MAX_PAYLOAD_BYTES + 1),  # oversized (refused by the intake, by its size alone)
        msgpack.packb({"v": 1, "kind": "pose", "responder": "bad"}),  # another kind on the frames' key
    ]
    for k in range(len(good)):
        wg.send("imu", good[k])
        if k < 10:
            wb.send("imu", bad_frames[k])
        elif k < 10 + len(attacks):
            wb.send("imu", attacks[k - 10])
        elif k == 20:
            wb.send("imu", bad_frames[5])  # a duplicate seq
        elif k > 20:
            wb.send("imu", bad_frames[k])
    assert wait_until(lambda: svc.frames_processed >= len(good) + len(bad_frames) - 12, 30)

    def all_judged():  # every good frame taken, the five attacks and the duplicate counted
        try:
            return (svc.responders["good"].gate.accepted == len(good)
                    and sum(svc.responders["bad"].gate.counts.values())
                    + sum(svc.core.intake.dropped_of("bad").values()) >= len(attacks) + 1)
        except RuntimeError:  # the worker changed a count while it was read: look again
            return False
    assert wait_until(all_judged, 10)
    st = svc.core.status_of(svc.responders["bad"], time.time())
    counts = st.rejected
    for reason in ("msgpack", "schema", "nonfinite", "oversize", "kind"):
        assert counts.get(reason, 0) == 1, (reason, counts)
    assert counts.get("duplicate", 0) + counts.get("late", 0) == 1
    assert svc.responders["good"].gate.counts == {}
    assert svc.responders["good"].gate.accepted == len(good)
    assert "rejected_frames" in st.alarms  # five bad messages within the window (a duplicate does not count)
    assert svc.errors == 0
    wg.close()
    wb.close()


def test_unknown_checkpoint_is_rejected_with_its_name(live):
    svc, cl, cfg = live
    w = Wearable(cl, cfg.id, "delta")
    for b in _walker_frames("delta", seconds=5.0):
        w.send("imu", b)
    w.send("fix", wire.Fix.checkpoint("delta", 1003.0, name="no-such-door"))
    w.send("fix", wire.Fix.checkpoint("delta", 1003.0, name=cfg.checkpoints[0].name))
    assert wait_until(lambda: svc.responders.get("delta") is not None
                      and svc.responders["delta"].fixes_rejected.get("unknown_reference") == 1, 10)
    w.close()


def test_motionless_responder_raises_man_down(live):
    svc, cl, cfg = live
    imu = static_imu(seconds=40.0, rate_hz=25.0)
    w = Wearable(cl, cfg.id, "echo")
    for b in wire.imu_batches_from_arrays("echo", "dev", imu.t, imu.acc, imu.gyr, imu.mag, per_batch=5):
        w.send("imu", b)
    assert wait_until(lambda: "echo" in svc.responders and svc.responders["echo"].gate.accepted == 200, 20)
    # the gate counts a frame before the round's end runs it through the tracker: wait for the tracker
    assert wait_until(lambda: svc.responders["echo"].tracker.device_time >= imu.t[-1], 20)
    st = svc.core.status_of(svc.responders["echo"], time.time())
    assert st.motion == "no_motion" and "man_down" in st.alarms
    w.close()


def _simulated_messages(n_walkers=3, seconds=60.0, fix_every_s=7.0):
    """(kind, key, payload) of simulated walkers interleaved as they would arrive: frames of
    10 samples, a checkpoint fix at each one's start and then every ``fix_every_s``, GNSS
    fixes in between."""
    from pdr.simulation import WalkerFleet

    cfg = default_incident()
    names = [f"w{i}" for i in range(n_walkers)]
    fleet = WalkerFleet(n_walkers, responders=names, seed=3, attitude=False, floors=(0, 0), start_t=100.0)
    out = []
    for k in range(int(seconds * 10)):
        for i, b in enumerate(fleet.next_batches(10)):
            if k % int(fix_every_s * 10) == 0:  # a checkpoint passed just now; every other one
                # claims the floor below, so when a fix re-anchors the floor shows in the poses
                floor = int(b.floor[0]) - (k // int(fix_every_s * 10)) % 2
                fix = wire.Fix.checkpoint(names[i], float(b.t[0]), x=float(b.x[0]), y=float(b.y[0]),
                                          floor=max(floor, -2), sigma=0.3)
                out.append(("fix", wire.key(cfg.id, names[i], "fix"), wire.encode(fix)))
            if k % 30 == 15:  # and a GNSS fix every 3 s, 2 m off
                lat, lon, _ = cfg.to_geodetic(float(b.x[0]) + 2.0, float(b.y[0]))
                fix = wire.Fix.gnss(names[i], float(b.t[0]), lat=float(lat), lon=float(lon), accuracy=4.0)
                out.append(("fix", wire.key(cfg.id, names[i], "fix"), wire.encode(fix)))
            msg = wire.ImuBatch(responder=names[i], device="sim", seq=k, t=b.t, acc=b.acc, gyr=b.gyr, mag=b.mag,
                                pressure_t=b.pressure_t, pressure=b.pressure)
            out.append(("imu", wire.key(cfg.id, names[i], "imu"), wire.encode(msg)))
    return cfg, out


def _poses(outputs):
    return [o.message for o in outputs if isinstance(o.message, wire.Pose)]


@pytest.mark.bitexact
def test_rounds_of_any_size_give_the_same_poses_bit_for_bit():
    """Behind, the worker joins a responder's frames into one pipeline batch; the poses must
    be those of one message at a time (what ``reprocess`` does), fixes included."""
    cfg, msgs = _simulated_messages()
    one, out_one = IncidentCore(cfg), []
    for kind, key, payload in msgs:
        out_one += one.feed(Inbound(kind, key, payload, 0.0))
    rng = np.random.default_rng(7)
    rounds, out_rounds = IncidentCore(cfg), []
    i = 0
    while i < len(msgs):
        n = int(rng.integers(1, 120))
        out_rounds += rounds.feed_round([Inbound(kind, key, payload, 0.0) for kind, key, payload in msgs[i:i + n]])
        i += n
    # each responder's poses in order (between responders a round may reorder them)
    a = sorted(_poses(out_one), key=lambda p: p.responder)
    b = sorted(_poses(out_rounds), key=lambda p: p.responder)
    assert rounds.counters.errors == 0 and one.counters.errors == 0
    assert rounds.counters.tracker_batches < 0.5 * one.counters.tracker_batches  # frames were joined
    assert rounds.counters.frames_processed == one.counters.frames_processed == sum(k == "imu" for k, _, _ in msgs)
    assert len(a) == len(b) > 100
    assert sum(p.source == "fused" for p in a) > 50  # the fixes were applied ...
    assert all(r.tracker.fixes_applied > 9 for r in rounds.responders.values())  # ... GNSS ones too (those above
    assert all(any(e.what == "gnss" and e.kind == "accepted" for e in r.tracker.estimator.fusion.events)  # ground, one per 5 s)
               for r in rounds.responders.values())
    for p, q in zip(a, b):
        assert (p.responder, p.t, p.x, p.y, p.floor, p.steps, p.source) == (q.responder, q.t, q.x, q.y, q.floor,
                                                                             q.steps, q.source)
        assert np.array_equal(p.cov, q.cov)


def test_a_pose_is_stamped_once_when_its_round_answers():
    """``published_at`` is set in one place: the stamp the round's caller hands in is read once
    per round that answers poses, and every pose of the round carries that reading; without a
    stamp (reprocess, benches) a pose carries its round's time. Nothing else differs."""
    cfg, msgs = _simulated_messages()
    plain, stamped = IncidentCore(cfg), IncidentCore(cfg)
    readings: list[float] = []

    def stamp() -> float:
        readings.append(5000.0 + len(readings))
        return readings[-1]

    n_rounds_with_poses = 0
    for i in range(0, len(msgs), 40):
        items = [Inbound(kind, key, payload, 10.0 + i) for kind, key, payload in msgs[i:i + 40]]
        a, before = _poses(plain.feed_round(items)), len(readings)
        b = _poses(stamped.feed_round(items, stamp=stamp))
        assert len(readings) - before == (1 if b else 0)  # read once for the whole round, and only when it answers
        n_rounds_with_poses += bool(b)
        assert all(p.published_at == 10.0 + i for p in a)  # the round's time
        assert all(q.published_at == readings[-1] for q in b)  # the one reading
        assert [p.model_copy(update={"published_at": 0.0}) for p in a] == \
            [q.model_copy(update={"published_at": 0.0}) for q in b]
    assert n_rounds_with_poses > 10 and len(readings) == n_rounds_with_poses


def test_warm_up_takes_a_responder_through_every_kind_of_fix():
    """The service warms its kernels, graph and codecs on a simulated responder before it
    subscribes; every kind of fix the incident supports must go through without an error."""
    from service.core.warmup import warm_up
    from service.protocol.incident import UwbAnchor

    cfg = default_incident()
    cfg = cfg.model_copy(update={"uwb_anchors": [UwbAnchor(id="A1", x=3.0, y=4.0)]})
    w = warm_up(cfg)
    assert w.errors == 0
    assert w.poses > 10
    assert w.fixes_applied == 4  # door checkpoint, GNSS, UWB range, second checkpoint
