"""Operator actions in the incident core (issue 19): who may act, revoked identities, an audit for
every action, implausible checkpoint fixes taken but flagged, and all of it reproduced bit for
bit from the recorded inputs."""
from __future__ import annotations

import time

import pytest

from service.core.incident_core import Inbound, IncidentCore
from service.core.plausibility import PlausibilitySettings, Reference, judge, semi_major
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.security_util import walking_frames

INC = "demo"


def _imu(frames, received=0.0):
    return [Inbound("imu", wire.key(INC, b.responder, "imu"), wire.encode(b), received) for b in frames]


def _op(actor, received=0.0, **fields):
    fields.setdefault("operator", "alice")
    fields.setdefault("utc", 1.7e9)
    return Inbound("op", wire.key(INC, actor, "op"), wire.encode(wire.OperatorAction(**fields)), received)


def _fix_op(actor, responder, t, x, y, **kw):
    fix = wire.Fix.checkpoint(responder, t, x=x, y=y, floor=0, sigma=1.0)
    return _op(actor, action="fix", responder=responder, fix=wire.encode(fix), **kw)


def _access(**kw):
    return Inbound("access", wire.key(INC, "svc", "access"), wire.encode(wire.Access(**kw)), 0.0)


def _audits(out):
    return [o.message for o in out if isinstance(o.message, wire.Audit)]


def _placed_walker(core, seconds=40.0):
    """ff1 walks; a checkpoint from its own wearable places it at the door after 2 s."""
    frames = walking_frames("ff1", seconds)
    head = [b for b in frames if b.t[-1] <= 1002.0]
    out = core.feed_round(_imu(head))
    door = wire.Fix.checkpoint("ff1", float(head[-1].t[-1]), x=0.0, y=0.0, floor=0, sigma=0.5)
    out += core.feed_round([Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(door), 0.0)])
    out += core.feed_round(_imu(frames[len(head):]))
    assert core.responders["ff1"].tracker.live is not None
    return out


def test_an_operator_fix_further_than_walkable_is_taken_flagged_and_audited():
    core = IncidentCore(default_incident())
    out = _placed_walker(core)
    assert _audits(out) == []  # the door checkpoint after 2 s of walking is plausible: no audit for a device fix
    r = core.responders["ff1"]
    live = r.tracker.live
    applied = r.tracker.fixes_applied
    far = core.feed_round([_fix_op("console-1", "ff1", live.t, live.x + 86.0, live.y)])
    (a,) = _audits(far)
    assert (a.actor, a.operator, a.action, a.outcome, a.responder) == ("console-1", "alice", "fix", "accepted", "ff1")
    assert a.flags == ["implausible_jump"] and a.jump_m > a.walkable_m and a.jump_m == pytest.approx(86.0, abs=1.0)
    assert r.tracker.fixes_applied + r.tracker.fixes_queued == applied + 1  # taken: an authorised operator
    status = core.tick(1.0)
    st = next(o.message for o in status if isinstance(o.message, wire.Status))
    assert st.fixes["flagged"] == 1
    # a fix beside the responder: plausible, not flagged. On a walker without the forged fix: after
    # it, the graph holds a compromise between the door, the steps and the forged fix (it does not
    # stretch the steps to follow an 86 m jump), so no point is beside both the estimate and that fix
    plain = IncidentCore(default_incident())
    _placed_walker(plain)
    now = plain.responders["ff1"].tracker.live
    near = plain.feed_round([_fix_op("console-1", "ff1", now.t, now.x + 1.0, now.y)])
    (b,) = _audits(near)
    assert b.outcome == "accepted" and b.flags == [] and b.jump_m < b.walkable_m


def test_a_device_checkpoint_far_from_the_track_is_flagged_too():
    core = IncidentCore(default_incident())
    _placed_walker(core)
    live = core.responders["ff1"].tracker.live
    bad = wire.Fix.checkpoint("ff1", live.t, x=live.x - 90.0, y=live.y, floor=0, sigma=0.5)
    held, a = _audits(core.feed_round([Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(bad), 0.0)]))
    # the estimator's walk gate holds it out (issue 32), audited with its sender; flagged as well
    assert (held.actor, held.action, held.outcome, held.reason) == ("ff1", "device_fix", "refused", "fix_walk_gate")
    assert (a.actor, a.action, a.outcome, a.reason, a.flags) == ("ff1", "device_fix", "refused", "walk_gate",
                                                                   ["implausible_jump"])


def test_only_authorised_actors_reach_the_graph_and_revoked_identities_nothing():
    core = IncidentCore(default_incident())
    core.feed_round([_access(enforce=True, operators=["console-1", "svc"], revoked=["ff2"])])
    _placed_walker(core)
    r = core.responders["ff1"]
    before = r.tracker.fixes_applied + r.tracker.fixes_queued
    live = r.tracker.live
    out = core.feed_round([_fix_op("mallory", "ff1", live.t, live.x, live.y),  # not an operator of the roster
                           _fix_op("ff1", "ff1", live.t, live.x, live.y),  # a wearable cannot act as an operator
                           _fix_op("console-1", "nobody", live.t, 0.0, 0.0),  # no such responder
                           _op("console-1", action="ack", responder="ff1", alarm="man_down"),
                           _op("console-1", action="evacuate", order="evacuate-1", responders=["ff1"]),
                           _op("svc", action="checkpoint", name="door-7", x=1.0, y=2.0, floor=0)])
    got = [(a.actor, a.action, a.outcome, a.reason) for a in _audits(out)]
    assert got == [("mallory", "fix", "refused", "unauthorised"), ("ff1", "fix", "refused", "unauthorised"),
                   ("console-1", "fix", "refused", "unknown_responder"), ("console-1", "ack", "recorded", None),
                   ("console-1", "evacuate", "recorded", None), ("svc", "checkpoint", "recorded", None)]
    assert r.tracker.fixes_applied + r.tracker.fixes_queued == before  # none reached the graph
    # a revoked wearable: its frames, fixes and presence are refused before any state is made
    ff2 = walking_frames("ff2", 2.0)
    core.feed_round(_imu(ff2) + [Inbound("presence", wire.key(INC, "ff2", "presence"), b"1", 0.0)])
    assert "ff2" not in core.responders and core.unattributed["revoked"] == len(ff2) + 1
    # revoking an operator later: refused from that message on
    core.feed_round([_access(enforce=True, operators=["console-1"], revoked=["console-1"])])
    (a,) = _audits(core.feed_round([_op("console-1", action="ack", responder="ff1", alarm="man_down")]))
    assert (a.outcome, a.reason) == ("refused", "revoked")


def test_without_a_policy_everyone_acts_the_open_demo():
    core = IncidentCore(default_incident())
    _placed_walker(core)
    live = core.responders["ff1"].tracker.live
    (a,) = _audits(core.feed_round([_fix_op("console", "ff1", live.t, live.x, live.y, operator="local")]))
    assert (a.actor, a.operator, a.outcome) == ("console", "local", "accepted")


def test_actions_and_policies_reprocess_bit_for_bit_in_any_rounds():
    frames = walking_frames("ff1", 30.0)
    k = len(frames) // 2
    t = float(frames[k - 1].t[-1])
    items = ([_access(enforce=True, operators=["console-1"], revoked=[])] + _imu(frames[:k])
             + [_fix_op("console-1", "ff1", t, 60.0, 0.0), _fix_op("mallory", "ff1", t, 0.0, 0.0),
                _op("console-1", action="par", order="par-1", responders=["ff1"])] + _imu(frames[k:]))

    def run(size):
        core, out = IncidentCore(default_incident()), []
        for i in range(0, len(items), size):
            out += core.feed_round(items[i:i + size])
        return out

    def poses(out):  # what a pose says (its seq names the newest frame of its round's batch)
        return [(p.t, p.x, p.y, p.floor, p.steps, p.source, p.cov.tobytes()) for p in
                (o.message for o in out) if isinstance(p, wire.Pose)]

    runs = [run(n) for n in (1, 7, len(items))]
    for other in runs[1:]:
        assert poses(other) == poses(runs[0])
        assert [wire.encode(a) for a in _audits(other)] == [wire.encode(a) for a in _audits(runs[0])]
    assert [a.outcome for a in _audits(runs[0])] == ["accepted", "refused", "recorded"]
    assert len(poses(runs[0])) > 20 and poses(runs[0])[-1][1] > 30.0  # the accepted fix at x = 60 m moved the track


def test_plausibility_arithmetic():
    s = PlausibilitySettings(max_speed_mps=3.0, n_sigma=3.0, margin_m=5.0)
    ref = Reference(t=0.0, x=0.0, y=0.0, sigma=0.0)
    v = judge(10.0, 35.0, 0.0, 0.0, [("last_fix", ref)], s)  # 30 m walkable + 5 m margin: just inside
    assert v.walkable_m == pytest.approx(35.0) and not v.implausible
    assert judge(10.0, 35.1, 0.0, 0.0, [("last_fix", ref)], s).implausible
    assert judge(10.0, 0.0, 0.0, 0.0, [], s) is None
    assert semi_major([[4.0, 0.0], [0.0, 1.0]]) == pytest.approx(2.0)
    assert semi_major([[2.0, 1.0], [1.0, 2.0]]) == pytest.approx(3.0 ** 0.5)


def test_operator_action_messages_say_what_is_missing():
    with pytest.raises(ValueError, match="a fix action needs fix"):
        wire.OperatorAction(action="fix", operator="alice", utc=time.time(), responder="ff1")
    with pytest.raises(wire.WireError) as e:
        wire.decode(wire.encode(wire.Access(enforce=True)) .replace(b"enforce", b"enforcX"), expect=wire.Access)
    assert e.value.reason == "schema"


def test_the_core_parses_each_messages_key_once(monkeypatch):
    """Frames, fixes, presence, orders, acknowledgements and actions fed without their key's
    parts (a replay): one parse of the key per message in the core, whichever part takes it
    (the access policy's key names no one: none). The live path, where the shell reads the key
    and the core none: tests/test_key_once.py."""
    from service.protocol import keys

    calls = []
    real = keys._parse_key
    monkeypatch.setattr(keys, "_parse_key", lambda k: calls.append(k) or real(k))
    core = IncidentCore(default_incident())
    frames = walking_frames("ff1", 4.0)
    fix = wire.Fix.checkpoint("ff1", float(frames[5].t[-1]), x=0.0, y=0.0, floor=0, sigma=0.5)
    order = wire.Command(responder="ff1", id="par-1", action="par", issued_at=1.0, issued_by="alice")
    ack = wire.Ack(responder="ff1", id="par-1", action="par", at=2.0)
    items = [*_imu(frames[:6]), Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(fix), 0.0),
             Inbound("presence", wire.key(INC, "ff1", "presence"), b"1", 0.0),
             Inbound("command", wire.key(INC, "ff1", "command"), wire.encode(order), 0.0),
             Inbound("ack", wire.key(INC, "ff1", "ack"), wire.encode(ack), 0.0),
             _op("console", action="ack", responder="ff1", alarm="man_down"), _access(enforce=False),
             *_imu(frames[6:])]
    for item in items:
        core.feed(item)
    assert len(calls) == len(items) - 1 and calls == [i.key for i in items if i.kind != "access"]
    assert core.responders["ff1"].commands["par"]["acked_at"] == 2.0


def test_a_checkpoint_held_out_then_shown_right_by_the_next_is_audited_again_as_taken():
    """Issue 27, point 5, audited: the walk ran 30° off dead reckoning. The first landmark is
    held out by the walk gate (audited refused, counted); the second shows the walk turned, so
    the graph takes both, and the first gets a second audit, ``accepted`` / ``fix_readmitted``,
    naming the same sender, its refusal withdrawn from the counts."""
    import math

    core = IncidentCore(default_incident())
    frames = walking_frames("ff1", 60.0)
    head = [b for b in frames if b.t[-1] <= 1002.0]
    core.feed_round(_imu(head))
    door = wire.Fix.checkpoint("ff1", float(head[-1].t[-1]), x=0.0, y=0.0, floor=0, sigma=0.3)
    core.feed_round([Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(door), 0.0)])
    r = core.responders["ff1"]
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))

    def landmark_after(until):
        core.feed_round(_imu([b for b in frames if until - 20.0 < b.t[-1] <= until]))
        p = r.tracker.live  # dead reckoning: nothing was taken since the door
        fix = wire.Fix.checkpoint("ff1", p.t, x=c * p.x - s * p.y, y=s * p.x + c * p.y, floor=0, sigma=0.3)
        return _audits(core.feed_round([Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(fix), 0.0)])), fix

    first, a = landmark_after(1022.0)
    assert [(x.actor, x.outcome, x.reason) for x in first if x.reason == "fix_walk_gate"] == [
        ("ff1", "refused", "fix_walk_gate")]
    assert r.tracker.fix_rejects == {"walk_gate": 1} and r.tracker.fixes_rejected == 1
    applied = r.tracker.fixes_applied
    second, b = landmark_after(1042.0)
    again = [x for x in second if x.reason == "fix_readmitted"]
    assert [(x.actor, x.outcome, x.t) for x in again] == [("ff1", "accepted", a.t)], second
    assert "fix_walk_gate" not in [x.reason for x in second]  # the second landmark is taken, not held out
    assert r.tracker.fix_rejects == {} and r.tracker.fixes_rejected == 0
    assert r.tracker.fixes_applied == applied + 2
    live = r.tracker.live
    assert math.hypot(live.x - b.x, live.y - b.y) < 1.0  # the live track starts from the second landmark
