"""A message's key is read once, end to end: at the shell's edge (the subscriber's callback or
the worker's round intake), and its parts carried through the intake's admission to the core."""
from __future__ import annotations

import time

from client.wearable import Wearable
from service.protocol import keys, wire
from service.protocol.incident import default_incident
from service.shell.service import IncidentService, ServiceSettings
from tests.security_util import walking_frames
from tests.zenoh_util import client, router, wait_until


def test_every_message_key_is_read_once_from_the_subscriber_to_the_core(monkeypatch):
    """Frames, the wearable's own fix, an anchor's fix, its presence token, an order, its
    acknowledgement and an operator's action, through a real router and service: the key
    parser runs once per message the core takes, and never in the core (every message arrives
    with its key's parts)."""
    calls: list[str] = []
    real = keys._parse_key
    monkeypatch.setattr(keys, "_parse_key", lambda k: calls.append(k) or real(k))
    session, endpoint = router()
    cfg = default_incident()
    svc = IncidentService(session, cfg, ServiceSettings()).start()
    assert calls == [wire.key(cfg.id, "warm-up", "imu"), wire.key(cfg.id, "warm-up", "fix")]  # its two keys, once each
    calls.clear()  # the service's warm-up core is behind it: from here on, the messages' keys
    taken = []
    feed_round = svc.core.feed_round
    svc.core.feed_round = lambda items, **kw: taken.extend(items) or feed_round(items, **kw)  # a spy: the real core runs
    cl = client(endpoint)
    try:
        w = Wearable(cl, cfg.id, "ff1")
        frames = walking_frames("ff1", 6.0, t0=time.time() - 6.0)
        for b in frames[:10]:
            w.send("imu", b)
        w.send("fix", wire.Fix.checkpoint("ff1", float(frames[9].t[-1]), x=0.0, y=0.0, floor=0, sigma=0.5))
        for b in frames[10:]:
            w.send("imu", b)
        assert wait_until(lambda: svc.frames_processed >= len(frames), 20)  # ff1 is a responder: orders reach it
        cl.put(wire.anchor_fix_key(cfg.id, "ff1", "a1"),
               wire.encode(wire.Fix.checkpoint("ff1", float(frames[-1].t[-1]), x=0.5, y=0.0, floor=0, sigma=0.5)))
        cl.put(wire.key(cfg.id, "ff1", "command"), wire.encode(wire.Command(
            responder="ff1", id="par-1", action="par", issued_at=time.time(), issued_by="alice")))
        cl.put(wire.key(cfg.id, "console", "op"), wire.encode(wire.OperatorAction(
            action="ack", operator="alice", utc=time.time(), responder="ff1", alarm="man_down")))
        assert wait_until(lambda: (svc.responders["ff1"].commands.get("par") or {}).get("acked_at") is not None
                          and any(i.kind == "op" for i in list(taken)), 20)
        w.close()
        assert wait_until(lambda: any(i.kind == "presence" and i.payload == b"0" for i in list(taken)), 10)
        svc.close()
        kinds = {i.kind for i in taken}
        assert {"imu", "fix", "presence", "command", "ack", "op"} <= kinds, kinds
        keyed = [i for i in taken if i.kind != "access"]  # the service's own policy: its key names no one
        assert all(isinstance(i.parts, wire.KeyParts) for i in keyed)  # read at the edge, so never in the core
        assert any(i.parts.sender == "a1" for i in keyed)  # the anchor, from the one reading
        assert sorted(calls) == sorted(i.key for i in keyed)  # one reading per message, none elsewhere
    finally:
        cl.close()
        svc.close()
        session.close()
