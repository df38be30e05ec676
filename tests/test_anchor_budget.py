"""An anchor's fixes go through the intake like every message from the network (issue 32:
budgets per identity): a flood on ``{responder}/fix-{anchor}`` is throttled in the responder's
``anchor`` lane, in the shell's round intake as in the core's own admission."""
from __future__ import annotations

import queue

from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from service.protocol.incident import default_incident
from service.shell.round_intake import RoundIntake
from tests.security_util import walking_frames


class _NoRoutes:
    sharded = False


def test_a_flood_of_anchor_fixes_is_throttled_in_its_lane_by_the_round_intake():
    core = IncidentCore(default_incident())
    core.feed_round([Inbound("imu", wire.key(core.id, "ff2", "imu"), wire.encode(f), 90.0 + i * 0.1)
                     for i, f in enumerate(walking_frames("ff2", 2.0))])  # ff2 is a responder of the core's
    assert "ff2" in core.responders
    inbox: queue.Queue = queue.Queue()
    rounds = RoundIntake(core, clock=lambda: 100.0, shard=(0, 1), routes=_NoRoutes(), inbox=inbox, max_round=10_000)
    key = f"firetrack/{core.id}/ff2/fix-a1"
    for _ in range(6000):  # 6000 fixes in the same instant from one anchor (the burst is 4000)
        inbox.put(("fix", key, b"\x80", wire.read_key(key)))
    items: list = []
    rounds.take_queued(items, wait=0.0)
    assert 0 < len(items) < 6000, f"{len(items)} of 6000 anchor fixes admitted in one instant: no budget applied"
    assert all(i.kind == "fix" and i.parts.sender == "a1" for i in items)
