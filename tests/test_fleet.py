"""The one PDR engine (:class:`pdr.fleet.PdrFleet`; issues 15, 30): a responder's events are
the same, bit for bit, alone (a :class:`pdr.pipeline.PdrPipeline`, a fleet of one, fed frame
by frame) or among many members in rounds of any size, joining, leaving and reusing slots; a
pickled fleet goes on as the original; and the service gives a responder the same poses
whether others share its core or not."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from pdr.events import MotionEvent
from pdr.fleet import PdrFleet
from pdr.fleet_rows import FleetRows
from pdr.floors import FloorElevations
from pdr.pipeline import ImuFrame, PdrPipeline, PipelineSettings, frames_of
from tests.test_pipeline import events_close

IPIN = ["ipin2023/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz",
        "ipin2023/IPIN2023_T3_TrainingTrial21_repetition01.txt.gz",
        "ipin2023/IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"]


def same_events(a, b) -> bool:
    """Same events, every number bit for bit (NaN equals NaN)."""
    return events_close(a, b, 0.0)


def by_kind(events):
    """Steps and floor events in order, and motion changes in order (how the two kinds interleave
    within one call depends on the batching, as in PdrPipeline)."""
    return ([e for e in events if not isinstance(e, MotionEvent)], [e for e in events if isinstance(e, MotionEvent)])


def join(frames: list[ImuFrame]) -> ImuFrame:
    def cat(name):
        parts = [getattr(f, name) for f in frames if getattr(f, name) is not None]
        return np.concatenate(parts) if parts else None
    return ImuFrame(cat("t"), cat("acc"), cat("gyr"), cat("mag"), cat("pressure_t"), cat("pressure"))


def alone(frames, floors, start_floor, settings=None):
    p = PdrPipeline(settings, floors, start_floor)
    out = []
    for f in frames:
        out += p.update(f)
    return out + p.finish()


def in_fleet(walks, floors, settings=None, seed=0, max_join=3, p_take=0.7, anchors=None):
    """Every walk's frames through one fleet: each round takes a random subset of the
    responders, each a random number of its next frames joined (as the service joins a
    responder's frames of a round). Returns the events, the members and the frames each
    member was given (to give a fleet of one the same batches: the compass sigma of a step
    answered while the field reference is still being learned depends on the batching, a
    property of the pipeline itself)."""
    rng = np.random.default_rng(seed)
    fleet = PdrFleet(settings, floors, capacity=2)  # small: the rows grow (and the views follow) mid-run
    members = [fleet.member(sf) for _, sf in walks]
    out = [[] for _ in walks]
    given = [[] for _ in walks]
    pos = [0] * len(walks)
    while any(pos[i] < len(w) for i, (w, _) in enumerate(walks)):
        items = []
        for i, (w, _) in enumerate(walks):
            if pos[i] < len(w) and rng.random() < p_take:
                k = int(rng.integers(1, max_join + 1))
                items.append((i, join(w[pos[i]:pos[i] + k])))
                given[i].append(items[-1][1])
                pos[i] += k
        for (i, _), events in zip(items, fleet.run([(members[i], f) for i, f in items])):
            assert not isinstance(events, Exception), events
            out[i] += events
        if anchors:
            for i, at, floor in anchors:
                if pos[i] == at:
                    members[i].anchor_floor(floor)
    return [o + m.finish() for o, m in zip(out, members)], members, given


def simulated(n, seconds, seed=3, still=()):
    from pdr.simulation import WalkerFleet, WalkerSettings

    sim = WalkerFleet(n, WalkerSettings(rate_hz=100.0), seed, responders=[f"w{i}" for i in range(n)], floors=(0, 2),
                      start_t=1000.0, attitude=False)
    for i, at, dur in still:
        sim.stand_still(i, dur, at=at)
    walks = [[] for _ in range(n)]
    for _ in range(int(seconds * 10)):
        for i, b in enumerate(sim.next_batches(10)):
            has_p = len(b.pressure_t) > 0
            walks[i].append(ImuFrame(b.t, b.acc, b.gyr, b.mag, b.pressure_t if has_p else None, b.pressure if has_p else None))
    return walks


@pytest.mark.bitexact
def test_simulated_walkers_alone_and_in_a_fleet_give_the_same_events():
    floors = FloorElevations.uniform(3.0, 0, 2)
    walks = simulated(12, 70, still=[(0, 1000.0, 8.0), (3, 1020.0, 35.0), (5, 1010.0, 12.0)])
    # one without a magnetometer, one of pressure-free frames: the fleet takes mixed rounds
    walks[1] = [ImuFrame(f.t, f.acc, f.gyr, None, f.pressure_t, f.pressure) for f in walks[1]]
    walks[2] = [ImuFrame(f.t, f.acc, f.gyr, f.mag) for f in walks[2]]
    for seed, join_max in ((1, 1), (2, 4)):
        got, _, given = in_fleet([(w, 0) for w in walks], floors, seed=seed, max_join=join_max)
        ref = [alone(g, floors, 0) for g in given]
        for i, (a, b) in enumerate(zip(ref, got)):
            (sa, ma), (sb, mb) = by_kind(a), by_kind(b)
            assert same_events(sa, sb), f"walker {i}: steps differ (rounds seed {seed})"
            assert same_events(ma, mb), f"walker {i}: motion states differ (rounds seed {seed})"
    assert sum(len(by_kind(a)[0]) for a in ref) > 600
    assert any(e.state.value == "no_motion" for e in by_kind(ref[3])[1])  # 35 s still: the stillness windows ran


@pytest.mark.bitexact
def test_a_released_slot_serves_a_new_member_as_a_fresh_pipeline():
    """An expired responder's slot goes to the next one (bounded memory), with no trace of it."""
    floors = FloorElevations.uniform(3.0, 0, 2)
    walks = simulated(3, 40, seed=5)
    fleet = PdrFleet(None, floors, capacity=2)
    old, other = fleet.member(0), fleet.member(0)
    for f, g in zip(walks[0][:250], walks[1][:250]):
        fleet.run([(old, f), (other, g)])
    slot = old.slot
    fleet.release(old)
    with pytest.raises(ValueError, match="not a current member"):
        fleet.release(old)
    new = fleet.member(0)
    assert new.slot == slot and len(fleet.members) == 2
    got = []
    for f, g in zip(walks[2], walks[1][250:] + [None] * len(walks[2])):
        res = fleet.run([(new, f)] + ([(other, g)] if g is not None else []))
        got += res[0]
    got += new.finish()
    ref = alone(walks[2], floors, 0)
    (sa, ma), (sb, mb) = by_kind(ref), by_kind(got)
    assert len(sa) > 40 and same_events(sa, sb) and same_events(ma, mb)


@pytest.mark.bitexact
@pytest.mark.recording
def test_real_walks_alone_and_in_a_fleet_give_the_same_events(shared_data):
    from pdr.io import load

    floors = FloorElevations.uniform(3.0, -2, 0)
    walks = []
    for name in IPIN:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = load(shared_data(name))
        imu = rec.imu_samples()
        frames = list(frames_of(imu.t, imu.acc, imu.gyr, imu.mag, rec.pressure.t, rec.pressure.values[:, 0], per_frame=10))
        walks.append((frames, int(rec.landmarks.floor[0])))
    # the same walks three times in the fleet, so that rounds hold several responders at once
    got, _, given = in_fleet(walks * 3, floors, seed=5)
    ref = [alone(g, floors, sf) for g, (_, sf) in zip(given, walks * 3)]
    for i, (a, b) in enumerate(zip(ref, got)):
        assert same_events(by_kind(a)[0], by_kind(b)[0]), f"{IPIN[i % len(walks)]}: steps differ"
        assert same_events(by_kind(a)[1], by_kind(b)[1]), f"{IPIN[i % len(walks)]}: motion states differ"
    assert all(len(by_kind(a)[0]) > 80 for a in ref)
    assert any(e.on_stairs for e in by_kind(ref[2])[0])  # trial 52 climbs: height, floors and stairs ran


@pytest.mark.bitexact
def test_a_floor_anchored_mid_walk_is_anchored_the_same_in_the_fleet():
    floors = FloorElevations.uniform(3.0, 0, 2)
    walks = simulated(3, 40, seed=8)
    ref, pipes = [], []
    for i, w in enumerate(walks):
        p = PdrPipeline(None, floors, 0)
        out = []
        for k, f in enumerate(w):
            out += p.update(f)
            if i == 1 and k == 149:
                p.anchor_floor(2)
        ref.append(out + p.finish())
        pipes.append(p)
    # the fleet path anchors after the round that took frame 149 (one frame per round here)
    got, members, _ = in_fleet([(w, 0) for w in walks], floors, seed=4, max_join=1, p_take=1.0, anchors=[(1, 150, 2)])
    for a, b in zip(ref, got):
        assert same_events(by_kind(a)[0], by_kind(b)[0])
    assert [m.floor for m in members] == [p.floor for p in pipes]
    assert pipes[1].floor != pipes[0].floor or any(e.floor == 2 for e in by_kind(ref[1])[0])  # the anchor moved it


def test_the_fleet_refuses_a_frame_that_goes_back_in_time_and_keeps_its_state():
    walks = simulated(2, 5)
    fleet = PdrFleet()
    a, b = fleet.member(0), fleet.member(0)
    fleet.run([(a, walks[0][0]), (b, walks[1][0])])
    res = fleet.run([(a, walks[0][0]), (b, walks[1][1])])
    assert isinstance(res[0], ValueError) and "not after the previous sample" in str(res[0])
    assert isinstance(res[1], list)
    assert a.last_time == float(walks[0][0].t[-1])
    p = PdrPipeline()
    p.update(walks[0][0])
    assert same_events(a.update(walks[0][1]), p.update(walks[0][1]))  # and it goes on as if nothing happened
    with pytest.raises(ValueError):
        a.update(walks[0][1])


def test_settings_the_engine_does_not_run_are_refused_naming_the_one_it_runs():
    with pytest.raises(ValueError, match="'norm' step detector.*eval steps"):
        PipelineSettings(detector="vertical")
    from pdr.heading import HeadingSettings

    with pytest.raises(ValueError, match="'decoupled' AHRS.*eval ahrs"):
        PipelineSettings(heading=HeadingSettings(ahrs="madgwick"))


@pytest.mark.bitexact
def test_the_service_gives_a_responder_the_same_poses_alone_or_beside_others():
    """Three walkers in one core (their frames in shared rounds of one fleet) and each alone in
    a core of its own: every pose the same, bit for bit."""
    from service.core.incident_core import CoreSettings, Inbound, IncidentCore
    from service.protocol import wire
    from tests.test_service import _simulated_messages

    cfg, msgs = _simulated_messages()

    rng = np.random.default_rng(11)
    rounds, i = [], 0
    while i < len(msgs):  # rounds of 1-80 messages; a responder alone gets its share of each
        n = int(rng.integers(1, 80))
        rounds.append(msgs[i:i + n])
        i += n

    def poses(keep):
        core = IncidentCore(cfg, CoreSettings())
        out = []
        for r in rounds:
            out += core.feed_round([Inbound(k, key, p, 0.0) for k, key, p in r if keep(key)])
        assert core.counters.errors == 0 and core.fleet is not None
        return sorted((o.message for o in out if isinstance(o.message, wire.Pose)), key=lambda p: (p.responder, p.t))

    together = poses(lambda key: True)
    names = sorted({p.responder for p in together})
    apart = [p for name in names for p in poses(lambda key, name=name: f"/{name}/" in key)]
    assert len(names) == 3 and len(together) == len(apart) > 100
    for p, q in zip(apart, together):
        assert (p.responder, p.t, p.x, p.y, p.floor, p.steps, p.source, p.lat, p.lon) == \
               (q.responder, q.t, q.x, q.y, q.floor, q.steps, q.source, q.lat, q.lon)
        assert np.array_equal(p.cov, q.cov)


_STATE_NOW = FleetRows.__getstate__


def _written_before_heading_bases(rows) -> dict:
    """What a snapshot written before the heading buffers grew in place (cap6, 3b46e2b) held:
    the same state without ``hbases`` and ``hb_end``."""
    d = _STATE_NOW(rows)
    d["layout"] = {k: v for k, v in d["layout"].items() if k != "hb_end"}
    del d["hbases"], d["hb_end"]
    return d


def _written_before_stands(rows) -> dict:
    """What a snapshot written before the compass epochs summed ‖f‖ (the stands of
    :mod:`pdr.heading`) held: the open epoch's state without its last two sums."""
    d = _STATE_NOW(rows)
    shape, dtype, fill = d["layout"]["ep"]
    d["layout"] = {**d["layout"], "ep": ((shape[0] - 2,), dtype, fill)}
    d["ep"] = d["ep"][:, :-2].copy()
    return d


def _written_before_air(rows) -> dict:
    """What a snapshot's rows held before the air guard (:mod:`pdr.air_guard`): no ``air`` rows."""
    d = _STATE_NOW(rows)
    d["layout"] = {k: v for k, v in d["layout"].items() if k != "air"}
    del d["air"]
    return d


def _written_before_release(rows) -> dict:
    """... and before the guard kept the time it last kept air out (11 columns of ``air``)."""
    d = _STATE_NOW(rows)
    shape, kind, fill = d["layout"]["air"]
    d["layout"] = {**d["layout"], "air": ((11,), kind, fill[:11])}
    d["air"] = d["air"][:, :11]
    return d


def _fleet_before_release(fleet) -> dict:
    """... and the fleet then: the guard's 8 numbers pickled, its settings without the release's."""
    d = {k: v for k, v in fleet.__dict__.items() if k != "_designs"}
    d["_air_p"] = fleet._air_p[:8].copy()
    air = object.__new__(type(fleet.settings.air))
    air.__dict__.update({k: v for k, v in fleet.settings.air.__dict__.items() if k not in ("release_s", "still_mps")})
    old = object.__new__(type(d["settings"]))
    old.__dict__.update({**d["settings"].__dict__, "air": air})
    d["settings"] = old
    return d


def _fleet_before_air(fleet) -> dict:
    """... and the fleet itself: no guard parameters, settings without ``air``."""
    d = {k: v for k, v in fleet.__dict__.items() if k not in ("_designs", "_air_p")}
    old = object.__new__(type(d["settings"]))
    old.__dict__.update({k: v for k, v in d["settings"].__dict__.items() if k != "air"})
    d["settings"] = old
    return d


@pytest.mark.bitexact
@pytest.mark.parametrize("writer", ["now", "before heading bases", "before stands", "before the air guard",
                                    "before the air's release"])
def test_a_pickled_fleet_goes_on_like_the_original(writer, monkeypatch):
    """A fleet pickled mid-walk (a service's snapshot: typed lists packed, the rows in use only)
    and read back gives the same events as the original, bit for bit, with its pipelines'
    floor trackers working on views of the restored rows again; so does one written by the
    version before the heading buffers grew in place (a standby or resume across an upgrade)."""
    import pickle

    floors = FloorElevations.uniform(3.0, 0, 2)
    walks = simulated(5, 50, seed=7)
    fleet = PdrFleet(None, floors, capacity=2)
    members = [fleet.member(0) for _ in walks]
    fleet.release(members.pop(3))  # a free slot
    walks.pop(3)
    for k in range(200):
        fleet.run([(m, w[k]) for m, w in zip(members, walks)])
    with monkeypatch.context() as m:
        if writer != "now":
            old = {"before heading bases": _written_before_heading_bases, "before stands": _written_before_stands,
                   "before the air guard": _written_before_air, "before the air's release": _written_before_release}[writer]
            m.setattr(FleetRows, "__getstate__", old)
        if writer == "before the air guard":
            m.setattr(PdrFleet, "__getstate__", _fleet_before_air)
        if writer == "before the air's release":
            m.setattr(PdrFleet, "__getstate__", _fleet_before_release)
        data = pickle.dumps(fleet, protocol=5)
    twin = pickle.loads(data)
    assert twin.rows.ring_t.shape == fleet.rows.ring_t.shape and twin.rows.free == fleet.rows.free
    np.testing.assert_array_equal(twin._air_p, fleet._air_p)  # every number the guard's kernel reads
    for m in twin.members:
        assert m.floor_tracker.rows()[0].base is twin.rows.fs and m.floor_tracker.rows()[1].base is twin.rows.ring_t
    a, b = [[] for _ in walks], [[] for _ in walks]
    for k in range(200, 500):
        for i, ev in enumerate(fleet.run([(m, w[k]) for m, w in zip(members, walks)])):
            a[i] += ev
        for i, ev in enumerate(twin.run([(m, w[k]) for m, w in zip(twin.members, walks)])):
            b[i] += ev
    assert sum(len(e) for e in a) > 100
    # a snapshot from before the air guard restarts the guard: its heights differ by what the
    # original's guard had absorbed before the snapshot (under 1 cm here), the rest is the same
    # (and one from before its release forgets when it last kept air out: no release until it does again)
    tol = 0.01 if writer in ("before the air guard", "before the air's release") else 0.0
    for x, y in zip(a, b):
        assert events_close(x, y, tol)
    assert [m.floor for m in members] == [m.floor for m in twin.members]


@pytest.mark.bitexact
def test_a_crowd_that_leaves_gives_its_rows_back_and_the_fleet_goes_on():
    """Forty members join beside one walker (a flood's admitted ids) and leave: the fleet's rows
    shrink back to their first capacity, the walker's events are those of a pipeline alone,
    and a member that joins afterwards starts as a fresh pipeline in a refilled row."""
    floors = FloorElevations.uniform(3.0, 0, 2)
    walks = simulated(3, 40, seed=9)
    fleet = PdrFleet(None, floors, capacity=2)
    walker = fleet.member(0)
    crowd = [fleet.member(0) for _ in range(40)]
    got = []
    for k in range(150):
        res = fleet.run([(walker, walks[0][k])] + [(m, walks[1 + j % 2][k]) for j, m in enumerate(crowd)])
        got += res[0]
    assert fleet.rows.cap == 64
    for m in crowd[::-1][:20] + crowd[:20]:  # out of order: the top is freed only when all of it is
        fleet.release(m)
    R = fleet.rows
    assert (R.n, R.cap, R.free, len(R.hbufs), len(R.step_times)) == (1, 2, [], 1, 1)
    late = fleet.member(0)
    assert late.slot == 1
    late_got = []
    for k in range(150, 400):
        res = fleet.run([(walker, walks[0][k]), (late, walks[2][k - 150])])
        got, late_got = got + res[0], late_got + res[1]
    got += walker.finish()
    late_got += late.finish()
    for ref, mine in ((alone(walks[0][:400], floors, 0), got), (alone(walks[2][:250], floors, 0), late_got)):
        (sa, ma), (sb, mb) = by_kind(ref), by_kind(mine)
        assert len(sa) > 20 and same_events(sa, sb) and same_events(ma, mb)


@pytest.mark.bitexact
def test_steps_assembled_for_a_round_of_members_equal_each_member_alone():
    """pdr.step_events.assemble_round over many members (heights, height changes, stairs,
    lengths in one pass) gives each member the events it gets assembled alone, bit for bit,
    with steps waiting for their headings, pressure rows or none, and climbs."""
    import dataclasses

    from pdr.events import StepDetection
    from pdr.heading import StepHeadings
    from pdr.step_events import StepAssembler, assemble_round

    rng = np.random.default_rng(7)
    members, rounds = 10, 150
    together = [StepAssembler(PipelineSettings()) for _ in range(members)]
    alone = [StepAssembler(PipelineSettings()) for _ in range(members)]
    t, z = np.full(members, 1000.0), np.zeros(members)
    names = [f.name for f in dataclasses.fields(StepDetection)]
    stairs = 0
    for _ in range(rounds):
        jobs, want = [], []
        for i in range(members):
            if rng.random() < 0.4:
                continue
            n = int(rng.integers(1, 4))
            found = []
            for _ in range(n):
                t[i] += rng.uniform(0.4, 0.7)
                v = {"t": t[i], "t_start": t[i] - 0.5, "a_max": rng.uniform(1, 5), "a_min": rng.uniform(-4, 0),
                     "a_mean": rng.normal(0, 0.3), "a_mean_abs": rng.uniform(0.5, 2)}
                found.append(StepDetection(**{k: float(v.get(k, rng.normal())) for k in names}))
            heads = StepHeadings(np.array([d.t for d in found]), *[rng.normal(0, 1, n) for _ in range(8)])
            z[i] += rng.choice([0.0, 0.17, -0.17, 0.01]) * n  # a climb now and then: stairs
            k = int(rng.integers(0, 4))
            pres = (np.column_stack([np.sort(rng.uniform(t[i] - 3, t[i] + 0.2, k)), z[i] + rng.normal(0, 0.02, k)])
                    if k else np.empty((0, 2)))
            extra = [found[-1]] if rng.random() < 0.2 else []  # one more detected than headed: it waits for the next round
            alone[i].detected(found + extra)
            together[i].detected(found + extra)
            want.append(alone[i].assemble(heads, pres, lambda _t: 0))
            jobs.append((together[i], heads, pres, lambda _t: 0))
        got = assemble_round(jobs)
        for a, b in zip(want, got):
            stairs += sum(e.on_stairs for e in a)
            assert [repr(dataclasses.astuple(e)) for e in a] == [repr(dataclasses.astuple(e)) for e in b]
    assert stairs > 0  # the stairs windows were exercised
