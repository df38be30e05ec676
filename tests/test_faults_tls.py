"""The faults of :mod:`tests.test_faults` with mutual TLS on (issue 32, part 5): TLS keeps every
promise plain TCP keeps. The router's access control comes from the incident roster
(:func:`service.protocol.access.access_control`); each wearable speaks with its own certificate.

* outages of 10 s and 40 s: every frame arrives (zenoh's history and recovery, which query the
  wearable's keep and watch its liveliness on ``.../@adv/...`` keys), and the wearable hears its
  acknowledgements (its own Status) and has every frame acknowledged;
* SIGKILL of ``firetrack serve --tls`` mid-walk and a restart: nothing lost, the track ends
  where the uninterrupted run does.

Slow on a loaded machine (a minute or two each): run them one at a time.
"""
from __future__ import annotations

import time

import pytest

from service.protocol.access import access_control, access_message, load_roster
from service.protocol.session import free_local_port, open_session
from service.shell.service import IncidentService, ServiceSettings
from tests.faults import TcpProxy, reference, shut_down, walker
from tests.security_util import identity, make_pki
from tests.test_faults import CFG, Watch, delivery_figures, figure, same_track, serve_killed_and_restarted
from tests.zenoh_util import wait_until


@pytest.fixture(scope="module")
def pkidir(tmp_path_factory):
    return make_pki(tmp_path_factory.mktemp("pki"))


def test_outages_of_10_and_40_s_with_tls_lose_nothing_and_every_frame_is_acknowledged(pkidir):
    port = free_local_port()
    roster = load_roster(pkidir / "roster.json")
    session = open_session([f"tls/127.0.0.1:{port}"], tls=identity(pkidir, "svc"), acl=access_control(roster))
    svc = IncidentService(session, CFG, ServiceSettings(), access=access_message(roster, str(pkidir / "roster.json")),
                          actor="svc").start()
    watch = Watch(session)
    outage = {"ff1": 10.0, "ff2": 40.0}
    proxies = {r: TcpProxy(port) for r in outage}
    speed = 2.0  # 20 frames/s of a 2x walk: the outages cover 20 s and 80 s of walking
    walkers = {r: walker(proxies[r].endpoint.replace("tcp/", "tls/"), r, seed=i, seconds=110.0, speed=speed,
                         tls=identity(pkidir, r)) for i, r in enumerate(outage)}
    try:
        for w in walkers.values():
            w.start()
        time.sleep(8.0)
        for p in proxies.values():
            p.cut()
        cut = time.monotonic()
        for r in sorted(outage, key=outage.get):
            time.sleep(max(0.0, cut + outage[r] - time.monotonic()))
            proxies[r].restore()
        for w in walkers.values():
            assert w.done.wait(120)
        for r, w in walkers.items():
            assert wait_until(lambda: svc.responders[r].gate.accepted + svc.responders[r].gate.lost >= w.sent(), 60)
            report = w.close(15.0)
            svc.wait_idle(10)
            ref, ref_core = reference(CFG, r, w.frames)
            f = figure(f"outage of {outage[r]:.0f} s with TLS ({r})", **delivery_figures(svc, w),
                       reference_steps=ref_core.responders[r].tracker.steps, acked_seq=report["acked_seq"],
                       wearable_unacknowledged=report["unacknowledged"], flushed=report["flushed"],
                       alarms_seen=sorted(watch.alarms.get(r, ())), zenoh_missed=svc.missed)
            assert f["silent_losses"] == 0 and f["lost_counted"] == 0
            assert f["steps"] == f["reference_steps"]
            # the wearable heard its acknowledgements through the router's access control
            assert report["unacknowledged"] == 0 and report["flushed"] and report["acked_seq"] == w.frames[-1].seq
            assert same_track(watch.poses[r], ref) < 1e-6
    finally:
        shut_down(walkers.values(), proxies.values(), watch, svc, session)


def test_serve_tls_killed_mid_walk_loses_nothing(pkidir, tmp_path):
    f = serve_killed_and_restarted(tmp_path, pkidir)
    assert f["unacknowledged"] == 0
