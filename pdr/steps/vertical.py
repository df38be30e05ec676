"""The smartphone-fusion thesis's step detector: max/min pairs of vertical acceleration (Ryšánek, §3.5.2).

The caller rotates the accelerometer to ENU with the AHRS quaternion and removes gravity
(:func:`pdr.steps.vertical_linear_acceleration`); the detector then

1. band-passes with a **6th-order Butterworth, 0.1-3 Hz** (total order 6: three poles
   at each band edge, as a filter-design tool's "order 6" band-pass; the band drops the
   residual gravity offset and the hand's slow sway, and keeps cadences up to 3 Hz);
2. finds the local maxima and minima of the filtered signal;
3. counts one step for each maximum followed by the next minimum when

   .. math:: a_{max} - a_{min} \\ge 1.8\\ \\mathrm{m/s^2}, \\qquad
             100\\ \\mathrm{ms} \\le t_{min} - t_{max} \\le 714\\ \\mathrm{ms}.

The thesis derives the time limits from a 1-3 Hz step band with 40 % tolerance but pairs
the words with the wrong numbers (714 ms = 1 s / 1.4 comes from 1 Hz, 100 ms from 3 Hz);
the numbers are used as printed. The step is recognised at the minimum.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pdr.events import StepDetection
from pdr.steps.base import DetectorSettings, StepDetector, bandpass_sos, ordered_extrema


@dataclasses.dataclass(frozen=True)
class VerticalSettings(DetectorSettings):
    order: int = 6  # total band-pass order
    low_hz: float = 0.1  # Hz
    high_hz: float = 3.0  # Hz
    threshold: float = 1.8  # m/s², a_max - a_min of a pair
    min_pair_s: float = 0.100  # s, t_min - t_max at least
    max_pair_s: float = 0.714  # s, t_min - t_max at most


class VerticalPairDetector(StepDetector):
    """One step per max->min pair with enough swing and a plausible duration (Ryšánek §3.5.2)."""

    name = "vertical"
    Settings = VerticalSettings

    def __init__(self, settings=None):
        super().__init__(settings)
        self._max: tuple[float, float] | None = None  # (t, a) of the last maximum not yet paired

    def _design(self, fs: float) -> np.ndarray:
        s = self.settings
        return bandpass_sos(s.order, s.low_hz, s.high_hz, fs)

    def _scan(self, t, y, lo, hi) -> list[StepDetection]:
        s = self.settings
        steps = []
        for i, top in zip(*ordered_extrema(y, lo, hi)):
            if top:
                self._max = (t[i], y[i])
                continue
            if self._max is None:
                continue
            (t_max, a_max), self._max = self._max, None
            dt = t[i] - t_max
            if a_max - y[i] >= s.threshold and s.min_pair_s <= dt <= s.max_pair_s:
                steps.append(self._detection(t[i], self._span_start(t[i])))
                self._last_step_t = t[i]
        return steps
