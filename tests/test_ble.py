"""BLE beacons: the IPIN loader's BLE4 lines, the ``ble`` fix (path-loss factor, robust to a
wild reading), the survey check finding swapped identities, the wire and the incident config."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pdr.io import load_ipin
from pdr.recording import BeaconReadings, Landmarks, Recording
from service.fusion import FusionSettings, TrackFusion
from service.fusion.fixes.ble import BeaconReading, BleScan, BleSettings, PathLoss, to_local
from service.protocol import wire
from service.protocol.incident import IncidentConfigError, default_incident, incident_from_dict
from service.protocol.messages import ble_scans
from service.review.ble_survey import SurveyEntry, check_survey, config_beacons
from tests.test_fusion import no_mag, walk
from tests.test_io import ipin_text, write

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ipin2023"
REAL_WALK = DATA / "IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"


# ------------------------------------------------------------------ loader


def test_loader_reads_ble4_lines_of_a_small_log(tmp_path):
    text = ipin_text().replace("iBeacon;BE:AC:20:23:00:01;-90;0;", "iBeacon;be:ac:20:23:00:07;-61;-59;", 1)
    text += "BLE4;1.5;iBeacon;BE:AC:20:23:00:02\n"  # no RSSI: skipped, with a warning
    text += "ACCE;2.5;5002.5;0.1;0.2;9.8;3\n"
    rec = load_ipin(write(tmp_path / "log.txt", text))
    b = rec.ble
    assert len(b) == 10 and b.ids() == ["BE:AC:20:23:00:01", "BE:AC:20:23:00:07"]
    offset = rec.meta["app_to_sensor_offset_s"]
    assert b.t[0] == pytest.approx(0.1040 + offset)  # app clock -> the sensor clock
    assert np.all(np.diff(b.t) >= 0)
    seven = b.beacon == "BE:AC:20:23:00:07"
    assert b.rssi[seven].tolist() == [-61.0] and b.tx_power[seven].tolist() == [-59.0]
    assert np.isnan(b.tx_power[~seven]).all() and (b.rssi[~seven] == -90.0).all()  # Power 0: unknown
    assert any("BLE4 line(s)" in w and "skipped" in w for w in rec.warnings)


@pytest.mark.skipif(not REAL_WALK.exists(), reason=f"IPIN walk not present at {REAL_WALK}")
def test_loader_on_a_real_walk():
    rec = load_ipin(REAL_WALK)
    b = rec.ble
    assert len(b) == rec.meta["line_counts"]["BLE4"] > 500
    assert len(b.ids()) == 6 and all(i.startswith("BE:AC:20:23:00:0") for i in b.ids())
    assert rec.acc.t[0] - 10.0 < b.t[0] and b.t[-1] < rec.acc.t[-1] + 10.0  # on the device clock
    assert -110.0 < b.rssi.min() and b.rssi.max() < -30.0


# ------------------------------------------------------------------ the factor


def _scan(t, beacon_xy, truth_xy, s: BleSettings, noise_db=0.0, rssi=None):
    reading = BeaconReading("B1", beacon_xy[0], beacon_xy[1], 1.0, 0, 0.0)
    model = PathLoss(reading, s, 0, 1.0)
    level = model.rssi(truth_xy)[0] + noise_db if rssi is None else rssi
    return BleScan(t, (BeaconReading("B1", beacon_xy[0], beacon_xy[1], 1.0, 0, level),), tag_z=1.0)


def _fusion():
    return TrackFusion(no_mag(display_gain=1.0, ble=BleSettings(offset_sigma_db=0.0)))


def test_a_walker_passing_a_beacon_is_pulled_to_it():
    """The dead reckoning starts 4 m off; scans of a beacon the walker passes under pull it back."""
    events, truth = walk(np.zeros(40))
    beacon = (16.0, 0.0)
    s = BleSettings()
    rng = np.random.default_rng(3)
    errors = {}
    for with_ble in (False, True):
        f = _fusion()
        f.start(0.0, 0.0, 4.0, 0.0, heading_sigma=0.02, position_sigma=5.0)
        for k, ev in enumerate(events):
            live = f.add_step(ev)
            near = math.hypot(*(truth[k + 1] - beacon)) < 12.0
            if with_ble and near:  # scans weaker than min_rssi_dbm are refused (ble_weak), the others taken
                taken = f.add_fix(_scan(ev.t, beacon, truth[k + 1], s, noise_db=rng.normal(0, 3.0)))
                live = taken or live
        errors[with_ble] = math.hypot(live.x - truth[-1, 0], live.y - truth[-1, 1])
    assert f.rejected["ble_weak"] > 0 and sum(e.kind == "accepted" for e in f.events) >= 5
    assert errors[False] > 3.5
    assert errors[True] < 0.5 * errors[False]


def test_a_wildly_wrong_rssi_does_not_move_the_walker_far():
    """One scan claiming the beacon is at arm's length when it is 15 m away: the Cauchy kernel
    bounds its pull to a fraction of what a Gaussian would do."""
    events, truth = walk(np.zeros(20))
    beacon = (truth[-1, 0], 15.0)
    moved = {}
    for kernel in ("cauchy", "gaussian"):
        s = BleSettings(kernel=kernel, offset_sigma_db=0.0)
        f = TrackFusion(no_mag(display_gain=1.0, ble=s))
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.02, position_sigma=1.0)
        for ev in events:
            before = f.add_step(ev)
        after = f.add_fix(_scan(events[-1].t, beacon, truth[-1], s, rssi=-40.0))
        moved[kernel] = math.hypot(after.x - before.x, after.y - before.y)
    assert moved["cauchy"] < 1.0
    assert moved["gaussian"] > 2.0 * moved["cauchy"]


def test_path_loss_gradient_matches_finite_differences():
    s = BleSettings(path_loss_exponent=2.0, floor_loss_db=10.0)
    m = PathLoss(BeaconReading("B", 3.0, -2.0, 4.0, -1, -70.0, -60.0), s, 0, 1.2)
    p = np.array([7.0, 1.5])
    v, g = m.rssi(p)
    r2 = 4.0 ** 2 + 3.5 ** 2 + 1.0 + 2.8 ** 2
    assert v == pytest.approx(-60.0 - 10.0 - 10.0 * math.log10(r2))
    h = 1e-6
    num = [(m.rssi(p + d)[0] - m.rssi(p - d)[0]) / (2 * h) for d in (np.array([h, 0]), np.array([0, h]))]
    np.testing.assert_allclose(g, num, rtol=1e-5)


def test_online_offset_learns_a_phone_that_hears_everything_8_db_weaker():
    events, truth = walk(np.zeros(30))
    s = BleSettings(offset_sigma_db=6.0, min_rssi_dbm=-100.0)
    f = TrackFusion(no_mag(ble=s))
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.02, position_sigma=0.3)
    beacon = (12.0, 2.0)
    for k, ev in enumerate(events):
        f.add_step(ev)
        f.add_fix(_scan(ev.t, beacon, truth[k + 1], s, noise_db=-8.0))
    learnt = f._fix_state["ble"]["offsets"]["B1"][0]
    assert -10.0 < learnt < -5.0


# ------------------------------------------------------------------ wire, config, scans


def _museum_with(beacons):
    cfg = default_incident()
    return incident_from_dict({**cfg.model_dump(exclude={"beacons", "floor_plans"}), "beacons": beacons})


def test_scans_from_readings_and_their_conversion_to_the_local_frame():
    t = np.array([0.0, 0.5, 1.0, 2.1, 2.2])
    readings = BeaconReadings(t=t + 100.0, beacon=np.array(["A", "B", "A", "A", "X"], dtype=object),
                              rssi=np.array([-70.0, -80.0, -72.0, -60.0, -50.0]), tx_power=np.full(5, np.nan))
    scans = ble_scans(readings, "r1", 2.0)
    assert [m.t for m in scans] == [101.0, 102.2]
    assert scans[0].beacons == ["A", "B"] and scans[0].rssi == [-71.0, -80.0] and scans[0].period == 1.0
    back = wire.decode(wire.encode(scans[1]))
    assert back.source == "ble" and back.beacons == ["A", "X"]
    cfg = _museum_with([{"id": "A", "x": 1.0, "y": 2.0, "floor": -2, "tx_power_dbm": -61.0}])
    scan = to_local(back, cfg)  # X is not configured: left out
    assert [r.beacon for r in scan.readings] == ["A"] and scan.t == pytest.approx(102.2 - 0.5 * 0.2)
    assert scan.readings[0].z == pytest.approx(cfg.elevations()[-2] + 1.0) and scan.readings[0].tx_power == -61.0
    from service.fusion.fixes.base import FixRejected

    with pytest.raises(FixRejected, match="no beacon of the scan"):
        to_local(wire.Fix(responder="r1", t=1.0, source="ble", beacons=["X"], rssi=[-60.0]), cfg)
    with pytest.raises(Exception, match="one rssi per beacon"):
        wire.Fix(responder="r1", t=1.0, source="ble", beacons=["A", "B"], rssi=[-60.0])


def test_incident_beacons_are_validated():
    with pytest.raises(IncidentConfigError, match=r"beacons\[1\]\.id: 'A' is used twice"):
        _museum_with([{"id": "A", "x": 0, "y": 0, "floor": 0}, {"id": "A", "x": 1, "y": 1, "floor": 0}])
    with pytest.raises(IncidentConfigError, match=r"beacons\[0\]\.floor: floor 7 is not configured"):
        _museum_with([{"id": "A", "x": 0, "y": 0, "floor": 7}])
    with pytest.raises(IncidentConfigError, match="at most 512"):
        _museum_with([{"id": f"B{i}", "x": 0, "y": 0, "floor": 0} for i in range(513)])
    cfg = default_incident()
    assert cfg.beacon("be:ac:20:23:00:02").name == "BLE3"  # the survey check's pairing, not the obvious one


# ------------------------------------------------------------------ survey check


def test_survey_check_finds_swapped_identities():
    """Synthetic walks past three beacons; the survey lists two of them under each other's names."""
    cfg = default_incident()
    truth = {"M1": (0.0, 0.0, 0), "M2": (30.0, 0.0, 0), "M3": (15.0, 20.0, 0)}
    s = BleSettings(path_loss_exponent=2.0)
    rng = np.random.default_rng(7)
    recordings = []
    for rep in range(2):
        corners = np.array([[-5.0, -2.0], [35.0, -2.0], [15.0, 22.0], [-5.0, -2.0]])
        lm_t = np.array([0.0, 40.0, 70.0, 100.0]) + rep
        lat, lon, _ = cfg.to_geodetic(corners[:, 0], corners[:, 1])
        lms = Landmarks(t=lm_t, lat=np.asarray(lat), lon=np.asarray(lon), floor=np.zeros(4, int), counter=np.arange(4))
        t = np.arange(0.5, 99.5, 0.4)
        x, y = np.interp(t, lm_t, corners[:, 0]), np.interp(t, lm_t, corners[:, 1])
        ids = np.array(sorted(truth) * (len(t) // 3 + 1), dtype=object)[: len(t)]
        rssi = np.array([PathLoss(BeaconReading(b, *truth[b][:2], 1.0, 0, 0.0, -62.0), s, 0, 1.0).rssi((xx, yy))[0]
                         for b, xx, yy in zip(ids, x, y)]) + rng.normal(0, 4.0, len(t))
        recordings.append(Recording(source=f"synthetic{rep}", kind="test", landmarks=lms,
                                    ble=BeaconReadings(t=t, beacon=ids, rssi=rssi, tx_power=np.full(len(t), np.nan))))
    survey = [SurveyEntry("S1", 0.5, 0.5, 0, 0, 0), SurveyEntry("S2", 15.0, 19.0, 0, 0, 0), SurveyEntry("S3", 29.0, 0.0, 0, 0, 0)]
    checks = {c.beacon: c for c in check_survey(recordings, survey, cfg, path_loss_exponent=2.0)}
    assert {b: c.matched for b, c in checks.items()} == {"M1": "S1", "M2": "S3", "M3": "S2"}
    assert checks["M1"].identity_agrees and not checks["M2"].identity_agrees and not checks["M3"].identity_agrees
    assert checks["M2"].listed == "S2" and checks["M2"].listed_distance_m > 10.0
    assert all(c.position_agrees and c.floor_agrees for c in checks.values())
    assert all(abs(c.tx_power_dbm - (-62.0)) < 3.0 for c in checks.values())
    suggested = config_beacons(list(checks.values()), survey)
    assert [(b["id"], b["name"]) for b in suggested] == [("M1", "S1"), ("M2", "S3"), ("M3", "S2")]
