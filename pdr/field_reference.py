"""The magnetic field a compass epoch is compared with: configured (e.g. the WMM's) or learned on the walk.

:class:`pdr.heading.HeadingEstimator` weighs each compass epoch by how far its field strength
|B| and dip I lie from a reference (``σ_m² = … + (k_n Δ|B|)² + (k_I ΔI)²``). A configured
reference (``field_norm``, ``field_inclination``) holds from the first sample. Otherwise the
reference is learned: the median |B| and I of the *usable* epochs (δ spread below the gate,
the phone not waved) since the stream began, logged after each such epoch once
``reference_min_s`` of the stream have passed, and fixed at the end of the first
``reference_seconds``. An epoch or a step at time ``t`` is judged against the reference as it
stood after the epochs that ended before ``t`` — never a later one, so a steel door at the
first landmark is weighed against the field the walker had before it (issue 27: before, the
first 60 s were not weighed at all), and one large batch and many small ones agree.
"""
from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np


class FieldReference:
    """``learn(t0, t_end, norm, inc, usable)`` per batch of closed epochs; ``at(t)`` -> (|B|, I)."""

    def __init__(self, settings):
        self.settings = s = settings
        self.norm, self.inclination = s.field_norm, s.field_inclination  # fixed values (NaN: learning)
        self._win: deque = deque()  # usable epochs of the window: (end, |B|, I)
        self._log: list[tuple[float, float, float]] = []  # the reference after each usable epoch: (end, |B|, I)

    def learn(self, t0: float | None, t_end, nrm, inc_m, usable) -> None:
        s = self.settings
        if (np.isfinite(self.norm) and np.isfinite(self.inclination)) or t0 is None:
            return
        end = t0 + s.reference_seconds
        for i in np.flatnonzero((t_end <= end) & usable & np.isfinite(nrm)):
            self._win.append((float(t_end[i]), float(nrm[i]), float(inc_m[i])))
            if t_end[i] - t0 >= s.reference_min_s:
                a = np.array(self._win)
                self._log.append((float(t_end[i]), float(np.median(a[:, 1])), float(np.median(a[:, 2]))))
        if not (t_end <= end).all():  # the window is over: fix the medians
            last = self._log[-1] if self._log else (math.nan, math.inf, math.inf)
            self.norm = s.field_norm if np.isfinite(s.field_norm) else last[1]
            self.inclination = s.field_inclination if np.isfinite(s.field_inclination) else last[2]
            self._win.clear()

    def at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(|B| µT, I rad) per time ``t``: NaN where nothing is known yet (no weight)."""
        s = self.settings
        t = np.atleast_1d(np.asarray(t, float))
        ref_n, ref_i = np.full(t.shape, math.nan), np.full(t.shape, math.nan)
        if self._log:
            log = np.array(self._log)
            k = np.searchsorted(log[:, 0], t - 1e-6, side="right") - 1  # epochs that ended before t
            ref_n = np.where(k >= 0, log[np.maximum(k, 0), 1], math.nan)
            ref_i = np.where(k >= 0, log[np.maximum(k, 0), 2], math.nan)
        if np.isfinite(s.field_norm):
            ref_n[:] = s.field_norm
        if np.isfinite(s.field_inclination):
            ref_i[:] = s.field_inclination
        return ref_n, ref_i

    def prune(self, limit: float) -> None:
        """Forget what no time after ``limit`` can ask for (the last entry before it stays)."""
        k = bisect.bisect_left(self._log, (limit,)) - 1
        if k > 0:
            del self._log[:k]
