"""The shipped default filter on the real recordings of ../shared/data (skipped when absent).

Measured with the shipped defaults (docs/ahrs.md): BROAD, 14 trials, mean total RMSE 2.08°,
undisturbed 2.34°, disturbed 1.74° (VQF with its defaults 2.92°, 2.50°, 3.49°); Justa's Vicon
recording MAE 4.08° (the author's stored figure 4.12°, FSCF tuned on it 4.14°). The bounds
below are the issue's requirements (VQF's figures, the author's 4.12°), not the figures themselves.
"""
import numpy as np
import pytest

from pdr.ahrs import DEFAULT_FILTER
from pdr.evaluation.orientation import benchmark_summary, score_benchmark, score_orientation
from pdr.io import load, load_broad_groups

pytestmark = pytest.mark.recording

VQF_ANCHOR_DEG = 2.92  # VQF's mean total RMSE on these 14 trials (../shared/data/README.md)
VQF_UNDISTURBED_DEG = 2.50  # VQF's mean over the 8 undisturbed trials (firetrack eval ahrs --baseline vqf)
VQF_DISTURBED_DEG = 3.49  # and over the 6 disturbed ones
JUSTA_ANCHOR_DEG = 4.12  # the author's own stored MAE of his fast filter on Justa_dataset.mat


@pytest.fixture(scope="module")
def broad_scores():
    from tests.conftest import shared_data_path

    folder = shared_data_path("broad")
    files = sorted(folder.glob("*.mat"))
    if len(files) < 14:
        pytest.skip(f"{folder} holds {len(files)} BROAD trials, not 14")
    groups = load_broad_groups(folder / "trials.json")
    scores = [score_benchmark(load(f), DEFAULT_FILTER) for f in files]
    return benchmark_summary(scores, groups), scores


def test_default_filter_beats_vqf_on_broad(broad_scores):
    summary, _ = broad_scores
    assert summary["mean_total_rmse_deg"] < VQF_ANCHOR_DEG
    assert summary["groups"]["undisturbed"]["mean_total_rmse_deg"] < VQF_UNDISTURBED_DEG
    assert summary["groups"]["disturbed"]["mean_total_rmse_deg"] < VQF_DISTURBED_DEG


def test_magnets_do_not_drag_the_inclination_on_broad(broad_scores):
    _, scores = broad_scores
    magnets = [s for s in scores if "magnet" in s.trial]
    assert magnets and max(s.rmse_deg("inclination") for s in magnets) < 1.5


def test_default_filter_on_justa_with_the_same_defaults(shared_data):
    rec = load(shared_data("ahrs-vicon/Justa_dataset.mat"))
    s = score_orientation(rec, DEFAULT_FILTER)
    assert s.mae_deg <= JUSTA_ANCHOR_DEG  # measured 4.08°
    assert np.isfinite(s.errors_deg).all()
