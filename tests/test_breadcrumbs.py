"""Breadcrumbs (issue 31): an operator marks "beacon dropped here" for a responder; the beacon is
placed at that responder's estimate with its uncertainty, and later scans of it are ``ble`` fixes
for anyone who passes: through the incident core, and as a simulated incident in the fusion."""
from __future__ import annotations

import math

import numpy as np

from service.core.incident_core import Inbound, IncidentCore
from service.core.plausibility import semi_major
from service.fusion import TrackFusion
from service.fusion.fixes.ble import BeaconReading, BleScan, BleSettings, PathLoss
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.test_fusion import no_mag, walk
from tests.test_operator_actions import INC, _audits, _op, _placed_walker


def test_a_dropped_beacon_takes_the_responders_estimate_and_its_scans_become_fixes():
    core = IncidentCore(default_incident())
    _placed_walker(core)
    r = core.responders["ff1"]
    live = r.tracker.live
    out = core.feed_round([_op("console-1", action="beacon", responder="ff1", name="CREW:01")])
    [audit] = _audits(out)
    assert audit.outcome == "accepted" and audit.action == "beacon" and "CREW:01" in audit.detail
    b = core.incident.beacon("crew:01")
    assert (b.x, b.y, b.floor) == (live.x, live.y, live.floor)
    assert b.sigma_m == max(semi_major(live.cov), 0.1) and b.lat is not None
    again = _audits(core.feed_round([_op("console-1", action="beacon", responder="ff1", name="CREW:01")]))
    assert again[0].outcome == "refused" and again[0].reason == "duplicate"
    nobody = _audits(core.feed_round([_op("console-1", action="beacon", responder="ff9", name="CREW:02")]))
    assert nobody[0].outcome == "refused" and nobody[0].reason == "unknown_responder"
    applied = r.tracker.fixes_applied
    scan = wire.Fix(responder="ff1", t=live.t, source="ble", beacons=["CREW:01"], rssi=[-66.0])
    core.feed_round([Inbound("fix", wire.key(INC, "ff1", "fix"), wire.encode(scan), 0.0)])
    assert r.tracker.fixes_applied == applied + 1
    assert core.status_of(r, 0.0).beacons_heard == {"CREW:01": live.t}  # when it was last heard, for the console


def _walker(headings, start, heading_error=0.0, turn_bias=0.0, position_sigma=0.3):
    events, truth = walk(headings, turn_bias=turn_bias)
    truth = truth + np.asarray(start)
    f = TrackFusion(no_mag(display_gain=1.0, ble=BleSettings(offset_sigma_db=0.0)))
    f.start(0.0, start[0], start[1], float(headings[0]) + heading_error, heading_sigma=0.05, position_sigma=position_sigma)
    return f, events, truth


def _drop(headings, start, turn_bias):
    """A responder placed at a door walks and drops a beacon: (where the beacon is, where it was placed, sigma)."""
    f, events, truth = _walker(headings, start, turn_bias=turn_bias)
    for ev in events:
        live = f.add_step(ev)
    return truth[-1], np.array([live.x, live.y]), max(semi_major(live.cov), 0.1)


def simulated_incident(seed: int = 0) -> dict[str, list[float]]:
    """Two responders drop beacons; a third, whose heading drifts, passes both later. Its error
    (m) where it passes each beacon, with and without the scans."""
    rng = np.random.default_rng(seed)
    east, north = np.zeros(40), np.full(20, math.pi / 2)
    drops = [_drop(np.zeros(20), (0.0, 0.0), 0.004), _drop(np.full(20, math.pi / 2), (32.0, 0.0), -0.004)]
    s = BleSettings(offset_sigma_db=0.0)
    errors = {}
    for with_ble in (False, True):
        rng_k = np.random.default_rng(rng.integers(1 << 30))
        f, events, truth = _walker(np.r_[east, north], (0.0, 0.0), heading_error=math.radians(6.0), turn_bias=0.006)
        at_beacon = []
        for k, ev in enumerate(events):
            live = f.add_step(ev)
            readings = []
            for true_xy, placed_xy, sigma in drops:
                if math.hypot(*(truth[k + 1] - true_xy)) < 15.0:
                    model = PathLoss(BeaconReading("b", *true_xy, 1.0, 0, 0.0), s, 0, 1.0)
                    rssi = model.rssi(truth[k + 1])[0] + rng_k.normal(0.0, 4.0)
                    readings.append(BeaconReading(f"b{len(readings)}", *placed_xy, 1.0, 0, rssi, math.nan, sigma))
            if with_ble and readings:
                live = f.add_fix(BleScan(ev.t, tuple(readings), tag_z=1.0)) or live
            for true_xy, _, _ in drops:
                if math.hypot(*(truth[k + 1] - true_xy)) < 0.5:
                    at_beacon.append(math.hypot(live.x - truth[k + 1, 0], live.y - truth[k + 1, 1]))
        errors["with" if with_ble else "without"] = at_beacon
    return errors


def test_a_third_responder_passing_dropped_beacons_is_re_anchored():
    errors = simulated_incident()
    assert len(errors["with"]) == len(errors["without"]) >= 2
    assert max(errors["without"]) > 2.0  # its heading drift has carried it off
    assert all(w < wo for w, wo in zip(errors["with"], errors["without"]))
    assert sum(errors["with"]) < 0.7 * sum(errors["without"])
