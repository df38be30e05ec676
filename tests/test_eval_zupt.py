"""Scoring the boot INS (pdr.evaluation.zupt) and ``firetrack eval zupt`` / ``bench zupt`` end to end,
on synthetic PyShoe-format files."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.io
from typer.testing import CliRunner

from pdr.evaluation.zupt import cross_validate, se2_apply, se2_fit, score_track
from pdr.zupt.synthetic import foot_walk, square_strides
from client.cli import app

runner = CliRunner()


def test_se2_fit_recovers_a_rotation_and_a_translation():
    rng = np.random.default_rng(0)
    ref = rng.normal(size=(50, 2))
    theta, t = 0.7, np.array([3.0, -1.0])
    c, s = math.cos(-theta), math.sin(-theta)
    est = (ref - t) @ np.array([[c, -s], [s, c]]).T  # est = R(θ)ᵀ (ref − t)
    th, tr = se2_fit(est, ref)
    assert th == pytest.approx(theta, abs=1e-12)
    np.testing.assert_allclose(tr, t, atol=1e-12)
    np.testing.assert_allclose(se2_apply(th, tr, est), ref, atol=1e-12)
    with pytest.raises(ValueError, match="same shape"):
        se2_fit(est[:3], ref)


def test_se2_fit_cannot_align_a_mirror_image():
    rng = np.random.default_rng(1)
    ref = rng.normal(size=(100, 2))
    th, tr = se2_fit(ref[:, ::-1], ref)
    assert np.sqrt(np.mean(np.sum((se2_apply(th, tr, ref[:, ::-1]) - ref) ** 2, axis=1))) > 0.3


def test_cross_validation_scores_the_choice_on_held_out_files():
    errors = np.array([[0.1, 0.1, 0.1, 0.2],
                       [0.3, 0.3, 0.3, 0.0]])
    # leave one out: config 0 wins on every set of three files
    cv = cross_validate(errors)
    np.testing.assert_allclose(cv["held_out"], [0.1, 0.1, 0.1, 0.2])
    assert cv["mean"] == pytest.approx(0.125) and list(cv["chosen"]) == [0, 0, 0, 0]
    # leave a group out: chosen on file 3 alone, the first three files get config 1
    groups = np.array(["a", "a", "a", "b"])
    np.testing.assert_allclose(cross_validate(errors, groups)["held_out"], [0.3, 0.3, 0.3, 0.2])
    with pytest.raises(ValueError, match="two groups"):
        cross_validate(errors, np.zeros(4))


def _pyshoe_file(path, vicon: bool, seed: int):
    """A synthetic walk written as PyShoe writes it: positions in a z-down frame (x, y swapped)."""
    w = foot_walk(square_strides(5, 1.1), acc_noise=0.02, gyr_noise=math.radians(0.5), seed=seed)
    stance_end = np.flatnonzero(w.stance[:-1] & ~w.stance[1:])  # last rest sample before each swing
    idx = np.concatenate((stance_end, [len(w.t) - 1]))
    truth = w.position[:, :2]
    peer = truth + 0.05 * np.column_stack((np.sin(w.t), np.cos(w.t)))  # a peer 5 cm off
    fields = {"imu_data": np.column_stack((w.acc, w.gyr)), "strideIndex": idx[None, :],
              "GCP": truth[idx][:, ::-1], "pyshoeTrajectory": peer[:, ::-1]}
    if vicon:
        fields |= {"timestamps_all": w.t[None, :], "timestamps": w.t[idx][None, :], "gt": truth[:, ::-1]}
    else:
        fields |= {"timestamps": w.t[None, :]}
    scipy.io.savemat(path, fields)
    return path


@pytest.fixture
def pyshoe_files(tmp_path):
    return [_pyshoe_file(tmp_path / "2017-01-01-10-00-00_LLIO.mat", True, 1),
            _pyshoe_file(tmp_path / "SensorConnectData_1_LLIO.mat", False, 2)]


def test_eval_zupt_json_reports_ours_next_to_pyshoe(pyshoe_files):
    result = runner.invoke(app, ["eval", "zupt", *map(str, pyshoe_files), "--json", "--per-frame", "10"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    vicon, hall = report["files"]
    assert vicon["kind"] == "vicon" and hall["kind"] == "gcp"
    assert vicon["distance_m"] == pytest.approx(20 * 1.1, rel=1e-6)
    assert vicon["ours"]["ate_rmse_m"] < 0.1 and vicon["ours"]["final_error_pct"] < 1.0
    assert vicon["pyshoe"]["ate_rmse_m"] == pytest.approx(0.05, abs=0.01)  # the peer's 5 cm, scored alike
    assert hall["ours"]["gcp_mean_m"] < 0.1 and hall["pyshoe"]["gcp_mean_m"] > 0.02
    assert math.isnan(hall["ours"]["ate_rmse_m"])
    s = report["summary"]
    assert s["vicon"]["files"] == 1 and s["gcp"]["files"] == 1
    assert s["vicon"]["ours"]["mean_ate_rmse_m"] == pytest.approx(vicon["ours"]["ate_rmse_m"])
    assert report["settings"]["detector"]["detector"] == "adaptive"


def test_eval_zupt_table_plots_and_options(pyshoe_files, tmp_path):
    result = runner.invoke(app, ["eval", "zupt", *map(str, pyshoe_files), "--detector", "shoe",
                                 "--param", "detector.shoe_threshold=2e4", "--plot", str(tmp_path / "plots")])
    assert result.exit_code == 0, result.output
    assert "Vicon files" in result.stdout and "Hallway files" in result.stdout
    assert len(list((tmp_path / "plots").glob("*_zupt.png"))) == 2
    bad = runner.invoke(app, ["eval", "zupt", str(pyshoe_files[0]), "--param", "shoe_threshold=2e4"])
    assert bad.exit_code == 2 and "section.name" in bad.output
    bad = runner.invoke(app, ["eval", "zupt", str(pyshoe_files[0]), "--param", "detector.nope=1"])
    assert bad.exit_code == 2 and "unknown parameter" in bad.output


def test_score_track_of_the_truth_is_zero(pyshoe_files):
    from pdr.io.pyshoe import load_pyshoe

    rec = load_pyshoe(pyshoe_files[0])
    s = score_track(rec.position_ref.values, rec)
    assert s.ate_rmse_m == pytest.approx(0.0, abs=1e-12) and s.gcp_mean_m == pytest.approx(0.0, abs=1e-12)


def test_bench_zupt_prints_json():
    result = runner.invoke(app, ["bench", "zupt", "--seconds", "30", "--repeats", "1"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["samples"] > 5000
    assert report["ins_detector_samples_per_s"] > 0 and report["motion_model_samples_per_s_live_batches"] > 0
