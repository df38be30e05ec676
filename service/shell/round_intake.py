"""What a worker takes into a round: frames from the subscribers' channels (its shard only),
and the queued fixes, orders and actions, waiting at most a bound.

A mixin of :class:`service.shell.service.IncidentService`.
"""
from __future__ import annotations

import logging
import queue

import zenoh

from service.core.incident_core import Inbound

log = logging.getLogger("firetrack.service")


class RoundIntake:
    """What a worker takes into a round (frames of its shard, then the queued messages)."""

    def _take_frames(self, limit: int | None) -> list[Inbound]:
        """Frames, then fixes, waiting in zenoh's channels for this worker's responders, each
        through the intake (by key and size, before its payload is copied) and stamped as taken."""
        out: list[Inbound] = []
        for kind, sub in (("imu", self._imu), ("fix", self._fix)):
            if sub is None:
                continue
            self._take_from(kind, sub, out, limit)
        return out

    def _take_from(self, kind: str, sub, out: list[Inbound], limit: int | None) -> None:
        admit, clock, mine = self.core.admit, self.clock, self._mine
        while limit is None or len(out) < limit:
            try:
                sample = sub.try_recv()
            except zenoh.ZError:  # undeclared (closing)
                break
            if sample is None:
                break
            key = str(sample.key_expr)
            if not mine(key):
                continue
            payload = sample.payload
            now = clock()
            if admit(kind, key, len(payload), now) is None:
                out.append(Inbound(kind, key, payload.to_bytes(), now))

    def _take_queued(self, items: list[Inbound], wait: float) -> tuple[int, int, bool]:
        """Append what the callbacks queued to ``items``, waiting up to ``wait`` s for the
        first. Returns how many queue entries were taken, how many were ticks, and whether one
        asked the worker to stop (the frames still in the channel are then taken too)."""
        try:
            pending = [self._queue.get(timeout=wait) if wait > 0 else self._queue.get_nowait()]
        except queue.Empty:
            return 0, 0, False
        while len(items) + len(pending) < self.settings.max_round:
            try:
                pending.append(self._queue.get_nowait())
            except queue.Empty:
                break
        stop = None in pending
        ticks = 0
        for p in pending:
            if p is None:
                continue
            if p[0] == "tick":
                ticks += 1
            elif p[0] in ("command", "ack", "op"):  # from the network: through the intake like frames
                now = self.clock()
                if self.core.admit(p[0], p[1], len(p[2]), now) is None:
                    items.append(Inbound(*p, now))
            else:  # presence (liveliness), access (this process's own policy)
                items.append(Inbound(*p, self.clock()))
        if stop:
            items += self._take_frames(None)
        return len(pending), ticks, stop
