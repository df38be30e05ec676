"""Step-length models, their calibration and the responder profile (pdr.step_length)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pdr.events import StepDetection
from pdr.step_length import (
    MODELS,
    ResponderProfile,
    calibrate,
    default_coefficients,
    step_arrays,
    step_frequency,
    step_lengths,
)


def steps_of(a_max, a_min, a_mean=0.0, a_mean_abs=1.0, duration=0.5):
    """Detections with the given statistics (scalars broadcast)."""
    a_max, a_min, a_mean, a_mean_abs, duration = np.broadcast_arrays(*np.atleast_1d(a_max, a_min, a_mean, a_mean_abs, duration))
    t = np.cumsum(duration)
    return [StepDetection(float(ti), float(ti - d), float(x), float(n), float(m), float(b))
            for ti, d, x, n, m, b in zip(t, duration, a_max, a_min, a_mean, a_mean_abs)]


def length(model, steps, **coefficients):
    return step_lengths(steps, ResponderProfile.with_model(model, coefficients=coefficients or default_coefficients(model)))


def test_weinberg_both_readings_of_the_thesis():
    steps = steps_of(a_max=[10.0, 1.0], a_min=[-6.0, -15.0])  # swing 16: fourth root 2
    assert length("weinberg", steps) == pytest.approx([2 * 0.828] * 2)  # eq. 3.6, K = 0.828
    assert length("weinberg_subtractive", steps) == pytest.approx([2 - 0.828] * 2)  # eq. 3.11 as printed
    assert length("weinberg_modified", steps, k1=0.5, k2=0.1) == pytest.approx([0.9] * 2)  # eq. 3.7


def test_kim_scarlett_frequency_height():
    steps = steps_of(a_max=4.0, a_min=0.0, a_mean=1.0, a_mean_abs=8.0, duration=0.5)
    assert length("kim", steps, k=0.5) == pytest.approx([1.0])  # K cbrt(8)
    assert length("scarlett", steps, k=2.0) == pytest.approx([0.5])  # K (1 - 0) / (4 - 0)
    assert length("frequency", steps, a=0.3, b=0.2) == pytest.approx([0.7])  # a + b * 2 Hz
    profile = ResponderProfile.with_model("height", height_m=1.8, coefficients={"k": 0.415})
    assert step_lengths(steps, profile) == pytest.approx([0.747])


def test_degenerate_steps_give_finite_lengths():
    flat = steps_of(a_max=1.0, a_min=1.0, a_mean=1.0, duration=0.0)
    for model in MODELS:
        assert np.isfinite(length(model, flat)).all(), model
    assert step_frequency([0.0, 0.5]) == pytest.approx([4.0, 2.0])
    assert step_lengths([], ResponderProfile()).shape == (0,)


def test_defaults_are_an_adult_stride():
    profile = ResponderProfile()
    for cadence in (1.8, 1.9, 2.0):
        (sl,) = step_lengths(steps_of(3.0, -3.0, duration=1 / cadence), profile)
        assert 0.60 <= sl <= 0.75  # an adult step at 1.8-2 Hz: 0.6-0.75 m
    (sl,) = step_lengths(steps_of(3.0, -3.0), ResponderProfile.with_model("height"))
    assert sl == pytest.approx(0.415 * 1.75)


def test_vectorised_over_many_steps():
    rng = np.random.default_rng(0)
    n = 100_000
    x = {"a_max": rng.uniform(1, 6, n), "a_min": rng.uniform(-6, -1, n), "a_mean": rng.normal(0, 0.2, n),
         "a_mean_abs": rng.uniform(0.5, 3, n), "duration": rng.uniform(0.4, 0.7, n)}
    for model in MODELS:
        out = step_lengths(x, ResponderProfile.with_model(model))
        assert out.shape == (n,) and np.isfinite(out).all()
    one = steps_of(x["a_max"][:3], x["a_min"][:3], x["a_mean"][:3], x["a_mean_abs"][:3], x["duration"][:3])
    arrays = step_arrays(one)
    np.testing.assert_allclose(arrays["duration"], x["duration"][:3])
    np.testing.assert_allclose(step_lengths(one, ResponderProfile.with_model("kim")),
                               step_lengths({k: v[:3] for k, v in x.items()}, ResponderProfile.with_model("kim")))


def _walks(rng, n_walks=6, steps_per_walk=40):
    """Random walks at different paces: (step arrays, none of them with a length yet)."""
    walks = []
    for w in range(n_walks):
        pace = 1.5 + 0.15 * w
        n = steps_per_walk
        walks.append({
            "a_max": rng.uniform(1, 3, n) * pace, "a_min": -rng.uniform(1, 3, n) * pace,
            "a_mean": rng.normal(0, 0.3, n), "a_mean_abs": rng.uniform(0.8, 2.0, n) * pace,
            "duration": 1 / rng.normal(pace, 0.05, n),
        })
    return walks


TRUE = {
    "weinberg": {"k": 0.47},
    "weinberg_subtractive": {"k": 0.9},
    "weinberg_modified": {"k1": 0.6, "k2": 0.2},
    "kim": {"k": 0.52},
    "scarlett": {"k": 1.3},
    "frequency": {"a": 0.21, "b": 0.27},
    "height": {"k": 0.41},
}


@pytest.mark.parametrize("model", list(MODELS))
def test_calibration_recovers_known_coefficients(model):
    rng = np.random.default_rng(1)
    truth = ResponderProfile.with_model(model, coefficients=TRUE[model], height_m=1.7)
    walks = [(x, step_lengths(x, truth).sum()) for x in _walks(rng)]
    fit = calibrate(walks, model, height_m=1.7)
    assert fit.coefficients == pytest.approx(TRUE[model], rel=1e-9)
    assert np.abs(fit.residuals_m).max() < 1e-9
    # with 1 % noise on each walk's length the fit stays close
    noisy = [(x, d * (1 + 0.01 * rng.standard_normal())) for x, d in walks]
    approx = calibrate(noisy, model, height_m=1.7).coefficients
    got = step_lengths(walks[0][0], ResponderProfile.with_model(model, coefficients=approx, height_m=1.7)).sum()
    assert got == pytest.approx(walks[0][1], rel=0.03)


def test_calibration_needs_enough_walks():
    x = _walks(np.random.default_rng(2), n_walks=1)[0]
    with pytest.raises(ValueError, match="at least"):
        calibrate([(x, 30.0)], "frequency")
    with pytest.raises(ValueError, match="unknown step-length model"):
        calibrate([(x, 30.0)], "stride")


def test_profile_is_plain_serialisable_data():
    profile = ResponderProfile.with_model("weinberg_modified", height_m=1.82, carry="chest",
                                          coefficients={"k1": 0.7, "k2": 0.15})
    text = json.dumps(profile.to_dict())
    assert ResponderProfile.from_dict(json.loads(text)) == profile
    with pytest.raises(ValueError, match="unknown profile fields"):
        ResponderProfile.from_dict({"height": 1.8})
    with pytest.raises(ValueError, match="takes coefficients"):
        ResponderProfile(model="kim", coefficients={"a": 1.0})
    with pytest.raises(ValueError, match="height_m"):
        ResponderProfile(height_m=0.0)
