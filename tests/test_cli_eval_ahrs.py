"""``firetrack eval ahrs`` and ``firetrack tune ahrs`` end to end, on a synthetic Vicon-format file."""
import json

import numpy as np
import pytest
import scipy.io
from typer.testing import CliRunner

from client.cli import app
from pdr import quaternion as quat
from pdr.ahrs.base import _NWU_TO_ENU
from pdr.synthetic import GRAVITY, rotating_imu

runner = CliRunner()


@pytest.fixture
def vicon_file(tmp_path):
    imu = rotating_imu(seconds=40, rate_hz=80, seed=7)
    q_nwu = quat.multiply(quat.conjugate(_NWU_TO_ENU), imu.q_true)
    path = tmp_path / "synthetic_vicon.mat"
    scipy.io.savemat(path, {
        "Accelerometer": imu.acc / GRAVITY,
        "Gyroscope": imu.gyr,
        "Magnetometer": imu.mag / np.linalg.norm(imu.mag, axis=1, keepdims=True),
        "qViconReference": q_nwu,
        "time": imu.t[None, :],
    })
    return path


def test_eval_ahrs_json_has_the_documented_fields(vicon_file):
    result = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "--filter", "fscf", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["filter"] == "fscf"
    assert set(report) == {"filter", "files", "mae_deg", "rmse_deg"}
    assert set(report["files"][0]) == {"file", "mae_deg", "rmse_deg"}
    assert 0 < report["mae_deg"] < 3.0  # a clean synthetic IMU is tracked within a few degrees
    assert report["rmse_deg"] >= report["mae_deg"]


def test_eval_ahrs_compares_filters_side_by_side(vicon_file):
    result = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-f", "fscf", "-f", "madgwick", "--json"])
    assert result.exit_code == 0, result.output
    names = [r["filter"] for r in json.loads(result.stdout)["filters"]]
    assert names == ["fscf", "madgwick"]


def test_a_parameter_changes_the_result(vicon_file):
    base = json.loads(runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-f", "fscf", "--json"]).stdout)["mae_deg"]
    no_correction = json.loads(runner.invoke(
        app, ["eval", "ahrs", str(vicon_file), "-f", "fscf", "--json", "-p", "gain_acc=0", "-p", "gain_mag=0"]).stdout)["mae_deg"]
    assert no_correction != base


def test_bad_parameter_and_bad_file_give_clear_errors(vicon_file, tmp_path):
    r = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-p", "gain_acc"])
    assert r.exit_code == 2 and "--param expects name=value" in r.output
    r = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-p", "speed=3"])
    assert r.exit_code == 2 and "unknown parameter 'speed'" in r.output
    r = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-f", "kalman"])
    assert r.exit_code == 2 and "unknown filter 'kalman'" in r.output
    r = runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-f", "fscf", "-p", "speed=3"])
    assert r.exit_code == 2 and "unknown parameter 'speed'" in r.output
    broken = tmp_path / "broken.mat"
    broken.write_bytes(b"not a mat file at all")
    r = runner.invoke(app, ["eval", "ahrs", str(broken), str(vicon_file), "--json"])
    assert r.exit_code == 1  # the bad file is reported, the good one is still scored
    assert "broken.mat" in r.output and "Traceback" not in r.output


def test_tune_improves_on_a_poor_start(vicon_file):
    r = runner.invoke(app, ["tune", "ahrs", str(vicon_file), "-f", "fscf", "-p", "gain_acc=0.005", "-p", "gain_mag=0.001", "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    start = json.loads(runner.invoke(app, ["eval", "ahrs", str(vicon_file), "-f", "fscf", "--json", "-p", "gain_acc=0.005", "-p", "gain_mag=0.001"]).stdout)
    assert report["mae_deg"] < start["mae_deg"]


def test_tune_grid_with_cross_validation(vicon_file, tmp_path):
    other = tmp_path / "second.mat"
    imu = rotating_imu(seconds=30, rate_hz=100, seed=9)
    scipy.io.savemat(other, {
        "Accelerometer": imu.acc / GRAVITY, "Gyroscope": imu.gyr,
        "Magnetometer": imu.mag / np.linalg.norm(imu.mag, axis=1, keepdims=True),
        "qViconReference": quat.multiply(quat.conjugate(_NWU_TO_ENU), imu.q_true), "time": imu.t[None, :],
    })
    cache = tmp_path / "cache.json"
    args = ["tune", "ahrs", str(vicon_file), str(other), "-f", "decoupled", "-g", "tau_mag=5,40",
            "-g", "tau_acc=0.5,2", "--cv", "--cache", str(cache), "--json"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert len(rep["top"]) == 4 and rep["chosen"]["params"] in [t["params"] for t in rep["top"]]
    cv = rep["cross_validation"]
    assert [f["held_out"] for f in cv["folds"]] == ["synthetic_vicon.mat", "second.mat"]
    assert cv["held_out_mean_deg"] == sum(f["held_out_deg"] for f in cv["folds"]) / 2
    assert cache.exists() and len(json.loads(cache.read_text())) == 8
    again = json.loads(runner.invoke(app, args).stdout)  # from the cache: the same figures
    assert again["cross_validation"] == cv
    r = runner.invoke(app, ["tune", "ahrs", str(vicon_file), "-f", "decoupled", "-g", "nope=1,2"])
    assert r.exit_code == 2 and "unknown parameter 'nope'" in r.output
    r = runner.invoke(app, ["tune", "ahrs", str(vicon_file), "--cv"])
    assert r.exit_code == 2 and "--cv needs a --grid" in r.output


def test_tune_grid_balanced_by_data_set(vicon_file, tmp_path):
    """--balance dataset: every data set (recording kind) one vote, in the choice and in each fold."""
    from tests.test_broad import _fields, _write

    broad = [str(_write(tmp_path / f"0{k}_undisturbed_{k}.mat", _fields(seconds=12, seed=k))) for k in (1, 2)]
    args = ["tune", "ahrs", *broad, str(vicon_file), "-f", "decoupled", "-g", "tau_mag=5,40", "--cv", "--json"]
    r = runner.invoke(app, [*args, "--balance", "dataset"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["balance"] == "dataset"
    per = rep["chosen"]["per_recording_deg"]
    b = [per[name] for name in per if "undisturbed" in name]
    assert len(b) == 2
    assert rep["chosen"]["mean_deg"] == pytest.approx(0.5 * (sum(b) / 2) + 0.5 * per["synthetic_vicon.mat"])
    assert rep["chosen"]["per_dataset_deg"]["broad"] == pytest.approx(sum(b) / 2)
    cv = rep["cross_validation"]
    assert set(cv["held_out_mean_by_dataset_deg"]) == {"broad", "vicon_ahrs"}
    assert cv["held_out_mean_by_dataset_deg"]["vicon_ahrs"] == cv["folds"][2]["held_out_deg"]
    plain = json.loads(runner.invoke(app, args).stdout)
    assert plain["balance"] == "recording"
    assert plain["chosen"]["mean_deg"] == pytest.approx(sum(plain["chosen"]["per_recording_deg"].values()) / 3)
    r = runner.invoke(app, [*args, "--balance", "imu"])
    assert r.exit_code == 2 and "--balance must be recording or dataset" in r.output
