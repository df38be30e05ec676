"""Shortcuts on the per-sample and per-step paths give the answers of the long way, bit for bit.

Each shortcut (issue 29: CPU per responder-second) claims to decide or compute exactly what the
code it stands in front of would: the stillness test's running sums rule on σ only where the
two-pass σ agrees (:func:`pdr.window_kernels._sigma_verdict`), the steps' sample buffer grows
in place with the rows :func:`pdr.fleet_buffers.keep_after` would give, numpy's mean without its
wrapper and the standing attitude's sums are numpy's and ``row_dot``'s own. Here each is run
against the long way on random inputs built to sit on the edges (σ at its limit to 1e-6, signed
zeros, buffers out of order).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr import grip
from pdr.fixed_order import mean0, row_dot
from pdr.fleet_buffers import keep_after, kept_with_room
from pdr.window_kernels import _sigma_verdict

LIMITS = np.array([0.005, 0.005, 0.005, 0.15])


def _two_pass_sd(w: np.ndarray) -> np.ndarray:
    """σ per column, summed oldest first as still_bias does."""
    out = []
    for c in range(w.shape[1]):
        s = 0.0
        for v in w[:, c].tolist():
            s += v
        mu = s / len(w)
        ss = 0.0
        for v in w[:, c].tolist():
            ss += (v - mu) * (v - mu)
        out.append(math.sqrt(ss / len(w)))
    return np.array(out)


@pytest.mark.bitexact
def test_the_running_sums_rule_on_sigma_only_where_the_two_pass_sigma_agrees():
    rng = np.random.default_rng(29)
    ruled = 0
    for _ in range(1500):
        n = int(rng.integers(2, 200))
        f = rng.choice([0.3, 0.99, 0.999999, 1.0, 1.000001, 1.01, 3.0])
        X = np.column_stack([rng.normal(0, 1, (n, 3)) * LIMITS[:3] * f + rng.normal(0, 0.003),
                             9.8 + rng.normal(0, 1, n) * LIMITS[3] * f])
        if rng.random() < 0.2:  # σ exactly the limit: two values, alternating
            X[:, 0] = np.where(np.arange(n) % 2, LIMITS[0], -LIMITS[0]) * f
        lo = int(rng.integers(0, n - 1))  # the window: samples lo..n-1 of the call's n
        shift = X[0]
        y = X - shift
        t1, t2 = np.abs(y).sum(axis=0), (y * y).sum(axis=0)
        w1, w2 = np.zeros(4), np.zeros(4)
        for i in range(n):  # as still_bias keeps them: in as a sample enters, out as it leaves
            w1 += y[i]
            w2 += y[i] * y[i]
        for i in range(lo):
            w1 -= y[i]
            w2 -= y[i] * y[i]
        verdict = _sigma_verdict(w1, w2, t1, t2, n - lo, LIMITS)
        below = _two_pass_sd(X[lo:]) < LIMITS
        if verdict > 0:
            assert below.all()
        elif verdict < 0:
            assert not below.all()
        ruled += verdict != 0
    assert ruled > 1000  # it does rule, far from the limits


@pytest.mark.bitexact
def test_the_steps_sample_buffer_grows_in_place_with_the_rows_keep_after_gives():
    rng = np.random.default_rng(7)
    buf, base, end = np.empty((0, 12)), np.empty((0, 12)), -1
    ref = np.empty((0, 12))
    copies = 0
    t = 0.0
    for k in range(400):
        n = int(rng.integers(1, 15))
        rows = rng.normal(size=(n, 12))
        rows[:, 0] = t + np.cumsum(rng.uniform(0.005, 0.015, n))
        if k % 97 == 50:  # a buffer out of time order: not a suffix
            rows[0, 0] = t - 10.0
        t = float(rows[-1, 0])
        lim = float(rows[0, 0]) - 0.6
        want = keep_after(ref, lim, n)
        want[want.shape[0] - n:] = rows
        before = base
        buf, base, end = kept_with_room(buf, base, end, lim, n)
        buf[buf.shape[0] - n:] = rows
        copies += base is not before
        assert buf.tobytes() == want.tobytes() and buf.base is not None and end <= base.shape[0]
        ref = want
    assert copies < 100  # most frames wrote in place
    # a buffer that is not the view it claims to be is copied, not trusted
    stranger = ref.copy()
    stranger[-1, 0] += 1.0
    got, _, _ = kept_with_room(stranger, base, end, -math.inf, 0)
    assert got.tobytes() == stranger.tobytes()


@pytest.mark.bitexact
def test_numpys_mean_and_the_standing_sums_without_their_wrappers_are_the_same_bits():
    rng = np.random.default_rng(3)
    for _ in range(3000):
        n, k = int(rng.integers(1, 700)), int(rng.integers(1, 13))
        a = rng.normal(0, rng.choice([1e-3, 1.0, 1e6]), (n, k))
        col = a[int(rng.integers(0, n)):, int(rng.integers(0, k))]  # strided, as the buffers' columns
        assert np.float64(np.mean(col)).tobytes() == np.float64(mean0(col)).tobytes()
        assert a.mean(axis=0).tobytes() == mean0(a).tobytes()
        v = col.copy()
        v[int(rng.integers(0, len(v)))] = -0.0
        assert np.float64(row_dot(v, v)).tobytes() == np.float64(grip._sum_squares(v)).tobytes()
        x, y = rng.normal(size=3), rng.normal(size=3)
        assert np.float64(row_dot(x, y)).tobytes() == np.float64(grip._dot(x, y)).tobytes()
        c = np.clip(math.cos(0.2) + rng.normal(0, rng.choice([1e-16, 1e-9, 1e-3]), n), -1.0, 1.0)
        first = next((i for i in range(1, n) if math.acos(float(c[i])) >= 0.2), n)
        assert grip._settled_run(c, 0.2) == first
