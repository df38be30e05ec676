"""examples/ runs as written on a real IPIN walk: the plot is written, and the track has a pose
for every step the PDR pipeline takes from the walk's first landmark on."""
from __future__ import annotations

import runpy
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from pdr.events import StepEvent
from pdr.floors import FloorElevations
from pdr.io import load
from pdr.pipeline import PdrPipeline, frames_of, run_pipeline
from tests.conftest import shared_data_path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
WALK = "ipin2023/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"


@pytest.fixture(scope="module")
def walk():
    """The walk's path and the steps the pipeline takes after its first landmark, run here
    directly with the pipeline's defaults and frames of another size than the example's."""
    path = shared_data_path(WALK)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = load(path)
    imu = rec.imu_samples()
    pipeline = PdrPipeline(floors=FloorElevations.uniform(3.0, -2, 0), start_floor=int(rec.landmarks.floor[0]))
    events = run_pipeline(pipeline, frames_of(imu.t, imu.acc, imu.gyr, imu.mag, rec.pressure.t,
                                              rec.pressure.values[:, 0], per_frame=50))
    steps = [e for e in events if isinstance(e, StepEvent) and e.t >= rec.landmarks.t[0]]
    assert len(steps) > 100
    return path, steps, rec.landmarks


def _run(script: str, *args: str) -> dict:
    """The example run as ``python examples/<script> args...``, in this process."""
    argv, path = sys.argv, list(sys.path)
    sys.argv, sys.path = [str(EXAMPLES / script), *args], [str(EXAMPLES), *sys.path]
    try:
        return runpy.run_path(str(EXAMPLES / script), run_name="__main__")
    finally:
        sys.argv, sys.path[:] = argv, path


def _is_png(path: Path) -> bool:
    return path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


def test_track_a_walk_plots_a_position_for_every_step_of_the_pipeline(walk, tmp_path, capsys):
    path, steps, _ = walk
    out = tmp_path / "track.png"
    track = _run("track_a_walk.py", str(path), "--out", str(out))["track"]
    assert _is_png(out)
    assert len(track) == len(steps)
    assert np.array_equal(track[:, 0], [s.t for s in steps])  # the declination turns the track, not the steps
    walked = np.hypot(*np.diff(track[:, 1:3], axis=0).T)
    assert np.allclose(walked, [s.length for s in steps[1:]])
    assert f"{len(steps)} steps" in capsys.readouterr().out


def test_fuse_a_walk_solves_one_pose_a_step_and_holds_the_checkpoints(walk, tmp_path):
    pytest.importorskip("gtsam")
    path, steps, landmarks = walk
    out = tmp_path / "fused.png"
    r = _run("fuse_a_walk.py", str(path), "--every", "3", "--out", str(out))["r"]
    assert _is_png(out)
    assert r["steps"] == len(steps) and r["poses"] == len(steps) + 1
    assert list(r["checkpoints"]) == list(range(3, len(landmarks), 3))
    fused = r["xy"]["fused"][r["checkpoint_poses"]]
    held = np.hypot(*(fused - r["landmarks"][r["checkpoints"]]).T)
    assert np.all(held < 1.5), held  # checkpoint sigma 0.5 m, plus the walk to the pose before it
    assert np.median(r["error"]["fused"]) < np.median(r["error"]["pdr"])
