"""The per-responder PDR pipeline: batch invariance, motion state, floors, and the IPIN eval."""
from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

from pdr.events import MotionEvent, MotionState, StepEvent
from pdr.floors import FloorElevations
from pdr.height import pressure_at_height
from pdr.pipeline import ImuFrame, PdrPipeline, frames_of, run_pipeline
from pdr.synthetic import static_imu

IPIN_TRIAL52 = "ipin2023/IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"


def events_close(a, b, tol=0.0) -> bool:
    """Same events, numbers equal to ``tol`` (NaN equals NaN; 0: bit for bit)."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if type(x) is not type(y):
            return False
        for name in x.__dataclass_fields__:
            u, v = getattr(x, name), getattr(y, name)
            if isinstance(u, float):
                if not (math.isclose(u, v, rel_tol=0, abs_tol=tol) or (math.isnan(u) and math.isnan(v)) or u == v):
                    return False
            elif u != v:
                return False
    return True


def split(events):
    return [e for e in events if isinstance(e, StepEvent)], [e for e in events if isinstance(e, MotionEvent)]


@pytest.fixture(scope="module")
def trial52():
    from pdr.io import load
    from tests.conftest import shared_data_path

    path = shared_data_path(IPIN_TRIAL52)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = load(path)
    imu = rec.imu_samples()
    return rec, imu


def _run(rec, imu, per_frame):
    floors = FloorElevations.uniform(3.0, -2, 0)
    p = PdrPipeline(floors=floors, start_floor=int(rec.landmarks.floor[0]))
    return run_pipeline(p, frames_of(imu.t, imu.acc, imu.gyr, imu.mag, rec.pressure.t, rec.pressure.values[:, 0],
                                      per_frame=per_frame))


@pytest.mark.bitexact
@pytest.mark.recording
def test_live_frames_give_the_same_events_as_one_batch(trial52):
    rec, imu = trial52
    whole = split(_run(rec, imu, 10**9))
    for per_frame in (10, 37, 700):  # 700: several seconds, as the service joins frames when behind
        part = split(_run(rec, imu, per_frame))
        assert events_close(whole[0], part[0]), f"step events differ with frames of {per_frame}"
        assert events_close(whole[1], part[1]), f"motion events differ with frames of {per_frame}"
    steps, motion = whole
    assert len(steps) > 200
    assert [e.index for e in steps] == list(range(1, len(steps) + 1))
    assert all(np.isfinite(e.heading) and e.length > 0 and e.length_sigma > 0 for e in steps)
    assert {m.state for m in motion} >= {MotionState.WALKING, MotionState.STILL}


@pytest.mark.recording
def test_floor_changing_walk_follows_the_landmark_floors(trial52):
    rec, imu = trial52
    steps, _ = split(_run(rec, imu, 50))
    t = np.array([e.t for e in steps])
    fl = np.array([e.floor for e in steps])
    lm = rec.landmarks
    assert len(set(lm.floor.tolist())) > 1, "trial 52 changes floor"
    i = np.clip(np.searchsorted(t, lm.t, side="right") - 1, 0, None)
    assert np.all(fl[i][1:] == lm.floor[1:])
    assert any(e.on_stairs for e in steps)
    stair_len = [e.length for e in steps if e.on_stairs]
    assert max(stair_len) <= 0.56 + 1e-9  # whole treads, not a level stride


def _cuts(n: int, sizes) -> list[tuple[int, int]]:
    out, i, k = [], 0, 0
    while i < n:
        out.append((i, min(n, i + sizes[k % len(sizes)])))
        i, k = out[-1][1], k + 1
    return out


@pytest.mark.bitexact
def test_frames_of_any_mixture_of_sizes_give_the_same_events():
    """The service runs 10-sample frames one by one when idle and joins many when behind
    (up to several seconds): a simulated walk cut both ways gives the same events."""
    from pdr.simulation import SimulatedWalker

    b = SimulatedWalker("w").next_batch(6000)  # 60 s at 100 Hz

    def run(sizes):
        p = PdrPipeline()
        out = []
        for i, j in _cuts(len(b.t), sizes):
            sel = (b.pressure_t > (b.t[i - 1] if i else -np.inf)) & (b.pressure_t <= b.t[j - 1])
            out += p.update(ImuFrame(b.t[i:j], b.acc[i:j], b.gyr[i:j], b.mag[i:j], b.pressure_t[sel], b.pressure[sel]))
        return split(out + p.finish())

    steady = run([10])
    mixed = run([10, 10, 500, 30, 10, 1000, 20])
    assert len(steady[0]) > 60
    # bit for bit: a float that depended on where frames were cut could tip a threshold
    assert events_close(steady[0], mixed[0]) and events_close(steady[1], mixed[1])


def test_motionless_device_raises_no_motion_after_30_s():
    imu = static_imu(seconds=45.0, rate_hz=50.0)
    p = PdrPipeline()
    events = run_pipeline(p, frames_of(imu.t, imu.acc, imu.gyr, imu.mag, per_frame=10))
    motion = [e for e in events if isinstance(e, MotionEvent)]
    states = [m.state for m in motion]
    assert states[0] is MotionState.STILL
    nm = [m for m in motion if m.state is MotionState.NO_MOTION]
    assert len(nm) == 1
    assert 30.0 <= nm[0].t - imu.t[0] <= 31.0
    assert nm[0].since == pytest.approx(imu.t[0], abs=1.0)
    assert not any(isinstance(e, StepEvent) for e in events)


def test_a_moving_hand_is_not_no_motion():
    imu = static_imu(seconds=45.0, rate_hz=50.0)
    acc = imu.acc.copy()
    gyr = imu.gyr.copy()
    gyr[:, 2] += 0.4 * np.sin(2 * np.pi * 0.3 * imu.t)  # slow turning of the hand, no steps
    events = run_pipeline(PdrPipeline(), frames_of(imu.t, acc, gyr, imu.mag, per_frame=10))
    assert not any(isinstance(e, MotionEvent) and e.state is MotionState.NO_MOTION for e in events)


def test_frames_must_come_in_time_order():
    imu = static_imu(seconds=2.0, rate_hz=50.0)
    p = PdrPipeline()
    p.update(ImuFrame(imu.t[10:20], imu.acc[10:20], imu.gyr[10:20]))
    with pytest.raises(ValueError, match="not after the previous sample"):
        p.update(ImuFrame(imu.t[5:15], imu.acc[5:15], imu.gyr[5:15]))


def test_pressure_goes_with_the_frame_that_ends_after_it():
    t = np.arange(100) / 50.0
    pt = np.arange(0, 2.0, 0.2) + 0.01
    frames = list(frames_of(t, np.zeros((100, 3)), np.zeros((100, 3)), None, pt, np.ones(pt.size), per_frame=10))
    got = np.concatenate([f.pressure_t for f in frames])
    assert np.array_equal(got, pt)
    for f in frames[:-1]:
        assert np.all(f.pressure_t <= f.t[-1])


def test_anchor_floor_moves_height_and_floor():
    floors = FloorElevations.uniform(3.0, -2, 0)
    p = PdrPipeline(floors=floors, start_floor=0)
    imu = static_imu(seconds=5.0, rate_hz=50.0)
    pt = np.arange(0, 5.0, 0.1)
    pres = pressure_at_height(np.zeros(pt.size), 1000.0)
    p.update(ImuFrame(imu.t, imu.acc, imu.gyr, None, pt, pres))
    assert p.floor == 0
    p.anchor_floor(-2)
    assert p.floor == -2
    assert p.height == pytest.approx(-6.0)


@pytest.mark.recording
def test_eval_ipin_command_scores_landmarks(trial52, tmp_path):
    from client.cli import app
    from tests.conftest import shared_data_path

    path = shared_data_path(IPIN_TRIAL52)
    r = CliRunner().invoke(app, ["eval", "ipin", str(path), "--engine", "dr", "--json", "--plot", str(tmp_path)])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["n_eval"] == len(trial52[0].landmarks) - 1
    assert rep["floor_accuracy"] == 1.0
    assert 0 < rep["median_m"] <= rep["p75_m"] < 30
    assert rep["files"][0]["n_eval"] == rep["n_eval"]
    assert list(tmp_path.glob("*.png"))
