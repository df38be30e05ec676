r"""The detector's input put back on a uniform clock: samples taken at irregular times, resampled.

A digital filter designed at rate :math:`f_s` assumes its samples are :math:`1/f_s` apart.
A browser breaks that: Chromium fires ``devicemotion`` from a 60 Hz timer whose ticks
wander (measured in the browser walk test, tests/test_phone_browser.py: intervals 10-24 ms
for the 5-95 % quantiles around a 16 ms median), and each event carries the sensor's
reading *at that tick*. Filtered as if evenly spaced, the walk's acceleration is read at
the wrong times: an error of :math:`\dot a\,\delta t`, with a jerk of tens of m/s³ and
:math:`\delta t` of a few ms, a few tenths of m/s² before the band-pass and about
0.05-0.09 m/s² (one standard deviation) at the filtered peaks after it. That is enough to
lift a bounce just under the detector's 0.5 m/s² floor over it, and the browser walk
counted a step the file does not have (107 or 108 of 106).

So before filtering, the samples are interpolated linearly onto the grid
:math:`g_m = g_0 + m / f_s` (:math:`m = 0, 1, \dots`; :math:`g_0` the first sample's time,
:math:`f_s` the detector's estimated rate). A grid point :math:`g` between samples
:math:`(t_i, a_i)` and :math:`(t_{i+1}, a_{i+1})` takes

.. math:: a(g) = a_i + (a_{i+1} - a_i)\,\frac{g - t_i}{t_{i+1} - t_i}.

Streaming: a grid point is made once the sample after it has arrived, so any batching
gives the same points. Samples not after the previous one are dropped. Two samples more
than ``max_gap_s`` apart are a gap, not jitter: the grid restarts at the later sample (the
stream is then filtered as if contiguous, as before). On an evenly sampled stream the grid
falls within a fraction of an interval of the samples, and the values barely change.

The compiled engine (:func:`pdr.detector_kernels.onto_grid`) does the same arithmetic in
the same order, so both give the same numbers bit for bit.
"""
from __future__ import annotations

import math

import numpy as np


class UniformClock:
    """Streaming linear resampling onto ``g0 + m / rate`` (module docstring)."""

    def __init__(self, rate_hz: float, max_gap_s: float):
        self.rate = float(rate_hz)
        self.max_gap_s = float(max_gap_s)
        self.g0 = math.nan  # grid origin (s); nan until the first sample
        self.m = 0.0  # index of the next grid point
        self.t_prev = math.nan  # the last sample kept
        self.a_prev = math.nan

    def push(self, t: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``t`` (s, increasing) and ``a`` -> the grid points they complete: (times, values)."""
        if t.size == 0:
            return t, a
        if math.isnan(self.t_prev):
            self.g0, self.m, self.t_prev, self.a_prev = float(t[0]), 0.0, float(t[0]), float(a[0])
            t, a = t[1:], a[1:]
            out_t, out_a = [np.array([self.g0])], [np.array([self.a_prev])]
            self.m = 1.0
        else:
            out_t, out_a = [], []
        keep = t > np.maximum.accumulate(np.concatenate(([self.t_prev], t[:-1])))
        t, a = t[keep], a[keep]
        if t.size == 0:
            return _joined(out_t), _joined(out_a)
        ts = np.concatenate(([self.t_prev], t))
        av = np.concatenate(([self.a_prev], a))
        gaps = np.flatnonzero(np.diff(ts) > self.max_gap_s)
        start = 0
        for end in [*gaps, ts.size - 1]:  # runs ts[start..end] without a gap, then a restart at end + 1
            self._run(ts[start : end + 1], av[start : end + 1], out_t, out_a)
            if end < ts.size - 1:
                self.g0, self.m = float(ts[end + 1]), 1.0
                out_t.append(ts[end + 1 : end + 2])
                out_a.append(av[end + 1 : end + 2])
            start = end + 1
        self.t_prev, self.a_prev = float(ts[-1]), float(av[-1])
        return _joined(out_t), _joined(out_a)

    def _run(self, ts: np.ndarray, av: np.ndarray, out_t: list, out_a: list) -> None:
        """Grid points from ``self.m`` on up to ``ts[-1]`` over samples ``ts``, ``av``."""
        if ts.size < 2:
            return
        last = int(math.floor((ts[-1] - self.g0) * self.rate)) + 1
        m = np.arange(self.m, max(last, self.m) + 1.0)
        g = self.g0 + m / self.rate
        g = g[g <= ts[-1]]
        if g.size == 0:
            return
        i = np.searchsorted(ts, g, side="right") - 1
        inner = i < ts.size - 1
        j = np.where(inner, i, 0)
        val = np.where(inner, av[j] + (av[j + 1] - av[j]) * ((g - ts[j]) / (ts[j + 1] - ts[j])), av[-1])
        out_t.append(g)
        out_a.append(val)
        self.m = m[g.size - 1] + 1.0


def _joined(parts: list) -> np.ndarray:
    return np.concatenate(parts) if parts else np.empty(0)
