"""Issue 19 on a real router on loopback: mutual TLS on every link and the roster's access
control. A client without a certificate cannot connect; a wearable's certificate publishes
its own responder's keys and nothing else, and cannot read other responders' tracks; the
attacks of the issue (a forged fix, an impersonating frame, a seq jump, a phantom pose, a
wildcard track query), rerun with TLS on, change no responder's pose; a revoked identity is
refused while the service runs; a name reserved before the router started joins later; a
standalone router from `firetrack certs router-config` enforces the same."""
from __future__ import annotations

import json
import time

import pytest
import zenoh

from service.core.incident_core import Inbound, IncidentCore
from service.protocol import pki, wire
from service.protocol.access import access_message, load_roster, router_config_json5
from service.protocol.incident import default_incident
from service.protocol.session import open_client, open_session
from service.protocol.tls import TlsConfigError
from service.shell.service import IncidentService, ServiceSettings
from tests.security_util import (
    INCIDENT,
    bare_tls_client,
    identity,
    make_pki,
    matched_publisher,
    put_routed,
    secure_service,
    tls_client,
    walking_frames,
)
from tests.zenoh_util import free_port, wait_until

SETTLE_S = 0.5  # s: a declaration reaches the router (the positive controls below prove delivery)


@pytest.fixture(scope="module")
def pkidir(tmp_path_factory):
    return make_pki(tmp_path_factory.mktemp("pki"))


def _put_all(session, items):
    for key, payload in items:
        session.put(key, payload)


def test_without_a_certificate_or_over_plain_tcp_no_client_connects(pkidir, tmp_path):
    with secure_service(pkidir) as (svc, endpoint, tap):
        port = endpoint.rsplit(":", 1)[1]
        with pytest.raises(zenoh.ZError):  # TLS, trusts the CA, presents no certificate
            bare_tls_client(endpoint, pkidir / "ca.crt").close()
        with pytest.raises(ConnectionError):  # plain TCP to the same port
            open_client(f"tcp/127.0.0.1:{port}").close()
        other = make_pki(tmp_path / "other")  # a certificate of another incident's CA, same names
        with pytest.raises(ConnectionError):
            tls_client(endpoint, identity(other, "ff1")).close()
        with pytest.raises(TlsConfigError, match="plain TCP is refused"):  # --tls never dials tcp/
            tls_client(f"tcp/127.0.0.1:{port}", identity(pkidir, "ff1"))
        ok = tls_client(endpoint, identity(pkidir, "ff1"))  # the positive control
        ok.close()
        assert svc.received == {"imu": 0, "fix": 0, "op": 0} and not svc.responders and not tap.items


def test_a_wearable_certificate_publishes_its_own_keys_only_and_reads_no_track(pkidir):
    with secure_service(pkidir) as (svc, endpoint, tap):
        ff1 = tls_client(endpoint, identity(pkidir, "ff1"))
        console = tls_client(endpoint, identity(pkidir, "console-1"))
        try:
            phantom = []
            console.declare_subscriber(wire.key_all(INCIDENT, "pose"),
                                       lambda s: phantom.append(str(s.key_expr)))
            time.sleep(SETTLE_S)
            own = walking_frames("ff1", 4.0)
            other = walking_frames("ff2", 1.0)
            fix_for_ff2 = wire.encode(wire.Fix.checkpoint("ff2", 1000.5, x=40.0, y=40.0))
            fake_pose = wire.encode(wire.Pose(responder="ff2", t=1.0, x=50.0, y=50.0, floor=0, lat=0.0, lon=0.0,
                                              heading_deg=0.0, cov=[[1.0, 0.0], [0.0, 1.0]], steps=1, source="pdr",
                                              seq=0, published_at=time.time()))
            forbidden = [(wire.key(INCIDENT, "ff2", "imu"), wire.encode(b)) for b in other] + [
                (wire.key(INCIDENT, "ff2", "fix"), fix_for_ff2),
                (wire.key(INCIDENT, "ff2", "pose"), fake_pose),
                (wire.key(INCIDENT, "ff1", "pose"), fake_pose),
                (wire.key(INCIDENT, "ff1", "status"), fake_pose),
                (wire.key(INCIDENT, "ff1", "op"), b"x"),
                (wire.key(INCIDENT, "ff1", "truth"), b"x"),
                ("firetrack/other-incident/ff1/imu", wire.encode(own[0])),
            ]
            _put_all(ff1, forbidden)
            pub = ff1.declare_publisher(wire.key(INCIDENT, "ff1", "imu"))
            for b in own:  # after the forbidden ones, on the same link: when these arrived, those would have
                pub.put(wire.encode(b))
            assert wait_until(lambda: svc.received["imu"] >= len(own) and svc.wait_idle(0.2), 20)
            assert svc.received == {"imu": len(own), "fix": 0, "op": 0}
            assert set(svc.responders) == {"ff1"}
            keys = set(tap.keys())
            assert not any(k.startswith("firetrack/demo/ff2/") for k in keys), keys
            assert wire.key(INCIDENT, "ff1", "op") not in keys and wire.key(INCIDENT, "ff1", "truth") not in keys
            # every pose that reached a reader is the service's own (ff1's, from its frames)
            for p in tap.payloads(wire.key(INCIDENT, "ff1", "pose")):
                assert wire.decode(p).x != 50.0
            assert not any("ff2" in k for k in phantom)

            # tracks: its own, yes; another responder's or everyone's, no (the reply never comes)
            mine = [r for r in ff1.get(wire.key(INCIDENT, "ff1", "track"), timeout=3.0) if r.ok is not None]
            assert [str(r.ok.key_expr) for r in mine] == [wire.key(INCIDENT, "ff1", "track")]
            assert list(ff1.get(wire.key(INCIDENT, "ff2", "track"), timeout=1.0)) == []
            assert list(ff1.get(wire.key_all(INCIDENT, "track"), timeout=1.0)) == []
            got = [r for r in console.get(wire.key_all(INCIDENT, "track"), timeout=3.0) if r.ok is not None]
            assert [str(r.ok.key_expr) for r in got] == [wire.key(INCIDENT, "ff1", "track")]
            # nor may it listen to anyone's poses (the subscription is refused at the router)
            heard = []
            ff1.declare_subscriber(wire.key_all(INCIDENT, "pose"), lambda s: heard.append(1))
            time.sleep(SETTLE_S)
            more = walking_frames("ff1", 6.0, t0=1004.0, seq0=len(own))
            for b in more:
                pub.put(wire.encode(b))
            assert wait_until(lambda: svc.responders["ff1"].poses > 0 and len(phantom) > 0, 20)
            assert heard == []
        finally:
            ff1.close()
            console.close()


def test_roles_console_viewer_anchor_publish_only_what_they_may(pkidir):
    with secure_service(pkidir) as (svc, endpoint, tap):
        ff1 = tls_client(endpoint, identity(pkidir, "ff1"))
        sessions = {n: tls_client(endpoint, identity(pkidir, n)) for n in ("console-1", "vic", "a1", "alice")}
        try:
            pub = matched_publisher(ff1, wire.key(INCIDENT, "ff1", "imu"))
            for b in walking_frames("ff1", 2.0):
                pub.put(wire.encode(b))
            assert wait_until(lambda: "ff1" in svc.responders, 10)
            fix = wire.encode(wire.Fix.checkpoint("ff1", 1000.5, x=1.0, y=1.0))

            def op(operator):
                return wire.encode(wire.OperatorAction(action="par", operator=operator, utc=time.time(),
                                                       order="par-1", responders=["ff1"]))
            # refused by the router: a console or viewer publishing a raw fix, a viewer acting, one actor
            # acting on another's key
            sessions["console-1"].put(wire.key(INCIDENT, "ff1", "fix"), fix)
            sessions["vic"].put(wire.key(INCIDENT, "vic", "op"), op("vic"))
            sessions["vic"].put(wire.key(INCIDENT, "ff1", "fix"), fix)
            sessions["alice"].put(wire.key(INCIDENT, "console-1", "op"), op("alice"))
            # an anchor on a wearable's own fix key, or on another anchor's (issue 32)
            sessions["a1"].put(wire.key(INCIDENT, "ff1", "fix"), fix)
            sessions["a1"].put(wire.anchor_fix_key(INCIDENT, "ff1", "a2"), fix)
            # allowed: a console's and an operator's actions on their own keys, an anchor's fix for anyone, on
            # the key that names it
            put_routed(sessions["console-1"], wire.key(INCIDENT, "console-1", "op"), op("bob"))
            put_routed(sessions["alice"], wire.key(INCIDENT, "alice", "op"), op("alice"))
            put_routed(sessions["a1"], wire.anchor_fix_key(INCIDENT, "ff1", "a1"), fix)
            assert wait_until(lambda: svc.received["op"] >= 2 and svc.received["fix"] >= 1 and svc.wait_idle(0.2), 10)
            time.sleep(SETTLE_S)
            assert svc.received["op"] == 2 and svc.received["fix"] == 1
            actors = sorted(k.split("/")[2] for k in tap.keys() if k.endswith("/op"))
            assert actors == ["alice", "console-1"]
        finally:
            ff1.close()
            for s in sessions.values():
                s.close()


def test_the_attacks_of_issue_19_with_tls_on_change_no_pose(pkidir):
    """Forged fix, impersonation, seq jump, phantom pose and a wildcard track read, from a program
    without a certificate and from one holding another responder's (ff2's) certificate, while ff1
    walks: ff1's track is exactly the one its own frames make."""
    frames = walking_frames("ff1", 30.0)
    half = len(frames) // 2
    with secure_service(pkidir) as (svc, endpoint, tap):
        ff1 = tls_client(endpoint, identity(pkidir, "ff1"))
        thief = tls_client(endpoint, identity(pkidir, "ff2"))
        watcher = tls_client(endpoint, identity(pkidir, "console-1"))
        outcomes = {}
        try:
            shown = []
            watcher.declare_subscriber(wire.key_all(INCIDENT, "pose"), lambda s: shown.append(str(s.key_expr)))
            pub = ff1.declare_publisher(wire.key(INCIDENT, "ff1", "imu"))
            for b in frames[:half]:
                pub.put(wire.encode(b))
            assert wait_until(lambda: svc.frames_processed >= half and svc.wait_idle(0.2), 20)
            placed = svc.responders["ff1"].tracker.live
            assert placed is not None  # walking and placed: the attacks have a track to damage

            # 1. no certificate at all: no connection, so nothing to send
            try:
                bare_tls_client(endpoint, pkidir / "ca.crt").close()
                outcomes["no certificate"] = "CONNECTED"
            except zenoh.ZError:
                outcomes["no certificate"] = "connection refused"
            t = float(frames[half - 1].t[-1])
            attacks = {
                "forged fix (86 m)": [(wire.key(INCIDENT, "ff1", "fix"),
                                       wire.encode(wire.Fix.checkpoint("ff1", t, x=placed.x + 86.0, y=placed.y)))],
                "impersonation (another device)": [(wire.key(INCIDENT, "ff1", "imu"), wire.encode(b))
                                                   for b in walking_frames("ff1", 0.2, t0=t + 0.02, device="evil")],
                "seq jump (5 frames, seq 1e9)": [(wire.key(INCIDENT, "ff1", "imu"), wire.encode(b)) for b in
                                                 walking_frames("ff1", 0.5, t0=t + 0.02, seq0=10**9)],
                "phantom pose": [(wire.key(INCIDENT, "ghost", "pose"),
                                  wire.encode(wire.Pose(responder="ghost", t=1.0, x=5.0, y=5.0, floor=0, lat=0.0,
                                                        lon=0.0, heading_deg=0.0, cov=[[1.0, 0.0], [0.0, 1.0]],
                                                        steps=1, source="fused", seq=0, published_at=time.time())))],
            }
            for items in attacks.values():
                _put_all(thief, items)
            wild = list(thief.get(wire.key_all(INCIDENT, "track"), timeout=1.0))
            outcomes["wildcard track query"] = f"{len(wild)} replies"
            for b in frames[half:]:
                pub.put(wire.encode(b))
            assert wait_until(lambda: svc.frames_processed >= len(frames) and svc.wait_idle(0.2), 30)
            r = svc.responders["ff1"]
            keys = set(tap.keys())
            ff1_imu = [wire.decode(p) for p in tap.payloads(wire.key(INCIDENT, "ff1", "imu"))]
            outcomes["forged fix (86 m)"] = ("reached the service" if wire.key(INCIDENT, "ff1", "fix") in keys
                                             or svc.received["fix"] else "refused by the router")
            outcomes["impersonation (another device)"] = ("reached the service" if any(b.device == "evil" for b in ff1_imu)
                                                          else "refused by the router")
            outcomes["seq jump (5 frames, seq 1e9)"] = ("reached the service" if any(b.seq >= 10**9 for b in ff1_imu)
                                                        else "refused by the router")
            outcomes["phantom pose"] = ("reached a console" if any("ghost" in k for k in shown) or
                                        wire.key(INCIDENT, "ghost", "pose") in keys else "refused by the router")
            print("\nissue 19 attacks with --tls:", json.dumps(outcomes, indent=2))
            assert outcomes == {"no certificate": "connection refused", "wildcard track query": "0 replies",
                                **{name: "refused by the router" for name in attacks}}
            # and ff1's track is the one its frames alone make: no restart, no rejects, the same pose bit for bit
            assert r.gate.epoch == 0 and dict(r.gate.counts) == {} and r.tracker.fixes_applied == 0
            core = IncidentCore(default_incident())
            core.feed_round([Inbound("imu", wire.key(INCIDENT, "ff1", "imu"), wire.encode(b), 0.0) for b in frames])
            alone = core.responders["ff1"].tracker.live
            live = r.tracker.live
            assert (live.t, live.x, live.y, live.steps) == (alone.t, alone.x, alone.y, alone.steps)
        finally:
            for s in (ff1, thief, watcher):
                s.close()


def test_a_revoked_identity_is_refused_while_the_service_runs(pkidir, tmp_path):
    d = make_pki(tmp_path / "pki")
    with secure_service(d) as (svc, endpoint, tap):
        ff1, ff2 = (tls_client(endpoint, identity(d, n)) for n in ("ff1", "ff2"))
        console = tls_client(endpoint, identity(d, "console-1"))
        try:
            a, b = walking_frames("ff1", 4.0), walking_frames("ff2", 4.0)
            p1, p2 = (matched_publisher(s, wire.key(INCIDENT, n, "imu")) for s, n in ((ff1, "ff1"), (ff2, "ff2")))
            for x, y in zip(a[:20], b[:20]):
                p1.put(wire.encode(x))
                p2.put(wire.encode(y))
            # these plain publishers do not retransmit: on a loaded machine a frame may not arrive (the gate counts
            # it lost); what this test is about is what the service takes after the revocation, so it counts on
            # what arrived before it rather than on all 40, once the gates hold none of it (frames after a lost one
            # wait for it up to resend_wait_s: counted before that, they were taken after the revocation)
            assert wait_until(lambda: svc.received["imu"] >= 30 and {"ff1", "ff2"} <= set(svc.responders)
                              and svc.wait_idle(0.5) and not any(svc.responders[r].gate.waiting for r in ("ff1", "ff2")),
                              15), (svc.received, svc.frame_accounting())
            n1, n2 = svc.responders["ff1"].gate.accepted, svc.responders["ff2"].gate.accepted
            pki.revoke(d, "ff2")
            pki.revoke(d, "console-1")
            svc.update_access(access_message(load_roster(d / "roster.json")))  # what the roster watcher does
            for x, y in zip(a[20:], b[20:]):
                p1.put(wire.encode(x))
                p2.put(wire.encode(y))
            console.put(wire.key(INCIDENT, "console-1", "op"), wire.encode(wire.OperatorAction(
                action="fix", operator="bob", utc=time.time(), responder="ff1",
                fix=wire.encode(wire.Fix.checkpoint("ff1", 1003.0, x=5.0, y=5.0)))))
            assert wait_until(lambda: svc.responders["ff1"].gate.accepted >= n1 + 15 and svc.received["op"] == 1
                              and svc.core.unattributed["revoked"] >= 15 and svc.wait_idle(0.5), 10)
            assert svc.responders["ff2"].gate.accepted == n2  # nothing of ff2 since the revocation
            assert svc.core.unattributed["revoked"] <= len(b) - 20  # ... every ff2 frame that came was refused
            audits = [wire.decode(p) for k, p in tap.items if k.endswith("/audit")]
            assert [(x.actor, x.outcome, x.reason) for x in audits] == [("console-1", "refused", "revoked")]
            assert svc.responders["ff1"].tracker.fixes_applied == 0  # the fix never came in
            with pytest.raises(pki.PkiError, match="never issued again"):
                pki.issue(d, "wearable", "ff2")
        finally:
            for s in (ff1, ff2, console):
                s.close()


def test_a_reserved_name_joins_mid_incident_and_an_unknown_one_waits_for_a_restart(pkidir, tmp_path):
    d = make_pki(tmp_path / "pki")  # ff9 is reserved, not issued
    with secure_service(d) as (svc, endpoint, tap):
        pki.issue(d, "wearable", "ff9")  # the responder arrives: a certificate for the reserved name
        pki.issue(d, "wearable", "ff10")  # a name the router's rules do not have
        joined = [tls_client(endpoint, identity(d, n)) for n in ("ff9", "ff10")]
        try:
            pub = matched_publisher(joined[0], wire.key(INCIDENT, "ff9", "imu"))  # reserved: routed once issued
            for b in walking_frames("ff9", 1.0):
                pub.put(wire.encode(b))
            for b in walking_frames("ff10", 1.0):  # not in the router's rules: refused there
                joined[1].put(wire.key(INCIDENT, "ff10", "imu"), wire.encode(b))
            assert wait_until(lambda: "ff9" in svc.responders and svc.wait_idle(0.2), 10)
            time.sleep(SETTLE_S)
            assert "ff10" not in svc.responders and not any("/ff10/" in k for k in tap.keys())
        finally:
            for s in joined:
                s.close()
    with secure_service(d) as (svc, endpoint, tap):  # the router restarted with the new roster
        s = tls_client(endpoint, identity(d, "ff10"))
        try:
            pub = matched_publisher(s, wire.key(INCIDENT, "ff10", "imu"))
            for b in walking_frames("ff10", 1.0):
                pub.put(wire.encode(b))
            assert wait_until(lambda: "ff10" in svc.responders, 10)
        finally:
            s.close()


def test_a_standalone_router_from_certs_router_config_enforces_the_same(pkidir):
    """What deploy/ runs: zenohd with the generated config (here the same zenoh, in-process), the
    service joining it as a client (`serve --tls --connect`)."""
    port = free_port()
    text = router_config_json5(load_roster(pkidir / "roster.json"), str(pkidir / "zenohd"), [f"tls/127.0.0.1:{port}"])
    conf = zenoh.Config.from_json5(text)
    router = zenoh.open(conf)
    endpoint = f"tls/127.0.0.1:{port}"
    try:
        svc_session = open_session(None, endpoint, tls=identity(pkidir, "svc"))
        svc = IncidentService(svc_session, default_incident(), ServiceSettings(warm_up=False),
                              access=access_message(load_roster(pkidir / "roster.json")), actor="svc").start()
        ff1 = tls_client(endpoint, identity(pkidir, "ff1"))
        console = tls_client(endpoint, identity(pkidir, "console-1"))
        try:
            poses = []
            console.declare_subscriber(wire.key_all(INCIDENT, "pose"), lambda s: poses.append(str(s.key_expr)))
            time.sleep(SETTLE_S)
            for b in walking_frames("ff2", 1.0):
                ff1.put(wire.key(INCIDENT, "ff2", "imu"), wire.encode(b))
            pub = matched_publisher(ff1, wire.key(INCIDENT, "ff1", "imu"))
            for b in walking_frames("ff1", 8.0):
                pub.put(wire.encode(b))
            assert wait_until(lambda: len(poses) > 0, 20), "no pose reached the console through zenohd"
            assert set(svc.responders) == {"ff1"} and set(poses) == {wire.key(INCIDENT, "ff1", "pose")}
            with pytest.raises(zenoh.ZError):
                bare_tls_client(endpoint, pkidir / "ca.crt").close()
        finally:
            ff1.close()
            console.close()
            svc.close()
            svc_session.close()
    finally:
        router.close()


def test_the_shipped_zenohd_config_is_tls_only_with_mtls_and_default_deny():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "deploy" / "zenohd.json5").read_text()
    zenoh.Config.from_json5(text)  # zenoh's own parser takes it
    body = json.loads("\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//")))
    tls = body["transport"]["link"]["tls"]
    assert body["transport"]["link"]["protocols"] == ["tls"] and tls["enable_mtls"] is True
    assert all(e.startswith("tls/") for e in body["listen"]["endpoints"])
    acl = body["access_control"]
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert all("cert_common_names" in s or s["id"] == "everyone" for s in acl["subjects"])
    everyone = next(p for p in acl["policies"] if p["subjects"] == ["everyone"])
    rules = {r["id"]: r for r in acl["rules"]}
    assert all(rules[r]["messages"] == ["declare_subscriber", "declare_queryable"] for r in everyone["rules"])


def test_a_simulator_publishes_for_its_own_walkers_only_and_replay_and_record_need_a_service_identity(pkidir,
                                                                                                       tmp_path):
    from client.simulate import SimulationPublisher
    from service.cli.record import record, replay
    from service.review.recorder import IncidentRecorder

    with secure_service(pkidir) as (svc, endpoint, tap):
        sim = tls_client(endpoint, identity(pkidir, "sim"))
        try:
            pub = SimulationPublisher(sim, INCIDENT, 2, 50.0, 0, prefix="sim", start_spread_s=0.0)
            pub.run(2.0)
            pub.close()
            for b in walking_frames("ff1", 1.0):  # a simulator is no wearable of the roster
                sim.put(wire.key(INCIDENT, "ff1", "imu"), wire.encode(b))
            assert wait_until(lambda: {"sim-000", "sim-001"} <= set(svc.responders) and svc.wait_idle(0.2), 10)
            time.sleep(SETTLE_S)
            assert set(svc.responders) == {"sim-000", "sim-001"}
        finally:
            sim.close()

        # a recording of ff2 replayed into the secured incident with the service's identity
        path = tmp_path / "ff2.mcap"
        with IncidentRecorder(path, INCIDENT) as rec:
            for i, b in enumerate(walking_frames("ff2", 1.0, t0=2000.0)):
                rec.write(wire.key(INCIDENT, "ff2", "imu"), wire.encode(b), 100.0 + 0.1 * i)
        with pytest.raises(ConnectionError):
            replay(path, endpoint.replace("tls/", "tcp/"), speed=0, quiet=True)
        out = tmp_path / "rec.mcap"
        import threading

        ready, stop = threading.Event(), threading.Event()
        recorder = threading.Thread(target=record, args=(endpoint, INCIDENT, out), daemon=True,
                                    kwargs=dict(stop_event=stop, ready=ready, quiet=True, tls=identity(pkidir, "svc")))
        recorder.start()
        assert ready.wait(10)
        done = replay(path, endpoint, speed=0, quiet=True, tls=identity(pkidir, "svc"), wait_for_subscribers_s=2.0)
        assert done["messages"] == 10
        assert wait_until(lambda: "ff2" in svc.responders and svc.responders["ff2"].gate.accepted == 10, 10)
        time.sleep(SETTLE_S)
        stop.set()
        recorder.join(10)
        from service.review.recorder import read_recording

        assert sum(m.kind == "imu" and m.responder == "ff2" for m in read_recording(out)) == 10


def test_only_consoles_give_orders_and_a_wearable_hears_and_answers_its_own(pkidir):
    from client.wearable import Wearable

    with secure_service(pkidir) as (svc, endpoint, tap):
        s1, s2, console = (tls_client(endpoint, identity(pkidir, n)) for n in ("ff1", "ff2", "console-1"))
        w1 = Wearable(s1, INCIDENT, "ff1")
        try:
            for b in walking_frames("ff1", 1.0):
                w1.send("imu", b)
            assert wait_until(lambda: "ff1" in svc.responders, 10)
            time.sleep(SETTLE_S)

            def order(action, oid, by):
                return wire.encode(wire.Command(responder="ff1", id=oid, action=action, issued_at=time.time(),
                                                issued_by=by))
            s2.put(wire.key(INCIDENT, "ff1", "command"), order("evacuate", "forged-1", "chief"))  # ff2 forges one
            heard_by_ff2 = []
            s2.declare_subscriber(wire.key(INCIDENT, "ff1", "command"), lambda s: heard_by_ff2.append(1))
            time.sleep(SETTLE_S)
            put_routed(console, wire.key(INCIDENT, "ff1", "command"), order("par", "par-7", "alice"))
            assert wait_until(lambda: (svc.responders["ff1"].commands.get("par") or {}).get("acked_at") is not None, 10)
            assert [(c.action, c.id) for c in w1.commands] == [("par", "par-7")]  # the forged order never came
            assert "evacuate" not in svc.responders["ff1"].commands and heard_by_ff2 == []
        finally:
            w1.close()
            for s in (s1, s2, console):
                s.close()


def test_a_phone_gateway_publishes_for_the_rosters_wearables_only(pkidir):
    """The console's phone gateway (role gateway) speaks for every wearable of the roster, as
    the phones it enrols, with their acknowledgements; for a name not in the roster the router
    refuses it, and it cannot give orders or act as an operator."""
    from client.wearable import Wearable

    with secure_service(pkidir) as (svc, endpoint, tap):
        gw = tls_client(endpoint, identity(pkidir, "gw"))
        ff1, ff7 = Wearable(gw, INCIDENT, "ff1"), Wearable(gw, INCIDENT, "ff7")
        try:
            for w in (ff1, ff7):
                for b in walking_frames(w.responder, 1.0):
                    w.send("imu", b)
            assert wait_until(lambda: "ff1" in svc.responders, 10)
            assert ff1.flush(10.0), ff1.delivery()  # the service's Status reached the gateway: acknowledged
            gw.put(wire.key(INCIDENT, "ff1", "command"), wire.encode(wire.Command(
                responder="ff1", id="gw-1", action="evacuate", issued_at=time.time())))
            time.sleep(SETTLE_S)
            assert "ff7" not in svc.responders and svc.responders["ff1"].commands == {}
        finally:
            ff1.close()
            ff7.close()
            gw.close()
