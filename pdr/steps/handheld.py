"""Step detectors of the handheld-PDR thesis: peak detection and zero crossing (Tupý 2023, §2.1-2.2).

Both read gravity-free acceleration — vertical linear acceleration when the phone's
orientation is known, else the norm minus g (§2.1) — low-passed by a **9th-order
Butterworth at 3 Hz** (after Susi et al.: walking lives "in units of Hz"), designed as
second-order sections because the (b, a) form of that order is numerically fragile at
phone rates. The low-pass keeps the DC, so the input must really be gravity-free.

* :class:`PeakDetector` (§2.2.1): a step at each local maximum :math:`a_p` of the filtered
  signal with :math:`a_p > a_{th}` (2 m/s², the thesis's Fig. 2.4) and
  :math:`t_p - t_{p-1} > 0.33` s since the previous accepted step (walking stays under
  3 Hz; the thesis prints the difference with the wrong sign).
* :class:`ZeroCrossingDetector` (§2.2.2): a step starts at a negative-to-positive crossing
  and ends at the next one, or after a timeout when walking stops; it counts only when the
  signal's magnitude in between reached a threshold. The thesis gives neither the
  threshold nor the timeout: here the peak detector's 2 m/s² and the slowest step
  (1 s, 1 Hz). A crossing sooner than the minimum step time (0.33 s) after the step began is
  a ripple inside the step, not a new one.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from pdr.events import StepDetection
from pdr.steps.base import DetectorSettings, StepDetector, extrema


@dataclasses.dataclass(frozen=True)
class HandheldSettings(DetectorSettings):
    order: int = 9  # Butterworth low-pass order (§2.1)
    cutoff_hz: float = 3.0  # Hz
    threshold: float = 2.0  # m/s², a_th: peak height (peak) or magnitude reached (zero crossing)
    min_interval_s: float = 0.33  # s between steps: at most 3 steps per second


class _LowPassDetector(StepDetector):
    Settings = HandheldSettings

    def _design(self, fs: float) -> np.ndarray:
        s = self.settings
        return signal.butter(s.order, s.cutoff_hz, "lowpass", fs=fs, output="sos")


class PeakDetector(_LowPassDetector):
    """Peaks above ``threshold`` at least ``min_interval_s`` apart (Tupý §2.2.1)."""

    name = "peak"

    def _scan(self, t, y, lo, hi) -> list[StepDetection]:
        s = self.settings
        maxima, _ = extrema(y, lo, hi)
        steps = []
        for i in maxima[y[maxima] > s.threshold]:
            if t[i] - self._last_step_t > s.min_interval_s:
                steps.append(self._detection(t[i], self._span_start(t[i])))
                self._last_step_t = t[i]
        return steps


class ZeroCrossingDetector(_LowPassDetector):
    """Steps between negative-to-positive crossings whose magnitude reached ``threshold`` (§2.2.2)."""

    name = "zero_crossing"

    def __init__(self, settings=None):
        super().__init__(settings)
        self._open: float | None = None  # time the current step began (an upward crossing)

    def _scan(self, t, y, lo, hi) -> list[StepDetection]:
        s = self.settings
        # an upward crossing between samples i-1 and i, timed at sample i
        i = np.flatnonzero((y[lo - 1 : hi] < 0) & (y[lo : hi + 1] >= 0)) + lo
        steps = []
        for tc in t[i]:
            if self._open is not None and tc - self._open > s.max_step_s:
                steps += self._close(self._open + s.max_step_s)
            if self._open is None:
                self._open = tc
            elif tc - self._open >= s.min_interval_s:
                steps += self._close(tc)
                self._open = tc
        if self._open is not None and t[hi] - self._open > s.max_step_s:
            steps += self._close(self._open + s.max_step_s)
        return steps

    def _close(self, t_end: float) -> list[StepDetection]:
        """End the open step at ``t_end``; it counts if its magnitude reached the threshold."""
        t_start, self._open = self._open, None
        i0 = np.searchsorted(self._t, t_start, side="left")
        i1 = np.searchsorted(self._t, t_end, side="right")
        if i1 <= i0 or np.abs(self._y[i0:i1]).max() < self.settings.threshold:
            return []
        self._last_step_t = t_end
        return [self._detection(t_end, t_start)]

    def _finish(self) -> list[StepDetection]:
        if self._open is None or self._t.size == 0:
            return []
        return self._close(min(self._open + self.settings.max_step_s, float(self._t[-1])))
