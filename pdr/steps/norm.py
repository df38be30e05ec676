r"""A step detector that does not care how the phone is carried: peaks of ‖f‖ - g with adaptive limits.

Why the norm. In every carry position (hand, trouser pocket, bag, neck pouch, armband, a
swinging arm) the body's vertical bounce — one rise and fall of the centre of mass per
step — reaches the phone, and the acceleration norm sees it whatever the phone's attitude
(Tupý §2.1, eq. 2.1). What differs between positions is the size of the signal and what
rides on it: the thigh's swing (a pocket) repeats once per *stride*, so alternate steps
look unequal; a bag keeps swinging like a pendulum after the walker stops; putting the
phone away or taking it out makes a few irregular bumps. The limits below are therefore
relative or physical, not tuned per position.

The signal ``a = ‖f‖ - g`` (m/s², :func:`pdr.steps.norm_minus_gravity`) is

1. band-passed, **Butterworth 0.3-3 Hz, 4th order** (two poles at each edge), causal: 3 Hz
   is the fastest walking cadence (Tupý §2.2.1), 0.3 Hz removes the accelerometer's offset
   (some phones read ‖f‖ = 9.35 m/s² at rest) and slow posture changes;
2. each local maximum :math:`y_p` (at :math:`t_p`) and the minimum :math:`y_v` that follows it
   form a bounce — the max/min pair of Ryšánek §3.5.2 — with swing :math:`s = y_p - y_v`. It
   is a step, recognised at the minimum, when

   * :math:`y_p \ge y_{floor}` = 0.5 m/s²: the gentlest hand-held walk bounces about twice
     that, a phone at rest or a slow hand move much less;
   * :math:`s \ge r\,\tilde s` with :math:`\tilde s` the median swing of the (at most 8)
     steps of the last 5 s and r = 0.3: a bounce under a third of the walker's recent steps
     is not a step (a bag swinging on after a stop, the filter's ring-out after the last
     step, a ripple between steps) while the weaker leg's step with the phone on one thigh
     still passes. The window forgets: after a pause, or 5 s into a much gentler walk, the
     walker's new level sets the reference;
   * :math:`t_p - t_{p,last} \ge` 0.33 s (3 Hz, as above);
3. steps form a **bout** while their peaks follow each other within 1 s (1 Hz, the slowest
   walking cadence, Ryšánek §2.7's lower limit); a bout counts once it has 4 steps, and
   then all of them are released with their own times. Isolated bumps are not walking. The
   price: the first three steps of each bout arrive when the fourth is recognised (about
   1.5 s late), and a walk of fewer than 4 steps, or steps more than 1 s apart, is not
   counted (``min_bout_steps=1`` counts every step).

Measured on the Oxford step-counter set (48 optimisation walks + 1 validation walk, seven
carry positions, three phones, four people), the mean absolute step-count error is about
1.5 %, and the limits above are flat optima there (changing any one by ±20-30 % moves it by
less than 0.2 points); see ``firetrack eval steps``.
"""
from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from pdr.events import StepDetection
from pdr.steps.base import DetectorSettings, StepDetector, bandpass_sos, ordered_extrema


@dataclasses.dataclass(frozen=True)
class NormSettings(DetectorSettings):
    order: int = 4  # total band-pass order
    low_hz: float = 0.3  # Hz
    high_hz: float = 3.0  # Hz, fastest cadence
    floor: float = 0.5  # m/s², smallest step peak
    relative: float = 0.3  # r: a step's swing is at least this fraction of the recent median
    reference_steps: int = 8  # steps in the median reference
    reference_window_s: float = 5.0  # s; only steps this recent make the reference
    min_interval_s: float = 0.33  # s between steps (3 Hz)
    bout_gap_s: float = 1.0  # s; a longer pause ends a bout (1 Hz)
    min_bout_steps: int = 4  # steps before a bout counts


class NormDetector(StepDetector):
    """Orientation-free peaks of ‖f‖ - g with a floor, a relative threshold and bouts."""

    name = "norm"
    Settings = NormSettings

    def __init__(self, settings=None):
        super().__init__(settings)
        self._swings: deque[tuple[float, float]] = deque(maxlen=self.settings.reference_steps)  # (t, swing)
        self._peak: tuple[float, float] | None = None  # (t, y) of the maximum awaiting its minimum
        self._last_peak_t = -np.inf
        self._bout: list[StepDetection] = []  # the current bout while it is too short to count
        self._bout_steps = 0

    def _design(self, fs: float) -> np.ndarray:
        s = self.settings
        return bandpass_sos(s.order, s.low_hz, s.high_hz, fs)

    def _scan(self, t, y, lo, hi) -> list[StepDetection]:
        s = self.settings
        steps: list[StepDetection] = []
        for i, top in zip(*ordered_extrema(y, lo, hi)):
            if top:
                if y[i] >= s.floor and (self._peak is None or y[i] > self._peak[1]):
                    self._peak = (t[i], y[i])
                continue
            if self._peak is None:
                continue
            (t_peak, y_peak), self._peak = self._peak, None
            swing = y_peak - y[i]
            since = t_peak - self._last_peak_t
            if since < s.min_interval_s:
                continue
            recent = [w for tw, w in self._swings if t_peak - tw <= s.reference_window_s]
            if recent and swing < s.relative * np.median(recent):
                continue
            step = self._detection(t[i], self._span_start(t[i]))
            self._swings.append((float(t_peak), float(swing)))
            self._last_peak_t, self._last_step_t = t_peak, t[i]
            steps += self._in_bout(step, since)
        return steps

    def _in_bout(self, step: StepDetection, since: float) -> list[StepDetection]:
        if since > self.settings.bout_gap_s:
            self._bout, self._bout_steps = [], 0
        self._bout_steps += 1
        if self._bout_steps < self.settings.min_bout_steps:
            self._bout.append(step)
            return []
        released, self._bout = self._bout + [step], []
        return released
