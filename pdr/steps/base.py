"""What every step detector shares: rate estimation, a causal filter with state, a bounded tail.

A detector is fed ``update(t, a)`` with timestamps (s) and one gravity-free acceleration per
sample (m/s², see :mod:`pdr.steps.signals`) and returns the steps it has recognised so far
as :class:`~pdr.events.StepDetection`. Feeding a recording in one batch or in batches of
any size gives exactly the same steps, because

* the filter is designed once, at the rate estimated from a fixed prefix of the stream
  (the samples up to the first one ``rate_window_s`` after the first), whatever the batches;
* the filter runs as second-order sections with their state carried between calls
  (``scipy.signal.sosfilt`` with ``zi``), started in steady state for the first sample;
* an extremum is judged only when the sample after it has arrived, and every later
  decision depends on times and values, never on where a batch ended.

Memory is bounded: only the last ``max_step_s + 0.5`` s of the filtered signal are kept
(enough for the statistics of a step, which spans at most ``max_step_s``). Filtering and
the search for extrema are vectorised over each batch; the Python loop runs only over the
extrema found (a few per second), where each decision depends on the previous step.
Non-finite samples are dropped (a NaN would poison the filter state). Before the filter the
samples are put on a uniform clock at the estimated rate (:mod:`pdr.steps.uniform`: a
browser's sensor events come at irregular times, and a filter assumes even spacing); a gap
in the stream (over ``max_gap_s``) is filtered as if the samples were contiguous.

The live path is causal. :meth:`StepDetector.detect` with ``zero_phase=True`` runs the
same logic on a forward-backward filtered recording, for offline analysis only (the
filter's magnitude response is then squared, so thresholds bite slightly differently).
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
from scipy import signal

from pdr.events import StepDetection
from pdr.settings import settings_with  # noqa: F401  (re-exported)
from pdr.steps.signals import estimate_rate
from pdr.steps.sosfilter import sos_filter
from pdr.steps.uniform import UniformClock

TAIL_MARGIN_S = 0.5  # s kept beyond the longest step, for the extremum and crossing tests


@dataclasses.dataclass(frozen=True)
class DetectorSettings:
    """Settings every detector has (subclasses add their own, each with a unit)."""

    rate_hz: float = 0.0  # Hz; 0 = estimate it from the first rate_window_s of timestamps
    rate_window_s: float = 2.0  # s of samples the rate is estimated from
    max_step_s: float = 1.0  # s; the longest step (1 Hz, the slowest walking cadence)
    max_gap_s: float = 0.2  # s; samples further apart are a gap (the uniform clock restarts), not jitter


class StepDetector:
    """Base of the streaming detectors; subclasses set ``name``, ``Settings``, ``_design``, ``_scan``."""

    name: ClassVar[str] = ""
    Settings: ClassVar[type[DetectorSettings]] = DetectorSettings

    def __init__(self, settings: DetectorSettings | None = None):
        self.settings = settings if settings is not None else self.Settings()
        self.rate_hz: float | None = None  # known once the filter is designed
        self._sos: np.ndarray | None = None
        self._zi: np.ndarray | None = None
        self._bypass = False  # the input is already filtered (offline zero-phase path)
        self._raw_t = np.empty(0)
        self._raw_a = np.empty(0)
        self._t = np.empty(0)  # filtered tail: times
        self._y = np.empty(0)  # filtered tail: values
        self._next = 1  # first tail index not yet examined as an extremum
        self._last_step_t = -np.inf
        self._fed = False
        self._clock: UniformClock | None = None
        if self.settings.rate_hz > 0:
            self._start(self.settings.rate_hz)

    # -- subclass hooks -----------------------------------------------------------------
    def _design(self, fs: float) -> np.ndarray:  # pragma: no cover - abstract
        """Second-order sections of the detector's filter at sampling rate ``fs``."""
        raise NotImplementedError

    def _scan(self, t: np.ndarray, y: np.ndarray, lo: int, hi: int) -> list[StepDetection]:  # pragma: no cover
        """Examine tail samples ``lo..hi`` (both have neighbours) and return new steps."""
        raise NotImplementedError

    def _finish(self) -> list[StepDetection]:
        """Steps still pending when the stream ends."""
        return []

    # -- streaming ----------------------------------------------------------------------
    def update(self, t, a) -> list[StepDetection]:
        """Feed samples ``t`` (s, (N,)) and ``a`` (m/s², (N,)); return the steps recognised."""
        t = np.asarray(t, dtype=float).reshape(-1)
        a = np.asarray(a, dtype=float).reshape(-1)
        if t.shape != a.shape:
            raise ValueError(f"t and a must have the same length, got {t.shape[0]} and {a.shape[0]}")
        self._fed = True
        finite = np.isfinite(t) & np.isfinite(a)
        if not finite.all():  # a NaN would poison the filter state for good
            t, a = t[finite], a[finite]
        if self.rate_hz is None:
            self._raw_t = np.concatenate([self._raw_t, t])
            self._raw_a = np.concatenate([self._raw_a, a])
            if self._raw_t.size < 2:
                return []
            done = np.flatnonzero(self._raw_t - self._raw_t[0] >= self.settings.rate_window_s)
            if done.size == 0:
                return []
            self._start(estimate_rate(self._raw_t[: done[0] + 1]))
            t, a = self._raw_t, self._raw_a
            self._raw_t = self._raw_a = np.empty(0)
        return self._process(t, a)

    def finish(self) -> list[StepDetection]:
        """The stream has ended: process what is buffered and release pending steps."""
        steps: list[StepDetection] = []
        if self.rate_hz is None and self._raw_t.size >= 2 and np.ptp(self._raw_t) > 0:
            self._start(estimate_rate(self._raw_t))
            steps += self._process(self._raw_t, self._raw_a)
            self._raw_t = self._raw_a = np.empty(0)
        return steps + self._finish()

    def detect(self, t, a, zero_phase: bool = False) -> list[StepDetection]:
        """A whole recording through this fresh detector; ``zero_phase=True`` filters
        forward-backward (offline analysis only)."""
        if self._fed:
            raise RuntimeError("detect() needs a fresh detector; this one has already seen samples")
        if not zero_phase:
            return self.update(t, a) + self.finish()
        t = np.asarray(t, dtype=float).reshape(-1)
        if self.rate_hz is None:
            self._start(estimate_rate(t))
        t, a = self._clock.push(t, np.asarray(a, dtype=float).reshape(-1))
        y = signal.sosfiltfilt(self._sos, a)
        self._bypass = True
        return self.update(t, y) + self.finish()

    # -- internals ----------------------------------------------------------------------
    def filter_sections(self, fs: float) -> np.ndarray:
        """The detector's band-pass at sampling rate ``fs`` (Hz) as contiguous second-order
        sections (what a columnar engine runs for it)."""
        return np.ascontiguousarray(self._design(float(fs)), dtype=np.float64)

    def _start(self, fs: float) -> None:
        self.rate_hz = float(fs)
        self._sos = self.filter_sections(self.rate_hz)
        self._clock = UniformClock(self.rate_hz, self.settings.max_gap_s)

    def _process(self, t: np.ndarray, a: np.ndarray) -> list[StepDetection]:
        if t.size == 0:
            return []
        if self._bypass:
            y = a
        else:
            t, a = self._clock.push(t, a)
            if t.size == 0:
                return []
            if self._zi is None:  # steady state for the first sample: no start-up transient
                self._zi = np.ascontiguousarray(signal.sosfilt_zi(self._sos) * a[0])
            y = sos_filter(self._sos, a, self._zi)
        self._t = np.concatenate([self._t, t])
        self._y = np.concatenate([self._y, y])
        n = self._t.size
        steps = self._scan(self._t, self._y, self._next, n - 2) if n - 2 >= self._next else []
        self._next = max(self._next, n - 1)
        drop = int(np.searchsorted(self._t, self._t[-1] - (self.settings.max_step_s + TAIL_MARGIN_S)))
        drop = min(drop, self._next - 1)
        if drop > 0:
            self._t, self._y = self._t[drop:], self._y[drop:]
            self._next -= drop
        return steps

    def _span_start(self, t_step: float) -> float:
        """Where a step ending at ``t_step`` began: the previous step, at most ``max_step_s`` ago."""
        return max(self._last_step_t, t_step - self.settings.max_step_s)

    def _detection(self, t_step: float, t_start: float) -> StepDetection:
        """The step ``(t_start, t_step]`` with the statistics of the filtered signal over it."""
        i0 = int(np.searchsorted(self._t, t_start, side="right"))
        i1 = int(np.searchsorted(self._t, t_step, side="right"))
        seg = self._y[i0:i1] if i1 > i0 else self._y[max(i1 - 1, 0) : i1]
        return StepDetection(
            t=float(t_step),
            t_start=float(t_start),
            a_max=float(seg.max()),
            a_min=float(seg.min()),
            a_mean=float(seg.mean()),
            a_mean_abs=float(np.abs(seg).mean()),
        )


def bandpass_sos(order: int, low_hz: float, high_hz: float, fs: float) -> np.ndarray:
    """Butterworth band-pass of total ``order`` (even: half of it per edge) as second-order sections."""
    if order % 2:
        raise ValueError(f"a band-pass has an even total order, got {order}")
    return signal.butter(order // 2, [low_hz, high_hz], "bandpass", fs=fs, output="sos")


def extrema(y: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of local maxima and minima of ``y`` among ``lo..hi`` (each needs both neighbours).

    A maximum is where the slope turns from rising to not rising,
    :math:`\\operatorname{sgn}(y_i - y_{i-1}) > \\operatorname{sgn}(y_{i+1} - y_i)` with a
    rise before it (Tupý §2.2.1, step 1); a minimum mirrors it.
    """
    d = np.diff(y[lo - 1 : hi + 2])
    before, after = d[:-1], d[1:]
    maxima = np.flatnonzero((before > 0) & (after <= 0)) + lo
    minima = np.flatnonzero((before < 0) & (after >= 0)) + lo
    return maxima, minima

def ordered_extrema(y: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """All extrema among ``lo..hi`` in time order: indices and whether each is a maximum."""
    maxima, minima = extrema(y, lo, hi)
    idx = np.concatenate((maxima, minima))
    order = np.argsort(idx, kind="stable")
    return idx[order], np.concatenate((np.ones(maxima.size, bool), np.zeros(minima.size, bool)))[order]
