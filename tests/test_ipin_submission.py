"""eval ipin --submit: the IPIN 2023 Track 3 result files, scored from the files alone."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from service.review.ipin_submission import organisers_errors, read_estimates, score_files

WALKS = ("IPIN2023_T3_TrainingTrial01_repetition01.txt.gz", "IPIN2023_T3_TrainingTrial52_repetition01.txt.gz")


def test_the_submission_files_reproduce_eval_ipins_p75_to_a_centimetre(tmp_path, shared_data):
    from client.cli import app

    files = [str(shared_data(f"ipin2023/{w}")) for w in WALKS]
    r = CliRunner().invoke(app, ["eval", "ipin", *files, "--submit", str(tmp_path), "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    pairs = []
    for f in files:
        name = Path(f).name.removesuffix(".txt.gz")
        est, gt = tmp_path / f"{name}.est", tmp_path / f"GT_{name}.csv"
        lines = est.read_text().splitlines()
        assert lines[0].startswith("%") and lines[1].startswith("%")  # the organisers' reader skips two lines
        rows = read_estimates(est)
        assert rows.shape[1] == 7 and np.all(np.diff(rows[:, 0]) > 0) and np.all(np.diff(rows[:, 0]) <= 0.5 + 0.021)  # a grid row just after a landmark gives way
        assert np.all(np.abs(rows[:, 5] - 49.461) < 0.01) and np.all(np.abs(rows[:, 4] - 11.111) < 0.01)  # lat, lon
        pairs.append((est, gt))
    again = score_files(pairs)  # from the two files of each walk, nothing else
    assert again["n_eval"] == report["n_eval"] > 20
    assert abs(again["p75_m"] - report["p75_m"]) < 0.01, (again["p75_m"], report["p75_m"])
    for walk, f in zip(again["walks"], report["files"]):
        assert abs(walk["p75_m"] - f["p75_m"]) < 0.01 and walk["n_eval"] == f["n_eval"]
    assert report["submission"]["p75_m"] == again["p75_m"]


def test_the_organisers_match_rule_and_quantile():
    # ground truth at 10 s and 20 s (time, lon, lat, floor, index), estimates every 0.5 s plus one 5 ms late
    lat, lon = 49.4612, 11.1110
    gt = np.array([[10.0, lon, lat, 0, 1], [20.0, lon, lat, -1, 2]])
    t = np.arange(0.0, 30.0, 0.5)
    est = np.column_stack([t, 0 * t, 0.5 + 0 * t, 0 * t, lon + 0 * t, lat + 0 * t, 0 * t])
    est = np.insert(est, 21, [10.005, 0, 0.5, 0, lon, lat + 1e-4, 0], axis=0)  # within 10 ms after the first: taken
    e = organisers_errors(est, gt)
    assert abs(e["horizontal_m"][0] - 11.12) < 0.05 and e["horizontal_m"][1] < 1e-6
    assert list(e["floor_error"]) == [0, 1] and abs(e["error_m"][1] - 15.0) < 1e-6
    # MATLAB's quantile places the i-th of n sorted values at (i - 0.5) / n: 3.5 for 1..4 (numpy's linear: 3.25)
    assert np.percentile([1.0, 2.0, 3.0, 4.0], 75, method="hazen") == 3.5
