"""The robustness suite's driver and the per-walk baseline (issue 27), on synthetic walks; the
command on a real walk at the end (skipped when ../shared is absent)."""
from __future__ import annotations

import copy
import json

import pytest
from typer.testing import CliRunner

from pdr.evaluation.robustness import perturbed
from service.core.tracker import tracker_settings_for
from service.protocol.incident import default_incident
from service.review import ipin_baseline as B
from service.review.ipin_robustness import figures, run_suite
from service.review.ipin_run import run_ipin
from tests.test_ipin_eval import synthetic_walk

CFG = default_incident()
SETTINGS = tracker_settings_for(CFG)


@pytest.fixture(scope="module")
def walks():
    return [synthetic_walk("sim_route01_rep01", seed=1, laps=1), synthetic_walk("sim_route02_rep01", seed=2, laps=1)]


def test_the_suite_scores_each_perturbation_as_eval_ipin_would(walks):
    lines = []
    rep = run_suite(walks, CFG, ["grip_z", "gaps"], settings=SETTINGS, log=lines.append)
    assert rep["unperturbed"] == {**figures([run_ipin(w, CFG, 0, True, SETTINGS) for w in walks]),
                                  "worst_walk": rep["unperturbed"]["worst_walk"],
                                  "worst_p75_m": rep["unperturbed"]["worst_p75_m"], "errors": []}
    assert [r["name"] for r in rep["perturbations"]] == ["grip_z", "gaps"]
    grip = rep["perturbations"][0]
    direct = figures([run_ipin(perturbed(w, "grip_z"), CFG, 0, True, SETTINGS) for w in walks])
    assert grip["p75_m"] == direct["p75_m"] and grip["walks"] == direct["walks"]
    assert grip["worst_p75_m"] == max(direct["walks"].values())
    base = rep["unperturbed"]["walks"]
    assert grip["passes"] == (grip["p75_m"] <= 1.25 * rep["unperturbed"]["p75_m"]
                              and all(p <= 2 * base[w] + 2 for w, p in grip["walks"].items()))
    assert rep["passes"] == all(r["passes"] for r in rep["perturbations"])
    assert len(lines) == 3 and lines[1].startswith("grip_z: pooled p75")


def test_several_seeds_run_each_perturbation_once_per_draw(walks):
    # one draw of a random perturbation is luck (mag_steel passed at seed 27 and broke 3 walks at
    # seed 1): with several seeds every perturbation is a row per seed, each its own draw
    rep = run_suite(walks[:1], CFG, ["gaps"], settings=SETTINGS, seed=[5, 6])
    assert rep["seed"] == [5, 6]
    rows = rep["perturbations"]
    assert [(r["name"], r["perturbation"], r["seed"]) for r in rows] == [("gaps@5", "gaps", 5), ("gaps@6", "gaps", 6)]
    for r in rows:
        direct = figures([run_ipin(perturbed(walks[0], "gaps", r["seed"]), CFG, 0, True, SETTINGS)])
        assert r["walks"] == direct["walks"]
    assert rows[0]["walks"] != rows[1]["walks"]  # two draws, two walks


def test_the_seed_option_reads_one_seed_or_several_and_names_what_is_not_one():
    from pdr.evaluation.robustness import seeds_from

    assert seeds_from("27") == [27] and seeds_from(" 27, 1,2,1 ") == [27, 1, 2]
    with pytest.raises(ValueError, match=r"'x1' is not a whole number"):
        seeds_from("27,x1")
    with pytest.raises(ValueError, match="empty list"):
        seeds_from(" , ")


def test_a_perturbation_the_pipeline_cannot_run_fails_and_the_suite_goes_on(walks, monkeypatch):
    import dataclasses

    from pdr.evaluation import robustness
    from pdr.recording import Series

    def too_fast(rec, seed):  # a clock 100 x too fast: 5 kHz, which the wire refuses
        return dataclasses.replace(rec, acc=Series(rec.acc.t[0] + (rec.acc.t - rec.acc.t[0]) / 100, rec.acc.values))

    monkeypatch.setitem(robustness.PERTURBATIONS, "too_fast", robustness.Perturbation("too_fast", "test", too_fast))
    rep = run_suite(walks[:1], CFG, ["too_fast", "gaps"], settings=SETTINGS)
    bad, gaps = rep["perturbations"]
    assert bad["name"] == "too_fast" and not bad["passes"] and bad["p75_m"] is None
    assert bad["errors"][0]["walk"] == "sim_route01_rep01" and "Hz" in bad["errors"][0]["error"]
    assert gaps["p75_m"] is not None and not rep["passes"]


def test_the_baseline_names_each_walk_and_figure_that_got_worse(walks, tmp_path):
    now = B.compute(walks, CFG, SETTINGS, ks=(0, 3))
    assert set(now) == {"sim_route01_rep01", "sim_route02_rep01"}
    assert set(now["sim_route01_rep01"]) == {"K0", "K3"}
    assert set(now["sim_route01_rep01"]["K3"]) == {"live", "pdr", "smoothed"}
    B.write(tmp_path / "b.json", now, {"commit": "x"})
    doc = B.read(tmp_path / "b.json")
    assert B.compare(doc["walks"], now) == []  # the same code against its own baseline
    worse = copy.deepcopy(now)
    worse["sim_route02_rep01"]["K3"]["pdr"]["p75_m"] += 0.6
    worse["sim_route01_rep01"]["K0"]["live"]["p75_m"] += 0.4  # within the tolerance
    worse["sim_route01_rep01"]["K3"]["smoothed"]["floor_accuracy"] -= 0.1
    problems = B.compare(doc["walks"], worse)
    assert len(problems) == 2
    assert problems[0].startswith("sim_route01_rep01 K = 3 smoothed floors")
    assert problems[1].startswith("sim_route02_rep01 K = 3 dead reckoning p75") and "(+0.60 > 0.5 m)" in problems[1]
    del worse["sim_route02_rep01"]
    assert "sim_route02_rep01: not evaluated" in B.compare(doc["walks"], worse)
    better = copy.deepcopy(now)
    better["sim_route01_rep01"]["K0"]["live"]["p75_m"] -= 1.0
    assert B.compare(doc["walks"], better) == [] and len(B.improvements(doc["walks"], better)) == 1


def test_a_file_that_is_not_a_baseline_is_refused(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"walks": {}}))
    with pytest.raises(ValueError, match="not a per-walk baseline"):
        B.read(p)


def test_an_unknown_perturbation_is_refused_before_loading_anything(tmp_path):
    from client.cli import app

    r = CliRunner().invoke(app, ["eval", "ipin", str(tmp_path / "absent.txt"), "--perturb", "rate50,wobble"])
    assert r.exit_code == 2
    assert "unknown wobble" in r.output and "rate50" in r.output


@pytest.mark.recording
def test_eval_ipin_perturb_and_baseline_on_a_real_walk(shared_data, tmp_path):
    from client.cli import app

    walk = str(shared_data("ipin2023/IPIN2023_T3_TrainingTrial04_repetition01.txt.gz"))
    r = CliRunner().invoke(app, ["eval", "ipin", walk, "--perturb", "rate100,gyro_bias", "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert [p["name"] for p in rep["perturbations"]] == ["rate100", "gyro_bias"]
    assert list(rep["unperturbed"]["walks"]) == ["IPIN2023_T3_TrainingTrial04_repetition01"]
    assert all(p["p75_m"] > 0 and p["worst_walk"] for p in rep["perturbations"])
    path = tmp_path / "walks.json"
    r = CliRunner().invoke(app, ["eval", "ipin", walk, "--write-baseline", str(path)])
    assert r.exit_code == 0, r.output
    doc = B.read(path)
    assert len(doc["made_with"]["commit"]) == 40 and doc["made_with"]["settings_digest"]
    fig = doc["walks"]["IPIN2023_T3_TrainingTrial04_repetition01.txt.gz"]
    assert fig["K0"]["live"]["p75_m"] == pytest.approx(rep["unperturbed"]["p75_m"])
    r = CliRunner().invoke(app, ["eval", "ipin", walk, "--check-baseline", str(path)])
    assert r.exit_code == 0, r.output
    assert "0 regression(s)" in r.output
    fig["K3"]["live"]["p75_m"] -= 1.0  # the baseline says better than the code gives
    path.write_text(json.dumps(doc))
    r = CliRunner().invoke(app, ["eval", "ipin", walk, "--check-baseline", str(path)])
    assert r.exit_code == 1
    assert "Trial04_repetition01.txt.gz K = 3 live p75" in r.output and "1 regression(s)" in r.output
