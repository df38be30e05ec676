"""The filters on the real Vicon recording of the firefighter dissertation (skipped when absent).

Measured with the shipped defaults: FSCF 4.14°, Madgwick 4.66° whole-recording MAE. The
published 3.37° / 3.90° do not reproduce on this file with the published algorithms (the
Vicon-to-IMU timing drifts by ±0.1 s within the fast-rotation part; see the issue notes), so
these tests guard the measured figures and the ranking, not the published ones.
"""
import pytest

from pdr.evaluation.orientation import score_orientation
from pdr.io import load

pytestmark = pytest.mark.recording


@pytest.fixture(scope="module")
def justa(request):
    from tests.conftest import shared_data_path

    return load(shared_data_path("ahrs-vicon/Justa_dataset.mat"))


def test_fscf_beats_madgwick_with_shipped_defaults(justa):
    fscf = score_orientation(justa, "fscf")
    madgwick = score_orientation(justa, "madgwick")
    assert fscf.mae_deg < 4.3
    assert fscf.mae_deg < madgwick.mae_deg - 0.3
    assert fscf.rmse_deg < madgwick.rmse_deg


def test_exact_and_fast_forms_agree(justa):
    """Justa 2022: SCF and FSCF were identical to the reported digits."""
    assert abs(score_orientation(justa, "scf").mae_deg - score_orientation(justa, "fscf").mae_deg) < 0.05


def test_slow_rotations_are_tracked_within_three_degrees(justa):
    assert score_orientation(justa, "fscf", samples=slice(0, 2799)).mae_deg < 3.0
