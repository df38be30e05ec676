"""Who may send which fix (issue 32, part 2), in the incident core and the router's rules: an
anchor's key names it and carries its own UWB ranges only; with access enforced a wearable
places itself only at a surveyed checkpoint, at the config's position; every refusal is
counted and audited with the identity that sent it, also for a fix held for a responder that
has not spoken yet. The same on a real TLS router: tests/test_attacks_tls.py."""
from __future__ import annotations

import pytest

from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from service.protocol.access import Roster, access_control
from service.protocol.incident import UwbAnchor, default_incident
from tests.security_util import walking_frames

CFG = default_incident().model_copy(update={"uwb_anchors": [UwbAnchor(id="a1", x=0.0, y=0.0, z=1.0)]})
CP = CFG.checkpoints[0]


def test_an_anchors_key_names_it_and_parses_as_a_fix():
    k = wire.anchor_fix_key("demo", "ff2", "a1")
    assert k == "firetrack/demo/ff2/fix-a1" and wire.parse_key(k) == ("demo", "ff2", "fix")
    assert wire.fix_sender(k) == "a1" and wire.fix_sender(wire.key("demo", "ff2", "fix")) is None
    with pytest.raises(ValueError):
        wire.parse_key("firetrack/demo/ff2/fix-")  # no anchor named
    with pytest.raises(ValueError):
        wire.anchor_fix_key("demo", "ff2", "a/1")


def test_the_router_lets_an_anchor_put_on_its_own_fix_keys_only():
    roster = Roster(incident="demo")
    for role, name in (("anchor", "a1"), ("anchor", "a2"), ("wearable", "ff2")):
        roster.add(name, role)
    acl = access_control(roster)
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["anchor-a1"]["key_exprs"] == ["firetrack/demo/*/fix-a1"] and rules["anchor-a1"]["messages"] == ["put"]
    policy = next(p for p in acl["policies"] if p["id"] == "anchor-a1")
    assert policy["rules"] == ["anchor-a1"]
    subject = next(s for s in acl["subjects"] if s["id"] == "anchor-a1")
    assert subject["cert_common_names"] == ["a1"]
    # nobody else puts on */fix: the wearable's own fix key is its own rule
    assert not any("firetrack/demo/*/fix" in r["key_exprs"] for r in acl["rules"] if r["id"] != "service-all")


def _core(enforce: bool) -> tuple[IncidentCore, float]:
    core = IncidentCore(CFG)
    core.feed(Inbound("access", wire.key(CFG.id, "svc", "access"),
                      wire.encode(wire.Access(enforce=enforce, operators=["svc"])), 0.0))
    frames = walking_frames("ff2", 4.0)
    core.feed_round([Inbound("imu", wire.key(CFG.id, "ff2", "imu"), wire.encode(f), 1000.0 + i * 0.1)
                     for i, f in enumerate(frames)])
    return core, float(frames[-1].t[-1])


def _refusals(out) -> list[tuple[str, str]]:
    return [(o.message.actor, o.message.reason) for o in out
            if isinstance(o.message, wire.Audit) and o.message.outcome == "refused"]


def test_an_anchor_sends_its_own_ranges_only_and_each_refusal_names_it():
    core, t = _core(enforce=False)  # by role even in the open demo: the key says who sent it
    a1 = wire.anchor_fix_key(CFG.id, "ff2", "a1")
    out = []
    for fix in (wire.Fix.checkpoint("ff2", t, x=100.0, y=100.0, sigma=0.01),
                wire.Fix.gnss("ff2", t, lat=49.46, lon=11.11, accuracy=1.0),
                wire.Fix.uwb("ff2", t, anchor="A9", range=3.0, sigma=0.1)):
        out += core.feed(Inbound("fix", a1, wire.encode(fix), 1100.0))
    out += core.feed(Inbound("fix", a1, b"\x93not a fix", 1100.0))
    assert _refusals(out) == [("a1", "fix_not_an_anchor_fix"), ("a1", "fix_not_an_anchor_fix"),
                              ("a1", "fix_wrong_anchor"), ("a1", "fix_msgpack")]
    st = core.status_of(core.responders["ff2"], 1100.5)
    assert st.rejected["fix_not_an_anchor_fix"] == 2 and st.rejected["fix_wrong_anchor"] == 1
    assert "fixes_refused" in st.alarms
    assert core.responders["ff2"].tracker.fixes_applied == 0


def test_a_wearable_places_itself_only_at_a_surveyed_checkpoint_with_access_enforced():
    core, t = _core(enforce=True)
    own = wire.key(CFG.id, "ff2", "fix")
    out = core.feed(Inbound("fix", own, wire.encode(wire.Fix.checkpoint("ff2", t, x=5.0, y=0.0, sigma=0.5)), 1100.0))
    assert _refusals(out) == [("ff2", "fix_unsurveyed_checkpoint")]
    # a named checkpoint is placed where the config says, whatever position and sigma the message claims
    named = wire.Fix.checkpoint("ff2", t, name=CP.name, x=CP.x + 40.0, y=CP.y, sigma=0.01, floor=3)
    out = core.feed(Inbound("fix", own, wire.encode(named), 1100.0))
    assert not _refusals(out)
    taken = core.responders["ff2"].last_checkpoint  # what went to the tracker
    assert (taken.x, taken.y, taken.sigma) == (CP.x, CP.y, CP.sigma_m)


def test_the_open_demo_still_takes_a_wearables_checkpoint_at_x_y():
    core, t = _core(enforce=False)
    out = core.feed(Inbound("fix", wire.key(CFG.id, "ff2", "fix"),
                            wire.encode(wire.Fix.checkpoint("ff2", t, x=5.0, y=0.0, sigma=0.5)), 1100.0))
    assert not _refusals(out) and (core.responders["ff2"].last_checkpoint.x, core.responders["ff2"].last_checkpoint.y) == (5.0, 0.0)


def test_a_held_fix_keeps_its_sender_and_an_unknown_id_is_audited_with_it():
    core = IncidentCore(CFG)
    out = core.feed(Inbound("fix", wire.anchor_fix_key(CFG.id, "ff3", "a1"),
                            wire.encode(wire.Fix.checkpoint("ff3", 1000.0, x=1.0, y=1.0)), 100.0))
    out += core.feed(Inbound("fix", wire.anchor_fix_key(CFG.id, "ghost", "a1"),
                             wire.encode(wire.Fix.uwb("ghost", 1000.0, anchor="a1", range=2.0, sigma=0.1)), 100.0))
    assert not _refusals(out) and not core.responders  # held: no responder made for a fix
    frames = walking_frames("ff3", 1.0)  # ff3 speaks: its held fix is judged by who sent it
    out = core.feed_round([Inbound("imu", wire.key(CFG.id, "ff3", "imu"), wire.encode(f), 101.0 + i * 0.1)
                           for i, f in enumerate(frames)])
    out += core.tick(120.0)  # the ghost's fix waited long enough
    out += core.feed(Inbound("imu", wire.key(CFG.id, "ff3", "imu"), wire.encode(frames[-1]), 120.0))
    assert ("a1", "fix_not_an_anchor_fix") in _refusals(out) and ("a1", "fix_unknown_responder") in _refusals(out)
    assert sorted(core.responders) == ["ff3"]


def test_a_snapshot_from_before_senders_were_kept_restores():
    """A snapshot of the core before issue 32's fields (a held fix as a pair, a responder with
    no ``fix_senders``/``last_fix_refused``, a tracker with no ``held_out``) restores with them
    empty, and the held fix is still judged as the wearable's own."""
    core, t = _core(enforce=False)
    core.feed(Inbound("fix", wire.key(CFG.id, "ff3", "fix"),
                      wire.encode(wire.Fix.checkpoint("ff3", 1000.0, x=1.0, y=1.0)), 1100.0))
    r = core.responders["ff2"]
    for name in ("fix_senders", "last_fix_refused"):
        delattr(r, name)
    del r.tracker.held_out
    core.fixes.held = {rid: [(received, fix) for received, fix, _ in v] for rid, v in core.fixes.held.items()}
    core.roster.blobs.clear()
    old = IncidentCore.restore(core.snapshot(), CFG)
    r = old.responders["ff2"]
    assert r.fix_senders == {} and r.last_fix_refused == float("-inf") and len(r.tracker.held_out) == 0
    assert [(a, f.x) for _, f, a in old.fixes.held["ff3"]] == [(None, 1.0)]
    out = old.feed(Inbound("fix", wire.anchor_fix_key(CFG.id, "ff2", "a1"),
                           wire.encode(wire.Fix.gnss("ff2", t, lat=49.46, lon=11.11, accuracy=1.0)), 1101.0))
    assert _refusals(out) == [("a1", "fix_not_an_anchor_fix")] and "fixes_refused" in old.status_of(r, 1101.5).alarms
