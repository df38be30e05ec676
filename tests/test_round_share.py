"""A worker's round is a cross-section of its responders (issue 29's regression at N = 1000).

With shards by key a worker takes frames from one channel per responder (a route,
:mod:`service.shell.shard_routes`). Drained one route after another, a worker behind its input
filled each round with the first routes' backlogs while the last ones waited; the round
intake now gives every route a fair share of the round. A real router on loopback, the
routes declared as a worker declares them, frames published by a client session.
"""
from __future__ import annotations

import collections
import queue

import zenoh

from service.core.incident_core import IncidentCore
from service.protocol import wire
from service.protocol.incident import default_incident
from service.protocol.keys import read_key
from service.shell.round_intake import RoundIntake
from service.shell.service import ServiceSettings
from service.shell.shard_routes import ShardRoutes
from service.shell.sharding import in_shard
from tests.security_util import walking_frames
from tests.zenoh_util import client, router, wait_until

FRAMES = 60  # per responder, waiting in its route before the worker looks


def _own(n: int) -> list[str]:
    return [r for r in (f"ff{i}" for i in range(40)) if in_shard(r, 0, 2)][:n]


def _waiting_routes(ids: list[str], fix_after: str | None = None):
    """A worker's routes (shard 0 of 2) with FRAMES frames of each responder waiting, and with
    ``fix_after``'s door fix published after its frames."""
    cfg = default_incident()
    rs, endpoint = router()
    worker, pub = client(endpoint), client(endpoint)
    routes = ShardRoutes(worker, cfg.id, ServiceSettings(), (0, 2), on_miss=lambda miss: None)
    arrived = collections.Counter()  # beside the routes on the worker's session: what reached it
    counter = worker.declare_subscriber(f"firetrack/{cfg.id}/*/*", lambda s: arrived.update([1]))
    for r in ids:
        routes.presence(read_key(wire.key(cfg.id, r, "presence")), True, {})
    publishers = {(r, k): pub.declare_publisher(wire.key(cfg.id, r, k), reliability=zenoh.Reliability.RELIABLE)
                  for r in ids for k in ("imu", "fix")}
    assert wait_until(lambda: all(p.matching_status.matching for p in publishers.values()))
    for r in ids:
        for f in walking_frames(r, FRAMES * 0.1, rate=50.0)[:FRAMES]:
            publishers[(r, "imu")].put(wire.encode(f))
    if fix_after is not None:
        publishers[(fix_after, "fix")].put(wire.encode(wire.Fix.checkpoint(fix_after, 1000.0, x=0.0, y=0.0,
                                                                           floor=0, sigma=0.3)))
    assert wait_until(lambda: arrived[1] == len(ids) * FRAMES + (fix_after is not None))
    counter.undeclare()
    core = IncidentCore(cfg)
    intake = RoundIntake(core, clock=lambda: 1000.0, shard=(0, 2), routes=routes, inbox=queue.Queue(),
                         max_round=10_000)
    return (rs, worker, pub), routes, intake


def _close(sessions, routes) -> None:
    routes.close()
    for s in sessions:
        s.close()


def _take_all(intake: RoundIntake, limit: int, expected: int) -> list[list]:
    """Rounds of at most ``limit`` until ``expected`` messages came (bounded in time)."""
    rounds: list[list] = []
    got = 0

    def more() -> bool:
        nonlocal got
        items = intake.take_frames(limit)
        if items:
            rounds.append(items)
            got += len(items)
        return got >= expected

    assert wait_until(more, timeout=20.0), f"{got} of {expected} messages taken"
    return rounds


def test_a_full_round_takes_an_equal_share_of_every_route():
    ids = _own(4)
    sessions, routes, intake = _waiting_routes(ids)
    try:
        assert wait_until(lambda: len(routes.routes) == 4)
        rounds = _take_all(intake, 40, 4 * FRAMES)
        first = collections.Counter(i.parts.responder for i in rounds[0])
        # 10 frames of each (taken one route after another: 40 of the first)
        assert sorted(first.values()) == [10, 10, 10, 10], first
        taken = collections.Counter(i.parts.responder for r in rounds for i in r)
        assert taken == {r: FRAMES for r in ids}
        for r in ids:  # each responder's frames in order, across the rounds
            seqs = [wire.decode(i.payload, expect=wire.ImuBatch).seq for rr in rounds for i in rr
                    if i.parts.responder == r]
            assert seqs == list(range(FRAMES))
    finally:
        _close(sessions, routes)


def test_a_routes_fix_comes_after_the_frames_that_waited_before_it():
    ids = _own(3)
    sessions, routes, intake = _waiting_routes(ids, fix_after=ids[1])
    try:
        assert wait_until(lambda: len(routes.routes) == 3)
        rounds = _take_all(intake, 12, 3 * FRAMES + 1)
        order = [(i.kind, i.parts.responder) for r in rounds for i in r]
        fix_at = order.index(("fix", ids[1]))
        assert order[:fix_at].count(("imu", ids[1])) == FRAMES, "the fix overtook frames sent before it"
    finally:
        _close(sessions, routes)


def test_rounds_that_fill_up_give_every_route_the_same_frames_across_rounds():
    """A worker behind its input: every round fills up before the channels are empty. The room
    the first pass leaves (6 frames of 30 over 8 routes: 3 each, then 2 more for three routes)
    goes to the routes in turn across rounds, so no route gets more than the others, give or
    take one pass's share. Starting each round one route further, as before, gave the extra
    to nearly the same routes round after round (after 2 rounds: 6 to 10 frames)."""
    from service.shell.round_intake import ROUTE_SHARE_MIN

    ids = _own(8)
    sessions, routes, intake = _waiting_routes(ids)
    try:
        assert len(ids) == 8 and wait_until(lambda: len(routes.routes) == 8)
        taken = collections.Counter({r: 0 for r in ids})
        for k in range(FRAMES * 8 // 30 - 1):  # every channel still holds frames after each of these
            items = intake.take_frames(30)
            assert len(items) == 30, (k, len(items))
            taken.update(i.parts.responder for i in items)
            assert max(taken.values()) - min(taken.values()) <= ROUTE_SHARE_MIN, (k, taken)
    finally:
        _close(sessions, routes)
