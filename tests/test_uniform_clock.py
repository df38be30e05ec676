"""The step detector's uniform clock (pdr.steps.uniform): irregular sample times resampled before
the filter, the same in the batch detector and the compiled engine, in any batching."""
from __future__ import annotations

import numpy as np
import pytest

from pdr import detector_kernels as DK
from pdr.steps.uniform import UniformClock

RATE = 60.0


def _browser_times(n: int, seed: int, sd_s: float = 0.0045, gaps=()) -> np.ndarray:
    """Ticks of a 60 Hz timer that wanders (sd ``sd_s`` per interval, as Chromium's devicemotion
    in tests/test_phone_browser.py), with pauses ``(index, s)``."""
    rng = np.random.default_rng(seed)
    dt = np.clip(rng.normal(1 / RATE, sd_s, n), 0.003, None)
    for i, s in gaps:
        dt[i] = s
    return 10.0 + np.cumsum(dt)


def _batches(n: int, seed: int) -> list[slice]:
    cuts = np.sort(np.random.default_rng(seed).choice(np.arange(1, n), 40, replace=False))
    return [slice(a, b) for a, b in zip([0, *cuts], [*cuts, n])]


def _kernel_clock(t, a, parts, max_gap):
    det = np.full((1, DK.D_STATE), np.nan)
    det[0, DK.D_RATE], det[0, DK.D_GM] = RATE, 0.0
    got = [DK.onto_grid(t[s].copy(), a[s].copy(), det, 0, max_gap) for s in parts]
    return np.concatenate([g for g, _ in got]), np.concatenate([v for _, v in got])


@pytest.mark.bitexact
def test_the_clock_gives_the_same_points_in_any_batching_and_in_the_compiled_engine():
    t = _browser_times(3000, 1, gaps=[(700, 0.5), (701, 0.0), (1500, 1.3)])  # one sample twice, two gaps
    a = np.sin(2 * np.pi * 1.8 * t) + np.random.default_rng(2).normal(0, 0.1, t.size)
    whole = UniformClock(RATE, 0.2).push(t, a)
    clock = UniformClock(RATE, 0.2)
    parts = [clock.push(t[s], a[s]) for s in _batches(t.size, 3)]
    batched = (np.concatenate([g for g, _ in parts]), np.concatenate([v for _, v in parts]))
    compiled = _kernel_clock(t, a, _batches(t.size, 4), 0.2)
    for got in (batched, compiled):
        assert np.array_equal(got[0], whole[0]) and np.array_equal(got[1], whole[1])
    g = whole[0]
    dg = np.diff(g)
    # evenly spaced except where the gaps restart the grid (at the sample after each gap)
    assert np.sum(np.abs(dg - 1 / RATE) > 1e-9) == 2 and np.all(dg > 0)
    assert set(np.round(g[1:][np.abs(dg - 1 / RATE) > 1e-9], 9)) == {round(t[700], 9), round(t[1500], 9)}
    # every point lies on the straight line between its two samples
    kept = np.delete(np.arange(t.size), 701)  # (the second of two samples at one time is dropped)
    assert np.allclose(whole[1], np.interp(g, t[kept], a[kept]), atol=1e-12)
