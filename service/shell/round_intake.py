"""What a worker takes into a round: frames from the subscribers' channels (its shard only),
and the queued fixes, orders and actions, waiting at most a bound.

Held by :class:`service.shell.service.IncidentService` (``svc.rounds``); the worker thread is
its only caller.
"""
from __future__ import annotations

import logging
import queue

import zenoh

from service.core.incident_core import Inbound
from service.protocol.keys import read_key
from service.shell.sharding import owns

log = logging.getLogger("firetrack.service")

ROUTE_SHARE_MIN = 2  # frames a route may give a round in one pass, at least (service.shell.shard_routes)


def _received(sub) -> list:
    """Every sample waiting in a subscriber's channel (none once it is undeclared)."""
    got = []
    while True:
        try:
            sample = sub.try_recv()
        except zenoh.ZError:
            return got
        if sample is None:
            return got
        got.append(sample)


class RoundIntake:
    """What a worker takes into a round (frames of its shard, then the queued messages)."""

    def __init__(self, core, clock, shard: tuple[int, int], routes, inbox: queue.Queue, max_round: int):
        self.core, self.clock, self.shard, self.routes = core, clock, shard, routes
        self.inbox, self.max_round = inbox, max_round
        self.heard = {"own": 0, "others": 0}  # samples taken from the frames' subscribers, by owner (this worker or not)
        self._turn = 0  # the route the next round starts at (see _take_routes)

    def take_frames(self, limit: int | None) -> list[Inbound]:
        """Frames, then fixes, waiting in zenoh's channels for this worker's responders, each
        through the intake (by key and size, before its payload is copied) and stamped as taken:
        the incident's wildcard (one worker, or the catch-all), then a fair share of every route
        (:meth:`_take_routes`)."""
        out: list[Inbound] = []
        for kind, sub in self.routes.wildcards():
            if limit is not None and len(out) >= limit:
                break
            self._take_from(kind, sub, out, limit)
        routes = self.routes.route_pairs()
        if routes and (limit is None or len(out) < limit):
            self._take_routes(routes, out, limit)
        return out

    def _take_routes(self, routes: list, out: list[Inbound], limit: int | None) -> None:
        """A round is a cross-section of the worker's responders, not a run of a few: in each
        pass every route gives at most an equal share of the room left (at least
        ``ROUTE_SHARE_MIN`` frames), until the round is full or every channel is empty. Drained
        one route after another instead, a worker behind its input filled its rounds with the
        backlogs of the first routes (their frames then ran a responder at a time,
        ``max_coalesce`` at once, not a column of the fleet) while the last routes waited rounds
        for their turn (issue 29: N = 1000 fell to a fifth of its throughput, and the last
        responders' frames were lost).

        The room the first pass leaves (less than one share per route) goes to the routes in
        turn, and a round that fills up mid-pass hands the turn on to the route after the last
        one it took from: across rounds, every route gets the same frames, give or take one
        pass's share. Starting each round only one route further, as before, gave a full round
        of 526 routes (5000 frames, 9 each) 2 more to the same 133 routes round after round:
        22 % more frames for a quarter of the responders while the worker was behind (issue 29,
        ``bench --responders 1050 --drill``). A round that empties every channel starts the
        next one route further.

        A route's fixes come after the frames that waited before them: a fix found in its
        channel first takes the rest of the route's frames (fixes are few, so the round's
        bound is passed by at most one route's channel)."""
        n = len(routes)
        start = self._turn % n
        order = routes[start:] + routes[:start]
        self._turn = start + 1  # unless the round fills up (below)
        while limit is None or len(out) < limit:
            before = len(out)
            share = None if limit is None else max(ROUTE_SHARE_MIN, (limit - len(out)) // n)
            for i, (imu, fix) in enumerate(order):
                if limit is not None and len(out) >= limit:
                    self._turn = start + i  # the next round goes on from the first route this pass left out
                    return
                emptied = self._take_from("imu", imu, out, None if share is None else len(out) + share, True)
                fixes = _received(fix)
                if fixes:
                    if not emptied:  # the frames sent before these fixes go first
                        self._take_from("imu", imu, out, None, True)
                    for sample in fixes:
                        self._admit("fix", sample, out, True)
            if limit is None or len(out) == before:
                return
        self._turn = start  # the pass took exactly the room left: the next one starts where it did

    def _take_from(self, kind: str, sub, out: list[Inbound], limit: int | None, routed: bool = False) -> bool:
        """From one subscriber, until ``out`` holds ``limit`` items; True when its channel was
        found empty (or closed)."""
        while limit is None or len(out) < limit:
            try:
                sample = sub.try_recv()
            except zenoh.ZError:  # undeclared (closing)
                return True
            if sample is None:
                return True
            self._admit(kind, sample, out, routed)
        return False

    def _admit(self, kind: str, sample, out: list[Inbound], routed: bool) -> None:
        """One sample through the intake: a route's samples are this worker's; the incident's
        wildcard (one worker, or the catch-all) gives the ids of its shard that have no route."""
        key = str(sample.key_expr)
        parts = read_key(key)  # the one reading of this message's key: the intake and the core take its parts
        own = owns(parts, *self.shard)
        self.heard["own" if own else "others"] += 1
        if not own or (not routed and key in self.routes.routed_keys):  # another's, or its route brings it
            return
        payload = sample.payload
        now = self.clock()
        if self.core.admit(kind, key, len(payload), now, parts) is None:
            out.append(Inbound(kind, key, payload.to_bytes(), now, parts))

    def take_queued(self, items: list[Inbound], wait: float) -> tuple[int, int, bool]:
        """Append what the callbacks queued to ``items``, waiting up to ``wait`` s for the
        first. Returns how many queue entries were taken, how many were ticks, and whether one
        asked the worker to stop (the frames still in the channel are then taken too)."""
        try:
            pending = [self.inbox.get(timeout=wait) if wait > 0 else self.inbox.get_nowait()]
        except queue.Empty:
            return 0, 0, False
        while len(items) + len(pending) < self.max_round:
            try:
                pending.append(self.inbox.get_nowait())
            except queue.Empty:
                break
        stop = None in pending
        ticks = 0
        for p in pending:
            if p is None:
                continue
            kind, key, payload, parts = p  # parts: the key as the callback read it (None: this process's own)
            if kind == "tick":
                ticks += 1
            elif kind in ("command", "ack", "op", "fix"):  # from the network (a fix here: an anchor's): through the
                # intake like frames, each in its sender's lane (service.core.intake)
                now = self.clock()
                if self.core.admit(kind, key, len(payload), now, parts) is None:
                    items.append(Inbound(kind, key, payload, now, parts))
            else:  # presence (liveliness), access (this process's own policy)
                if kind == "presence" and self.routes.sharded:  # one of this worker's own: its route
                    self.routes.presence(parts, payload == b"1", self.core.responders)
                items.append(Inbound(kind, key, payload, self.clock(), parts))
        if stop:
            items += self.take_frames(None)
        return len(pending), ticks, stop
