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


class RoundIntake:
    """What a worker takes into a round (frames of its shard, then the queued messages)."""

    def __init__(self, core, clock, shard: tuple[int, int], routes, inbox: queue.Queue, max_round: int):
        self.core, self.clock, self.shard, self.routes = core, clock, shard, routes
        self.inbox, self.max_round = inbox, max_round
        self.heard = {"own": 0, "others": 0}  # samples taken from the frames' subscribers, by owner (this worker or not)

    def take_frames(self, limit: int | None) -> list[Inbound]:
        """Frames, then fixes, waiting in zenoh's channels for this worker's responders, each
        through the intake (by key and size, before its payload is copied) and stamped as taken."""
        out: list[Inbound] = []
        for kind, sub, routed in self.routes.subscribers():
            if limit is not None and len(out) >= limit:
                break
            self._take_from(kind, sub, out, limit, routed)
        return out

    def _take_from(self, kind: str, sub, out: list[Inbound], limit: int | None, routed: bool = False) -> None:
        """From one subscriber: a route's samples are this worker's; the incident's wildcard
        (one worker, or the catch-all) gives the ids of its shard that have no route."""
        admit, clock, heard, k, n = self.core.admit, self.clock, self.heard, *self.shard
        routed_keys = self.routes.routed_keys
        while limit is None or len(out) < limit:
            try:
                sample = sub.try_recv()
            except zenoh.ZError:  # undeclared (closing)
                break
            if sample is None:
                break
            key = str(sample.key_expr)
            parts = read_key(key)  # the one reading of this message's key: the intake and the core take its parts
            own = owns(parts, k, n)
            heard["own" if own else "others"] += 1
            if not own or (not routed and key in routed_keys):  # another's, or its route brings it
                continue
            payload = sample.payload
            now = clock()
            if admit(kind, key, len(payload), now, parts) is None:
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
