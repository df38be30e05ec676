"""Fault injection (issue 20, part 5): a real router and service on loopback, wearables through a
link that can be cut, and the faults of a normal day, each with its figure (printed; run with
``-s`` to see them):

* a flood of hostile messages beside an honest and a bystander wearable;
* wearable outages of 10 s and 40 s, and a wearable killed mid-run and started again;
* an outage zenoh cannot fill, filled by the wearable's own resend (``Status.missing``);
* a router restart (5 s);
* SIGKILL of ``firetrack serve`` mid-walk and a restart on the same endpoint and recording.

The assertions are about what is counted and what the tracks are, never about timing (the
machine is shared); ``firetrack bench faults`` measures the timing figures (pose rate, latency,
memory) at the acceptance's sizes.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

import zenoh

from service.protocol import wire
from service.protocol.incident import default_incident
from service.protocol.session import client_config, free_local_port, router_config
from service.shell.service import IncidentService, ServiceSettings
from tests.faults import (  # noqa: F401
    RouterProcess,
    TcpProxy,
    WalkerWearable,
    hostile_messages,
    reference,
    shut_down,
    walker,
)
from tests.security_util import identity
from tests.zenoh_util import wait_until

CFG = default_incident()


class Watch:
    """Every pose and status of the incident as published (a subscriber on the service's session)."""

    def __init__(self, session):
        self.poses: dict[str, list] = {}
        self.alarms: dict[str, set] = {}
        self.status: dict[str, wire.Status] = {}
        self.history: dict[str, list] = {}  # (time received here, Status)
        self._lock = threading.Lock()
        self._subs = [session.declare_subscriber(wire.key_all(CFG.id, k), self._on) for k in ("pose", "status")]

    def _on(self, sample) -> None:
        msg = wire.decode(sample.payload.to_bytes())
        with self._lock:
            if isinstance(msg, wire.Pose):
                self.poses.setdefault(msg.responder, []).append(msg)
            else:
                self.status[msg.responder] = msg
                self.history.setdefault(msg.responder, []).append((time.time(), msg))
                self.alarms.setdefault(msg.responder, set()).update(msg.alarms)

    def close(self):
        for s in self._subs:
            s.undeclare()


def figure(name: str, **values) -> dict:
    print(f"\nFIGURE {name}: {json.dumps(values, default=str)}")
    return values


def same_track(live, ref) -> float:
    """The largest distance (m) between the live poses and the reference's, pose by pose (each
    at the same time and step count, or inf). Not bit for bit: the PDR pipeline's compass sigma
    differs by ~1e-6 rad between a frame at a time and a catch-up batch (pdr.heading), which
    moves a pose by ~1e-10 m."""
    if [(p.t, p.steps) for p in live] != [(p.t, p.steps) for p in ref]:
        return math.inf
    return max((math.hypot(a.x - b.x, a.y - b.y) for a, b in zip(live, ref)), default=0.0)


def delivery_figures(svc, w: WalkerWearable) -> dict:
    r = svc.responders[w.responder]
    g = r.gate
    dup = g.counts.get("duplicate", 0)
    rejected_other = g.rejected - dup
    return {"sent": w.sent(), "accepted": g.accepted, "lost_counted": g.lost, "gaps": g.gaps, "gap_s": round(g.gap_s, 2),
            "duplicates": dup, "rejected": rejected_other,
            "silent_losses": w.sent() - g.accepted - g.lost - rejected_other, "steps": r.tracker.steps}


# --------------------------------------------------------------------------------------
# Outages of 10 s and 40 s, and a wearable killed mid-run and started again
# --------------------------------------------------------------------------------------
def test_outages_of_10_and_40_s_and_a_killed_wearable_lose_nothing_silently():
    port = free_local_port()
    session = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"]))
    svc = IncidentService(session, CFG, ServiceSettings()).start()
    watch = Watch(session)
    proxies = {r: TcpProxy(port) for r in ("out10", "out40")}
    speed = 2.0  # 20 frames/s of a 2x walk: the outages cover 20 s and 80 s of walking
    walkers = {r: walker(proxies[r].endpoint, r, seed=i, seconds=110.0, speed=speed)
               for i, r in enumerate(("out10", "out40"))}
    killed = None
    try:
        for w in walkers.values():
            w.start()
        ep = f"tcp/127.0.0.1:{port}"
        args = [sys.executable, "-m", "tests.faults", "walker", ep, CFG.id, "killed", "7", "110", str(speed)]
        killed = subprocess.Popen(args, stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
        assert killed.stdout.readline().strip() == "ready"
        time.sleep(8.0)
        for p in proxies.values():
            p.cut()
        time.sleep(4.0)
        killed.kill()  # SIGKILL: no flush, no goodbye
        killed.wait(10)
        steps_before_kill = svc.responders["killed"].tracker.steps
        accepted_before_kill = svc.responders["killed"].gate.accepted
        time.sleep(6.0)
        proxies["out10"].restore()
        time.sleep(6.0)
        lost_contact_seen = "lost_contact" in watch.alarms.get("killed", set())  # 12 s without a frame
        # the killed wearable starts again 12 s later: a new boot, seq from 0, the walk goes on
        skip = int((8.0 + 4.0 + 12.0) * 10 * speed)
        restarted = subprocess.Popen([*args, "--skip", str(skip)], stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
        assert restarted.stdout.readline().strip() == "ready"
        time.sleep(24.0)
        proxies["out40"].restore()
        for w in walkers.values():
            assert w.done.wait(120)
        assert restarted.wait(120) == 0
        figures = {}
        for r, w in walkers.items():
            assert wait_until(lambda: svc.responders[r].gate.accepted + svc.responders[r].gate.lost >= w.sent(), 60)
            report = w.close(10.0)
            svc.wait_idle(10)
            ref, ref_core = reference(CFG, r, w.frames)
            f = delivery_figures(svc, w)
            figures[r] = f = {**f, "reference_steps": ref_core.responders[r].tracker.steps,
                              "wearable_unacknowledged": report["unacknowledged"], "alarms_seen": sorted(watch.alarms[r])}
            figure(f"outage {r}", **f)
            assert f["silent_losses"] == 0 and f["lost_counted"] == 0  # every frame of the outage came after it
            assert f["steps"] == f["reference_steps"] and report["unacknowledged"] == 0
            assert "man_down" not in f["alarms_seen"]
            assert same_track(watch.poses[r], ref) < 1e-6
        k = svc.responders["killed"]
        st = svc.core.status_of(k, time.time())
        f = figure("wearable killed and restarted", steps_before_kill=steps_before_kill, accepted_before_kill=accepted_before_kill,
                   steps_after=st.steps, streams=st.streams, gaps=st.gaps, gap_s=round(st.gap_s, 2), lost=st.lost,
                   alarms_seen=sorted(watch.alarms["killed"]), lost_contact_during_the_pause=lost_contact_seen)
        assert st.streams == 2 and st.gaps >= 1 and st.gap_s > 10.0 and st.steps > steps_before_kill + 50
        assert "man_down" not in watch.alarms["killed"] and lost_contact_seen
        # the kill lost nothing the service had been sent: every frame up to the last one taken was taken
        assert st.lost == 0
    finally:
        for p in (killed,):
            if p is not None and p.poll() is None:
                p.kill()
        shut_down(walkers.values(), proxies.values(), watch, svc, session)


def test_an_outage_zenoh_cannot_fill_is_filled_by_the_wearables_own_resend():
    """A wearable without zenoh's kept frames (a plain publisher: what zenoh drops while the link
    is down is gone for zenoh) loses a 3 s outage unless the service asks for the gap
    (``Status.missing``) and the wearable resends it from its own keep. The same path fills
    the gap a restarted service sees when zenoh's history reply loses the race with the live
    frames (:mod:`service.core.gate`, *Resend*)."""
    port = free_local_port()
    session = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"]))
    svc = IncidentService(session, CFG, ServiceSettings()).start()
    proxy = TcpProxy(port)
    w = walker(proxy.endpoint, "plain", seed=11, seconds=60.0, speed=3.0, zenoh_keep=False)
    try:
        w.start()
        assert wait_until(lambda: "plain" in svc.responders and svc.responders["plain"].gate.accepted > 30, 30, 0.05)
        proxy.cut()
        time.sleep(3.0)
        proxy.restore()
        assert w.done.wait(120)
        assert wait_until(lambda: svc.responders["plain"].gate.accepted + svc.responders["plain"].gate.lost
                          >= w.sent(), 60)
        report = w.close(10.0)
        svc.wait_idle(10)
        _, ref_core = reference(CFG, "plain", w.frames)
        f = figure("outage filled by the wearable's resend", **delivery_figures(svc, w),
                   reference_steps=ref_core.responders["plain"].tracker.steps, resent=report["resent"],
                   unacknowledged=report["unacknowledged"])
        assert f["resent"] > 0 and f["silent_losses"] == 0 and f["lost_counted"] == 0
        assert f["steps"] == f["reference_steps"] and report["unacknowledged"] == 0
    finally:
        if w.report is None:
            w.close(0.0)
        proxy.close()
        svc.close()
        session.close()


# --------------------------------------------------------------------------------------
# A router restart
# --------------------------------------------------------------------------------------
def test_a_router_restart_of_5_s_loses_nothing_silently():
    ep = f"tcp/127.0.0.1:{free_local_port()}"
    router = RouterProcess(ep).start()
    svc_session = zenoh.open(client_config(ep))
    svc = IncidentService(svc_session, CFG, ServiceSettings()).start()
    watch = Watch(svc_session)
    w = walker(ep, "ff1", seed=3, seconds=66.0, speed=3.0)
    try:
        w.start()
        time.sleep(8.0)
        router.kill()
        down = time.monotonic()
        time.sleep(5.0)
        router.start()
        up = time.monotonic()
        behind = w.sent()  # what the service must catch up with
        assert wait_until(lambda: svc.responders["ff1"].gate.accepted >= behind, 60, 0.05)
        recovered = time.monotonic()
        assert w.done.wait(120)
        assert wait_until(lambda: svc.responders["ff1"].gate.accepted + svc.responders["ff1"].gate.lost >= w.sent(), 60)
        report = w.close(10.0)
        svc.wait_idle(10)
        ref, ref_core = reference(CFG, "ff1", w.frames)
        f = figure("router restart", outage_s=round(up - down, 2), **delivery_figures(svc, w),
                   reference_steps=ref_core.responders["ff1"].tracker.steps, unacknowledged=report["unacknowledged"],
                   alarms_seen=sorted(watch.alarms.get("ff1", ())), s_from_restart_to_outage_frames=round(recovered - up, 1),
                   zenoh_missed=svc.missed)
        assert f["silent_losses"] == 0 and f["lost_counted"] == 0
        assert f["steps"] == f["reference_steps"] and "man_down" not in f["alarms_seen"]
        assert same_track(watch.poses["ff1"], ref) < 1e-6
    finally:
        if w.report is None:
            w.close(0.0)
        watch.close()
        svc.close()
        svc_session.close()
        router.stop()


# --------------------------------------------------------------------------------------
# SIGKILL of serve mid-walk, and a restart on the same endpoint and recording
# --------------------------------------------------------------------------------------
def test_serve_killed_mid_walk_resumes_the_track_and_reprocess_equals_the_live_poses(tmp_path):
    serve_killed_and_restarted(tmp_path)


def serve_killed_and_restarted(tmp_path, pki=None) -> dict:
    """A walker on ``firetrack serve`` (with ``pki``: ``serve --tls`` and the walker's own
    wearable certificate); serve is killed with SIGKILL about 36 s into the walk and started
    again 2 s later on the same endpoint and recording. Nothing is lost: the live track ends
    where the uninterrupted run does, the wearable has every frame acknowledged, and
    ``reprocess`` of the recording gives the live poses."""
    from service.review.recorder import read_recording, segment_paths
    from service.review.reprocess import reprocess

    tls = identity(pki, "ff1") if pki is not None else None
    ep = f"{'tls' if pki is not None else 'tcp'}/127.0.0.1:{free_local_port()}"
    rec = tmp_path / "incident.mcap"
    cmd = [sys.executable, "-m", "client.entry", "serve", "--listen", ep, "--record", str(rec), "--no-console"]
    if pki is not None:
        cmd += ["--tls", str(pki / "svc")]
    log = open(tmp_path / "serve.log", "w")
    serve = subprocess.Popen(cmd, stderr=log, stdout=log)
    w = None
    try:
        def up():
            try:
                s = zenoh.open(client_config(ep, tls))
            except Exception:
                return False
            s.close()
            return True
        assert wait_until(up, 60, 0.2)
        time.sleep(1.0)
        w = walker(ep, "ff1", seed=5, seconds=90.0, speed=3.0, tls=tls).start()
        time.sleep(12.0)  # about 36 s of walking, and a few snapshots
        serve.send_signal(signal.SIGKILL)
        serve.wait(10)
        killed_at = time.monotonic()
        time.sleep(2.0)
        serve = subprocess.Popen(cmd, stderr=log, stdout=log)
        assert w.done.wait(120)
        report = w.close(30.0)
        serve.send_signal(signal.SIGINT)
        assert serve.wait(60) == 0
        ref, ref_core = reference(CFG, "ff1", w.frames)
        live = [wire.decode(m.payload) for m in read_recording(rec, kinds=["pose"])]
        last = live[-1]
        same = [p for p in ref if p.t == last.t]
        rp = reprocess(rec, CFG)
        text = (tmp_path / "serve.log").read_text()
        f = figure(f"serve{' --tls' if pki is not None else ''} SIGKILL and restart",
                   segments=[p.name for p in segment_paths(rec)],
                   resumed="resumed incident" in text, live_steps=last.steps, reference_steps=ref[-1].steps,
                   final_distance_to_uninterrupted_m=round(math.hypot(last.x - same[-1].x, last.y - same[-1].y), 3)
                   if same else None, reprocess_max_deviation_m=rp["max_deviation_m"],
                   unmatched_live_poses=rp["responders"]["ff1"]["unmatched_live_poses"],
                   frames_sent=report["frames_sent"], unacknowledged=report["unacknowledged"],
                   acked_seq=report["acked_seq"], resent_on_request=report["resent"],
                   s_killed_to_end=round(time.monotonic() - killed_at, 1))
        # on a failure, what the service said of the frames (rejects, gaps, streams, the resume) goes with it
        said = "\n".join(line for line in text.splitlines() if " WARNING " in line or "resum" in line)[-4000:]
        assert report["unacknowledged"] == 0 and report["flushed"], (report, said)
        assert len(f["segments"]) == 2 and f["resumed"], said
        assert f["live_steps"] == f["reference_steps"], said
        assert same and f["final_distance_to_uninterrupted_m"] < 1.0, said
        assert f["reprocess_max_deviation_m"] == 0.0 and f["unmatched_live_poses"] == 0, \
            (rp["responders"]["ff1"]["worst_pose"], said)
        return f
    finally:
        if serve.poll() is None:
            serve.kill()
        if w is not None and w.report is None:
            w.close(0.0)
        log.close()


# --------------------------------------------------------------------------------------
# A flood beside an honest and a bystander wearable (small: the benchmark runs 100 k)
# --------------------------------------------------------------------------------------
def test_a_flood_is_throttled_and_named_and_the_bystander_tracks_as_before():
    import logging

    port = free_local_port()
    session = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"]))
    svc = IncidentService(session, CFG, ServiceSettings()).start()
    watch = Watch(session)
    ep = f"tcp/127.0.0.1:{port}"
    logged = []
    handler = logging.Handler()
    handler.emit = lambda record: logged.append(len(record.getMessage()))
    logging.getLogger("firetrack.service").addHandler(handler)
    attacker = zenoh.open(client_config(ep))
    honest = walker(ep, "honest", seed=1, seconds=50.0, speed=2.0)
    bystander = walker(ep, "bystander", seed=2, seconds=50.0, speed=2.0)
    try:
        honest.start()
        bystander.start()
        time.sleep(5.0)
        msgs = hostile_messages(20_000, CFG.id, "honest")
        t0 = time.monotonic()
        for i, (key, payload) in enumerate(msgs):  # 20 k in 10 s, none dropped on the way
            attacker.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
            if i % 200 == 199:
                time.sleep(max(0.0, t0 + (i + 1) / 2000.0 - time.monotonic()))
        flood_s = time.monotonic() - t0
        assert bystander.done.wait(60) and honest.done.wait(60)
        assert wait_until(lambda: svc.responders["bystander"].gate.accepted >= bystander.sent(), 30)
        svc.wait_idle(10)
        st_honest = svc.core.status_of(svc.responders["honest"], time.time())
        acct = svc.frame_accounting()
        ref, _ = reference(CFG, "bystander", bystander.frames)
        f = figure("flood (small)", hostile=len(msgs), flood_s=round(flood_s, 1), responders=len(svc.responders),
                   refused_at_intake={k: v for k, v in svc.core.intake.counts.items()},
                   honest_alarms=st_honest.alarms, honest_rejected=st_honest.rejected,
                   flooding_sources=svc.core.flooding_sources(time.time()),
                   bystander=delivery_figures(svc, bystander), log_lines=len(logged), log_bytes=sum(logged),
                   errors=svc.errors, accounting=acct)
        # the bystander: every frame, no reject, its poses exactly those of a run without the flood
        assert f["bystander"]["silent_losses"] == 0 and f["bystander"]["rejected"] == 0 and f["bystander"]["duplicates"] == 0
        assert same_track(watch.poses["bystander"], ref) < 1e-6
        assert "bystander" not in f["flooding_sources"]
        # the flooded key is named, throttled; fresh ids were refused beyond the budget
        assert "flooding" in st_honest.alarms and "honest" in f["flooding_sources"]
        assert acct.get("throttled", 0) > 0 and acct.get("bad_key", 0) == 2000 and acct.get("not_admitted", 0) > 0
        assert len(svc.responders) <= ServiceSettings().core.intake.admit_burst + 30
        assert f["log_bytes"] < 100_000 and svc.errors == 0
    finally:
        logging.getLogger("firetrack.service").removeHandler(handler)
        for w in (honest, bystander):
            if w.report is None:
                w.close(0.0)
        attacker.close()
        watch.close()
        svc.close()
        session.close()


# --------------------------------------------------------------------------------------
# A wearable asked to exit says what it could not deliver
# --------------------------------------------------------------------------------------
def test_a_wearable_that_exits_during_an_outage_says_what_was_not_acknowledged():
    port = free_local_port()
    session = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"]))
    svc = IncidentService(session, CFG, ServiceSettings()).start()
    proxy = TcpProxy(port)
    try:
        a = walker(proxy.endpoint, "a", seed=1, seconds=30.0, speed=4.0).start()
        assert wait_until(lambda: "a" in svc.responders and svc.responders["a"].gate.accepted > 20, 30)
        proxy.cut()
        assert a.done.wait(30)
        report = a.close(flush_s=2.0)  # asked to exit while nobody can hear it
        taken = svc.responders["a"].gate.accepted
        f = figure("exit during an outage", sent=a.sent(), taken_by_service=taken, **report)
        assert report["flushed"] is False and report["unacknowledged"] >= a.sent() - taken > 0
        proxy.restore()
        b = walker(proxy.endpoint, "b", seed=2, seconds=10.0, speed=4.0).start()
        assert b.done.wait(30)
        report_b = b.close(flush_s=15.0)  # asked to exit with the link up: it waits for the last acknowledgement
        figure("exit with the link up", sent=b.sent(), **report_b)
        assert report_b["flushed"] is True and report_b["unacknowledged"] == 0
        assert svc.responders["b"].gate.accepted == b.sent()
    finally:
        proxy.close()
        svc.close()
        session.close()
