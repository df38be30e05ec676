"""Recording a live multi-person exercise and reprocessing it offline: the same poses."""
from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from client.simulate import SimulationPublisher
from service.protocol.incident import default_incident
from service.review.recorder import IncidentRecorder, read_recording, recording_summary
from service.review.reprocess import reprocess
from service.shell.service import IncidentService, ServiceSettings
from tests.zenoh_util import client, router, wait_until


@pytest.mark.bitexact
def test_four_person_exercise_recorded_live_then_reprocessed_gives_identical_poses(tmp_path):
    cfg = default_incident()
    session, endpoint = router()
    path = tmp_path / "live.mcap"
    recorder = IncidentRecorder(path, cfg.id)
    svc = IncidentService(session, cfg, ServiceSettings(), recorder=recorder).start()
    cl = client(endpoint)
    # the service's own poses go into the recording, as with serve --record
    pub = SimulationPublisher(cl, cfg.id, 4, rate_hz=50.0, seed=3, truth=False)
    frames = 0
    for _ in range(300):  # 30 s of walking each, sent as fast as the service takes it
        frames += pub.step(5)
    assert wait_until(lambda: svc.frames_processed >= frames, 60)
    svc.wait_idle(10)
    pub.close()
    svc.close()
    recorder.close()
    cl.close()
    session.close()
    summary = recording_summary(path)
    assert not summary["truncated"]
    rep = reprocess(path, cfg)
    assert set(rep["responders"]) == set(pub.names)
    for rid, r in rep["responders"].items():
        assert r["steps"] > 30, rid
        assert r["recorded_poses"] == r["poses"] > 30
        assert r["max_deviation_m"] == 0.0  # bit for bit: reprocess runs the live code
    assert rep["max_deviation_m"] == 0.0
    # every pose the service published live is in the recording
    kinds = [m.kind for m in read_recording(path)]
    assert kinds.count("pose") == sum(r["poses"] for r in rep["responders"].values())


def test_exercise_and_reprocess_commands(tmp_path, shared_data):
    from client.cli import app

    d = shared_data("ipin2023")
    files = sorted(d.glob("IPIN2023_T3_TrainingTrial2*_repetition01.txt.gz"))[:2]
    out = tmp_path / "ex.mcap"
    args = ["exercise", "--out", str(out), "--landmark-every", "3"]
    for i, f in enumerate(files):
        args += ["--responder", f"ff{i}={f}"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    s = recording_summary(out)
    assert set(s["responders"]) == {"ff0", "ff1"}
    r = CliRunner().invoke(app, ["reprocess", str(out), "--json", "--export", str(tmp_path / "exp")])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["max_deviation_m"] is None  # an exercise has no live poses to compare with
    for rid in ("ff0", "ff1"):
        assert rep["responders"][rid]["steps"] > 50 and rep["responders"][rid]["distance_smoothed_m"] > 30 and rep["responders"][rid]["distance_live_m"] > 30
    geo = json.loads((tmp_path / "exp" / "tracks.geojson").read_text())
    assert {f["properties"]["responder"] for f in geo["features"]} == {"ff0", "ff1"}
    assert (tmp_path / "exp" / "ff0.tum").read_text().count("\n") > 50
    import csv

    import numpy as np

    live = list(csv.DictReader((tmp_path / "exp" / "live.csv").open()))  # the poses as published, with covariance
    assert {r["responder"] for r in live} == {"ff0", "ff1"}
    cov = np.array([[float(r["cov_xx"]), float(r["cov_xy"]), float(r["cov_yy"])] for r in live])
    assert np.all(cov[:, 0] > 0) and np.all(cov[:, 2] > 0) and np.all(cov[:, 1] ** 2 <= cov[:, 0] * cov[:, 2] * (1 + 1e-3))


def test_bad_exercise_arguments_are_refused(tmp_path):
    from client.cli import app

    r = CliRunner().invoke(app, ["exercise", "--out", str(tmp_path / "x.mcap"), "--responder", "nofile"])
    assert r.exit_code == 2 and "ID=FILE" in r.output
    r = CliRunner().invoke(app, ["reprocess", str(tmp_path / "missing.mcap")])
    assert r.exit_code == 2 and "no such recording" in r.output


def test_simulated_walkers_all_publish_in_real_time():
    from tests.zenoh_util import client as _client
    from tests.zenoh_util import router as _router

    session, endpoint = _router()
    cl = _client(endpoint)
    seen: set[str] = set()
    sub = cl.declare_subscriber("firetrack/demo/*/imu", lambda s: seen.add(str(s.key_expr).split("/")[2]))
    pub = SimulationPublisher(_client(endpoint), "demo", 4, rate_hz=50.0, seed=1, truth=False)
    frames = pub.run(0.5)
    assert frames == 4 * 5
    assert wait_until(lambda: seen == set(pub.names), 5), seen
    pub.close()
    sub.undeclare()
    cl.close()
    session.close()


def test_reprocess_reads_a_recording_of_another_incident_id(tmp_path):
    cfg = default_incident()
    path = tmp_path / "other.mcap"
    from pdr.synthetic import static_imu
    from service.protocol import wire

    imu = static_imu(seconds=5.0, rate_hz=50.0)
    with IncidentRecorder(path, "drill-7") as rec:
        for k, b in enumerate(wire.imu_batches_from_arrays("ff1", "d", imu.t, imu.acc, imu.gyr, per_batch=5)):
            rec.write(wire.key("drill-7", "ff1", "imu"), wire.encode(b), 1000.0 + 0.1 * k)
    rep = reprocess(path, cfg)
    assert rep["inputs"] == 50 and set(rep["responders"]) == {"ff1"}


@pytest.mark.recording
@pytest.mark.bitexact
def test_handheld_and_boot_mounted_wearers_live_then_reprocessed_give_identical_poses(tmp_path, shared_data):
    """Issue 16: an IPIN walk (phone in the hand) and a PyShoe walk (IMU on the boot), built into
    one exercise, replayed at 20x through a live service that records, then reprocessed."""
    from pdr.events import MotionState
    from service.cli.record import replay
    from service.review.reprocess import build_exercise

    cfg = default_incident()
    ipin = shared_data("ipin2023/IPIN2023_T3_TrainingTrial21_repetition01.txt.gz")
    boot = shared_data("pyshoe-vicon/2017-11-22-11-26-05_LLIO.mat")
    exercise = tmp_path / "two.mcap"
    build_exercise([("hand", ipin), ("boot", boot)], exercise, cfg, landmark_every=3, gnss=False)
    session, endpoint = router()
    live = tmp_path / "live.mcap"
    recorder = IncidentRecorder(live, cfg.id)
    svc = IncidentService(session, cfg, ServiceSettings(), recorder=recorder).start()
    sent = replay(exercise, endpoint, speed=20.0, quiet=True, wait_for_subscribers_s=5.0)
    frames = sum(n for k, n in sent["keys"].items() if k.endswith("/imu"))
    assert wait_until(lambda: svc.frames_processed >= frames, 60)
    svc.wait_idle(10)
    boot_tracker = svc.responders["boot"].tracker
    assert type(boot_tracker.model).__name__ == "ZuptMotionModel"  # carry="foot" chose the INS
    assert type(svc.responders["hand"].tracker.model).__name__ == "FleetMember"  # the handheld pipeline, in columnar rounds
    svc.close()
    recorder.close()
    session.close()
    rep = reprocess(live, cfg)
    assert set(rep["responders"]) == {"hand", "boot"}
    for rid in ("hand", "boot"):
        r = rep["responders"][rid]
        assert r["steps"] > 10 and r["recorded_poses"] == r["poses"] > 10, (rid, r)
        assert r["max_deviation_m"] == 0.0, rid  # bit for bit, under 20x load
    assert rep["responders"]["boot"]["distance_smoothed_m"] > 10  # strides walked, not a standing boot
    assert MotionState.NO_MOTION is not boot_tracker.motion[0]


@pytest.mark.recording
def test_replaying_an_exercise_the_service_already_has_says_what_to_do(tmp_path, shared_data):
    """Issue 18: the same frames twice are rejected as duplicates; the replay says so up front."""
    from service.cli.record import replay
    from service.review.reprocess import build_exercise

    cfg = default_incident()
    exercise = tmp_path / "one.mcap"
    build_exercise([("r1", shared_data("ipin2023/IPIN2023_T3_TrainingTrial21_repetition01.txt.gz"))], exercise, cfg,
                   gnss=False)
    session, endpoint = router()
    svc = IncidentService(session, cfg, ServiceSettings(), recorder=None).start()
    try:
        sent = replay(exercise, endpoint, speed=0.0, quiet=True, wait_for_subscribers_s=5.0)
        frames = sum(n for k, n in sent["keys"].items() if k.endswith("/imu"))
        assert wait_until(lambda: svc.frames_processed >= frames, 60)
        with pytest.raises(ValueError, match=r"already tracks r1 .*--as-incident"):
            replay(exercise, endpoint, speed=0.0, quiet=True)
        again = replay(exercise, endpoint, speed=0.0, quiet=True, incident=f"{cfg.id}-replay", wait_for_subscribers_s=0.2)
        assert again["messages"] == sent["messages"]  # under a new incident id it goes out
        assert again["unheard_keys"]  # ... and nobody serves that id here: the report says so
        assert sent["unheard_keys"] == []
    finally:
        svc.close()
        session.close()
