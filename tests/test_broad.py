"""BROAD trials: the loader on small synthetic files (good and malformed), the benchmark's metric, the CLI."""
import json
import warnings

import numpy as np
import pytest
import scipy.io
from typer.testing import CliRunner

from client.cli import app
from pdr import quaternion as quat
from pdr.evaluation.orientation import (
    METRICS,
    benchmark_score,
    benchmark_summary,
    earth_error_angles,
)
from pdr.io import RecordingFormatError, RecordingWarning, load, load_broad, load_broad_groups
from pdr.synthetic import rotating_imu

RATE = 285.714  # Hz, BROAD's rate
runner = CliRunner()


def _fields(seconds=20.0, rate=RATE, seed=3, missing=(2000, 2030)):
    imu = rotating_imu(seconds=seconds, rate_hz=rate, seed=seed)
    n = len(imu.t)
    q = imu.q_true.copy()
    q[missing[0]:missing[1]] = np.nan  # the cameras lost the markers
    movement = np.zeros((n, 1), dtype=np.uint8)
    movement[n // 4: 3 * n // 4] = 1
    return {
        "imu_gyr": imu.gyr, "imu_acc": imu.acc, "imu_mag": imu.mag, "opt_quat": q,
        "opt_pos": np.zeros((n, 3)), "movement": movement, "sampling_rate": np.array([[rate]]),
        "info": np.array(["synthetic BROAD-format trial"]),
    }


def _write(path, fields):
    scipy.io.savemat(path, fields)
    return path


@pytest.fixture
def broad_file(tmp_path):
    return _write(tmp_path / "01_undisturbed_synthetic.mat", _fields())


def test_loader_reads_units_frame_time_movement_and_gaps(broad_file):
    rec = load_broad(broad_file)
    f = _fields()
    n = f["imu_gyr"].shape[0]
    assert rec.kind == "broad" and rec.frame == "ENU"
    assert np.array_equal(rec.gyr.values, f["imu_gyr"]) and np.array_equal(rec.acc.values, f["imu_acc"])
    assert np.allclose(rec.acc.t, np.arange(n) / RATE)
    assert rec.meta["movement"].dtype == bool and rec.meta["movement"].sum() == f["movement"].sum()
    assert np.isnan(rec.orientation_ref.values[2000:2030]).all()
    assert np.isfinite(rec.orientation_ref.values[:2000]).all()
    assert rec.meta["trial"] == "01_undisturbed_synthetic"
    assert rec.meta["rate_hz"] == pytest.approx(RATE)
    assert rec.meta["info"] == "synthetic BROAD-format trial"


def test_load_picks_the_broad_loader_from_the_fields(broad_file):
    assert load(broad_file).kind == "broad"


@pytest.mark.parametrize("change, field, message", [
    (lambda f: f.pop("imu_mag"), "imu_mag", "missing"),
    (lambda f: f.__setitem__("imu_gyr", f["imu_gyr"][:, :2]), "imu_gyr", "N x 3"),
    (lambda f: f.__setitem__("movement", f["movement"] * 2), "movement", "booleans"),
    (lambda f: f.__setitem__("sampling_rate", np.array([[0.0]])), "sampling_rate", "plausible rate"),
    (lambda f: f.__setitem__("sampling_rate", np.array([[100.0, 200.0]])), "sampling_rate", "one number"),
    (lambda f: f.__setitem__("imu_acc", f["imu_acc"] / 9.81), "imu_acc", "m/s²"),
    (lambda f: f.__setitem__("opt_quat", np.full_like(f["opt_quat"], np.nan)), "opt_quat", "no finite"),
    (lambda f: f.__setitem__("movement", f["movement"][:-50]), None, "differ in length"),
])
def test_malformed_files_give_errors_that_name_file_and_field(tmp_path, change, field, message):
    f = _fields(seconds=3)
    change(f)
    path = _write(tmp_path / "bad.mat", f)
    with pytest.raises(RecordingFormatError, match=message) as info:
        load_broad(path)
    assert "bad.mat" in str(info.value)
    if field is not None:
        assert info.value.field == field


def test_nan_in_the_imu_data_is_an_error_with_its_sample(tmp_path):
    f = _fields(seconds=3)
    f["imu_gyr"][42, 1] = np.nan
    with pytest.raises(RecordingFormatError, match="first at sample 42"):
        load_broad(_write(tmp_path / "nan.mat", f))


def test_not_a_mat_file_and_empty_file(tmp_path):
    p = tmp_path / "x.mat"
    p.write_bytes(b"")
    with pytest.raises(RecordingFormatError, match="empty file"):
        load_broad(p)
    p.write_bytes(b"this is text")
    with pytest.raises(RecordingFormatError, match="cannot read as a MATLAB"):
        load_broad(p)


def test_partly_nan_reference_rows_are_missing_with_a_warning(tmp_path):
    f = _fields(seconds=3)
    f["opt_quat"][7, 2] = np.nan
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RecordingWarning)
        rec = load_broad(_write(tmp_path / "p.mat", f))
    assert np.isnan(rec.orientation_ref.values[7]).all()
    assert any("partly NaN" in str(w.message) for w in caught)


def test_groups_file_good_and_malformed(tmp_path):
    good = tmp_path / "trials.json"
    good.write_text(json.dumps({"groups": [], "trials": {"01_a": {"groups": ["all_trials", "undisturbed"]}}}))
    assert load_broad_groups(good) == {"01_a": ["all_trials", "undisturbed"]}
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(RecordingFormatError, match="JSON"):
        load_broad_groups(bad)
    bad.write_text(json.dumps({"trials": {"01_a": {"groups": "undisturbed"}}}))
    with pytest.raises(RecordingFormatError, match="no list of group names"):
        load_broad_groups(bad)
    bad.write_text(json.dumps([1, 2]))
    with pytest.raises(RecordingFormatError, match="'trials' mapping"):
        load_broad_groups(bad)


# -- the metric ------------------------------------------------------------------------------

def test_error_angles_split_heading_and_inclination():
    rng = np.random.default_rng(0)
    q_ref = quat.normalize(rng.normal(size=(200, 4)))
    heading = rng.uniform(-0.5, 0.5, 200)
    tilt = rng.uniform(0, 0.4, 200)
    axis = np.c_[np.cos(rng.uniform(0, 6.3, 200)), np.sin(rng.uniform(0, 6.3, 200)), np.zeros(200)]
    # an earth-frame error: first a tilt about a horizontal axis, then a turn about up
    e = quat.multiply(quat.from_yaw(heading), quat.from_axis_angle(axis, tilt))
    q_est = quat.multiply(e, q_ref)
    ang = earth_error_angles(q_est, q_ref)
    assert np.allclose(ang[:, 1], np.abs(heading), atol=1e-9)
    assert np.allclose(ang[:, 2], tilt, atol=1e-7)
    assert np.allclose(ang[:, 0], quat.angle(e), atol=1e-9)
    # the sign of the quaternions does not matter
    assert np.allclose(earth_error_angles(-q_est, q_ref), ang, atol=1e-9)


def test_rmse_over_movement_samples_ignores_reference_gaps(broad_file):
    rec = load_broad(broad_file)
    q_ref = rec.orientation_ref.values
    est = np.where(np.isnan(q_ref), 1.0, q_ref)
    est = quat.multiply(quat.from_yaw(np.radians(2.0)), quat.normalize(est))
    est[rec.meta["movement"] & (np.arange(len(est)) % 2 == 0)] = quat.multiply(
        quat.from_yaw(np.radians(4.0)), np.nan_to_num(q_ref[rec.meta["movement"] & (np.arange(len(est)) % 2 == 0)]))
    s = benchmark_score(rec, est, "test")
    # movement samples with a reference: the even ones 4° off, the odd ones 2°
    scored = rec.meta["movement"] & np.isfinite(q_ref[:, 0])
    n4 = np.count_nonzero(scored & (np.arange(len(est)) % 2 == 0))
    n2 = np.count_nonzero(scored) - n4
    want = np.sqrt((16.0 * n4 + 4.0 * n2) / (n4 + n2))
    assert s.rmse_deg("total") == pytest.approx(want, abs=1e-6)
    assert s.rmse_deg("heading") == pytest.approx(want, abs=1e-6)
    assert s.rmse_deg("inclination") == pytest.approx(0.0, abs=1e-5)
    assert rec.meta["movement"][2000:2030].all() and np.isnan(s.errors_deg[2000:2030]).all()
    assert set(s.as_dict()) == {"trial", "file"} | {f"{m}_rmse_deg" for m in METRICS}


def test_summary_means_over_trials_and_groups(broad_file, tmp_path):
    rec = load_broad(broad_file)
    q = np.nan_to_num(rec.orientation_ref.values, nan=0.5)
    a = benchmark_score(rec, quat.multiply(quat.from_yaw(np.radians(1.0)), q), "x")
    b = benchmark_score(rec, quat.multiply(quat.from_yaw(np.radians(3.0)), q), "x")
    b = type(b)(b.source, "02_other", b.filter, b.errors_deg, b.movement, b.t)
    s = benchmark_summary([a, b], {a.trial: ["all", "undisturbed"], "02_other": ["all", "disturbed"]})
    assert s["mean_total_rmse_deg"] == pytest.approx(2.0, abs=1e-6)
    assert s["groups"]["undisturbed"]["mean_total_rmse_deg"] == pytest.approx(1.0, abs=1e-6)
    assert s["groups"]["disturbed"]["trials"] == 1
    assert s["groups"]["all"]["trials"] == 2


# -- the command -----------------------------------------------------------------------------

@pytest.fixture
def broad_dir(tmp_path):
    _write(tmp_path / "01_undisturbed_a.mat", _fields(seconds=25, seed=1))
    _write(tmp_path / "24_disturbed_b.mat", _fields(seconds=25, seed=2))
    (tmp_path / "trials.json").write_text(json.dumps({"groups": [], "trials": {
        "01_undisturbed_a": {"groups": ["all_trials", "undisturbed"]},
        "24_disturbed_b": {"groups": ["all_trials", "disturbed"]}}}))
    return tmp_path


def test_eval_ahrs_broad_json_reports_trials_means_and_groups(broad_dir):
    files = sorted(str(p) for p in broad_dir.glob("*.mat"))
    r = runner.invoke(app, ["eval", "ahrs", *files, "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    b = rep["broad"]
    assert [t["trial"] for t in b["trials"]] == ["01_undisturbed_a", "24_disturbed_b"]
    assert set(b["groups"]) == {"all_trials", "undisturbed", "disturbed"}
    assert b["mean_total_rmse_deg"] == pytest.approx(np.mean([t["total_rmse_deg"] for t in b["trials"]]))
    assert 0 < b["mean_total_rmse_deg"] < 3.0  # a clean synthetic IMU, from the filter's own start


def test_eval_ahrs_with_the_vqf_baseline_side_by_side(broad_dir, tmp_path):
    pytest.importorskip("vqf", reason="the vqf baseline needs the 'eval' extra")
    files = sorted(str(p) for p in broad_dir.glob("*.mat"))
    plots = tmp_path / "plots"
    r = runner.invoke(app, ["eval", "ahrs", *files, "--baseline", "vqf", "--json", "--plot", str(plots)])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    names = [f["filter"] for f in rep["filters"]]
    assert names[-1] == "vqf" and rep["filters"][-1]["baseline"] is True
    assert set(rep["comparison"]) == {"mean_total_rmse_deg", "undisturbed_mean_total_rmse_deg",
                                      "disturbed_mean_total_rmse_deg"}
    assert rep["comparison"]["mean_total_rmse_deg"]["vqf"] < 3.0
    assert (plots / "broad_total_error.png").stat().st_size > 0


def test_unknown_baseline_is_a_clear_error(broad_dir):
    r = runner.invoke(app, ["eval", "ahrs", str(next(broad_dir.glob("*.mat"))), "--baseline", "kalman"])
    assert r.exit_code == 2 and "unknown baseline 'kalman'" in r.output
