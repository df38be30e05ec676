"""A walker standing still sees the same field epoch after epoch (issue 27: a stand in steel, or
beside the engine, before the walk). The compass error is a property of the place, so a stand's
epochs are one piece of evidence about δ, not one per epoch: δ_m = δ + d + v with d held for
the stand (:meth:`pdr.heading.HeadingEstimator._innovation`). The heading's σ then says how
little a stand proved, and the walk's clean field corrects δ within seconds."""
from __future__ import annotations

import math
import pickle

import numpy as np

from pdr.heading import HeadingEstimator, HeadingSettings, wrap
from pdr.heading_kernels import EPOCH_STATE
from pdr.synthetic import FIELD_ENU
from tests.test_heading import _rotated_field, deg, walk

STAND_S = 40.0


def _stand_then_walk(turned_deg: float = 50.0):
    """40 s standing where the field is turned ``turned_deg`` (strength as usual), then a
    straight walk in the clean field."""
    bad = _rotated_field(turned_deg)
    field = lambda t: np.where((t < STAND_S)[:, None], bad, FIELD_ENU)  # noqa: E731
    t, acc, gyr, mag, truth, steps = walk(lambda t: 0.0 * t, 70.0, field=field, bounce=lambda t: t >= STAND_S)
    return t, acc, gyr, mag, truth, steps[steps > STAND_S]


def _run(settings, t, acc, gyr, mag, truth, steps):
    r = HeadingEstimator(settings).update(t, acc, gyr, mag, steps)
    return r.t, np.abs(deg(wrap(r.heading - np.interp(r.t, t, np.unwrap(truth))))), deg(r.heading_sigma)


def test_a_stand_in_a_bent_field_is_one_piece_of_evidence_and_the_walk_corrects_it_at_once():
    data = _stand_then_walk()
    t, err, sigma = _run(HeadingSettings(), *data)
    first = t < STAND_S + 1.0
    assert err[first].max() > 15.0  # the stand's field set δ: the walk begins off
    assert sigma[first].min() > 12.0  # ... and says so: 40 s of one place proved little
    assert err[(t > STAND_S + 4.0) & (t < STAND_S + 10.0)].max() < 12.0
    # every epoch of the stand taken as new evidence: the heading claims 7° and is 30-45° off
    t0, err0, sigma0 = _run(HeadingSettings(stand_acc_std=0.0), *data)
    assert sigma0[t0 < STAND_S + 1.0].max() < 8.0
    assert err0[(t0 > STAND_S + 4.0) & (t0 < STAND_S + 5.0)].min() > 25.0


def test_a_stand_in_the_clean_field_keeps_the_heading():
    t, err, _ = _run(HeadingSettings(), *_stand_then_walk(turned_deg=0.0))
    assert err.max() < 5.0


def test_an_estimator_pickled_before_stands_were_told_apart_goes_on():
    """A snapshot from before this change: the open epoch's sums without ‖f‖, no stand state."""
    t, acc, gyr, mag, truth, steps = _stand_then_walk()
    half = t < 55.0
    est = HeadingEstimator()
    est.update(t[half], acc[half], gyr[half], mag[half], steps[steps < 55.0])
    old = pickle.loads(pickle.dumps(est))
    old._epoch_state = old._epoch_state[:8].copy()
    for k in [k for k in vars(old) if k.startswith("_stand")]:
        delattr(old, k)
    r = old.update(t[~half], acc[~half], gyr[~half], mag[~half], steps[steps >= 55.0])
    assert old._epoch_state.size == EPOCH_STATE and len(r) > 0
    err = np.abs(deg(wrap(r.heading - np.interp(r.t, t, np.unwrap(truth)))))
    assert np.isfinite(err).all() and err.max() < 5.0 and math.isnan(HeadingEstimator._stand_psi)
