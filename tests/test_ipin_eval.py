"""IPIN evaluation machinery (issue 12): replayed dead reckoning, leave-one-route-out cross-validation.

Synthetic walks (pdr.simulation) stand in for IPIN logs here, with landmarks where the walker
really was; the real walks are exercised by the recording tests at the end (skipped when absent).
"""
from __future__ import annotations

import json

import numpy as np
import pymap3d
import pytest

from pdr.evaluation.ipin import summary
from pdr.recording import Landmarks, Recording, Series
from pdr.simulation import Route, WalkerSettings, simulate_walk
from service.protocol.incident import default_incident
from service.review.ipin_cv import Candidate, apply_overrides, cross_validate, default_candidate, report, route_of
from service.review.ipin_run import PdrCache, run_ipin
from service.core.tracker import tracker_settings_for

CFG = default_incident()
ORIGIN = (CFG.origin.lat, CFG.origin.lon, CFG.origin.alt_m)


def synthetic_walk(name: str, seed: int, side: float = 12.0, laps: int = 2) -> Recording:
    """A walker going ``laps`` times round a rectangle on floor 0; a landmark every 8 s."""
    wp = [(0.0, 0.0), (side, 0.0), (side, 8.0), (0.0, 8.0)] * laps + [(0.0, 0.0)]
    sim = simulate_walk(Route(np.array(wp), np.zeros(len(wp), int)), WalkerSettings(rate_hz=50.0),
                        seconds=28.0 * laps + 8.0, seed=seed)
    idx = np.arange(int(3.0 * 50), len(sim.t), int(8.0 * 50))
    lat, lon, _ = pymap3d.enu2geodetic(sim.x[idx], sim.y[idx], 0.0, *ORIGIN)
    lm = Landmarks(t=sim.t[idx], lat=np.asarray(lat), lon=np.asarray(lon), floor=np.zeros(idx.size, int),
                   counter=np.arange(1, idx.size + 1))
    return Recording(source=name, kind="ipin", acc=Series(sim.t, sim.acc), gyr=Series(sim.t, sim.gyr),
                     mag=Series(sim.t, sim.mag), pressure=Series(sim.pressure_t, sim.pressure[:, None]), landmarks=lm)


@pytest.fixture(scope="module")
def walks():
    return [synthetic_walk("synthetic_Trial07_repetition01", 1), synthetic_walk("synthetic_Trial07_repetition02", 2),
            synthetic_walk("synthetic_Trial08_repetition01", 3, side=9.0)]


@pytest.mark.bitexact
@pytest.mark.parametrize("k", [0, 2])
def test_replayed_dead_reckoning_gives_the_same_tracks_bit_for_bit(walks, k):
    settings = tracker_settings_for(CFG)
    cache = PdrCache()
    first = run_ipin(walks[0], CFG, k, True, settings, pdr_cache=cache)
    again = run_ipin(walks[0], CFG, k, True, settings, pdr_cache=cache)
    assert (cache.misses, cache.hits) == (1, 1)
    for kind in ("live", "smoothed", "pdr"):
        for col in ("t", "x", "y", "floor"):
            np.testing.assert_array_equal(getattr(first, kind)[col], getattr(again, kind)[col])
    assert len(first.scored()) >= 4 and first.errors("live") is not None
    # another pipeline setting is another entry, not a stale replay
    other = apply_overrides(settings, (("pipeline.profile.coefficients.b", 0.30),))
    run_ipin(walks[0], CFG, k, True, other, pdr_cache=cache)
    assert cache.misses == 2


def test_routes_and_overrides():
    assert route_of("x/IPIN2023_T3_TrainingTrial24_repetition03.txt.gz") == "24"
    assert route_of("IPIN2023_T3_TrainingTrial53_repetition01.mat") == "53"
    assert route_of("walk.txt") == "walk.txt"
    s = tracker_settings_for(CFG)
    t = apply_overrides(s, (("pipeline.profile.coefficients.b", 0.2), ("fusion.turn_walk", 0.01)))
    assert t.pipeline.profile.coefficients == {"a": 0.25, "b": 0.2} and t.fusion.turn_walk == 0.01
    assert s.fusion is None and s.pipeline.profile.coefficients["b"] == 0.22  # untouched
    with pytest.raises(KeyError, match="nope"):
        apply_overrides(s, (("fusion.nope", 1.0),))
    with pytest.raises(KeyError, match="c"):
        apply_overrides(s, (("pipeline.profile.coefficients.c", 1.0),))


def test_each_route_is_scored_with_the_setting_chosen_on_the_others(walks):
    grid = (Candidate("short", (("pipeline.profile.coefficients.b", 0.15),)),
            Candidate("default", (("pipeline.profile.coefficients.b", 0.22),)),
            Candidate("long", (("pipeline.profile.coefficients.b", 0.30),)))
    settings = tracker_settings_for(CFG)
    res = cross_validate(walks, CFG, 0, False, settings, grid=grid)
    assert res.routes == ["07", "07", "08"]
    for route, chosen in res.chosen.items():
        others = [i for i, r in enumerate(res.routes) if r != route]
        p75 = {c.name: summary(res.errors(c.name, "live", others))["p75_m"] for c in grid}
        assert chosen == min(p75, key=p75.get)
    rep = report(res, default_candidate(settings, grid))
    assert rep["defaults"]["setting"] == "default"
    held = [e for es in res.held_out("live").values() for e in es]
    assert rep["pooled"]["live"] == summary(held)
    assert rep["in_sample"]["setting"] == min(grid, key=lambda c: summary(res.errors(c.name, "live"))["p75_m"]).name
    assert [w["route"] for w in rep["walks"]] == res.routes
    for w in rep["walks"]:
        assert w["live_minus_pdr_m"] == pytest.approx(w["live_p75_m"] - w["pdr_p75_m"])
    json.dumps(rep)  # plain data


@pytest.mark.recording
def test_eval_ipin_cv_on_real_walks_with_a_folder_glob(shared_data, tmp_path):
    from typer.testing import CliRunner

    from client.cli import app

    folder = shared_data("ipin2023")
    picks = [folder / n for n in ("IPIN2023_T3_TrainingTrial04_repetition01.txt.gz",
                                  "IPIN2023_T3_TrainingTrial21_repetition01.txt.gz",
                                  "IPIN2023_T3_TrainingTrial53_repetition02.mat", "Map_Floor_-01.png")]
    r = CliRunner().invoke(app, ["eval", "ipin", *map(str, picks), "--cv", "--json", "--plot", str(tmp_path)])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["headline"].startswith("cross-validated")
    assert rep["p75_m"] == rep["cv"]["pooled"]["live"]["p75_m"] and rep["in_sample_p75_m"] > 0
    assert {x["route"] for x in rep["cv"]["routes"]} == {"04", "21", "53"}
    assert rep["floor_accuracy"] == 1.0
    assert len(list(tmp_path.glob("*.png"))) == 3
