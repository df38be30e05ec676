"""Streaming zero-velocity detectors for a boot-mounted IMU: SHOE, ARED, MV and adaptive.

A foot comes to rest at every stance; recognising those instants is the whole art of a
zero-velocity-aided INS (Foxlin 2005; Skog, Händel, Nilsson, Rantakokko, "Zero-velocity
detection — an algorithm evaluation", IEEE Trans. Biomed. Eng. 57(11), 2010). Over a window
``W`` of samples centred on sample k, with specific force ``a_j`` (m/s²), angular rate
``ω_j`` (rad/s) and ``ā`` the window's mean specific force:

* **SHOE** (stance hypothesis optimal detector, the GLRT of Skog et al. 2010 eq. 13)::

      T = (1/W) Σ_j ( ‖a_j − g ā/‖ā‖‖² / σ_a²  +  ‖ω_j‖² / σ_ω² )  <  γ

* **ARED** (angular rate energy, eq. 16): ``(1/W) Σ_j ‖ω_j‖² < γ_ω²``;
* **MV** (acceleration moving variance, eq. 15): ``(1/W) Σ_j ‖a_j − ā‖² < γ_a²``;
* **adaptive**: SHOE whose threshold rises with the gait's intensity (see
  :class:`pdr.zupt.settings.DetectorSettings`). Wagstaff, Peretroukhin and Kelly
  ("Improving foot-mounted inertial navigation through real-time motion classification",
  IPIN 2017) showed that one SHOE threshold cannot serve walking and running, and switched
  thresholds on an SVM's motion class; Wagstaff and Kelly (2018, LSTM-based zero-velocity
  detection) learned the detector instead. Here the switch is a continuous law of one
  physical feature, the largest specific force of the last stride(s). SHOE tests for
  gravity along the window's own mean direction, so a boot resting on its toe (crawling)
  is tested like an upright one.

The window is a time window (``|t_j − t_k| ≤ window_s/2``), so the detector works at any
rate; a sample is decided once a sample past its window has arrived, half a window after
it. Every statistic is summed over its own window in sample order (compiled, see
:mod:`pdr.zupt._detector_kernel`): a stream cut into batches of any size gives the same
decisions, bit for bit, as the whole recording at once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdr.zupt import _detector_kernel as _k
from pdr.zupt.settings import DetectorSettings

_KIND = {"shoe": _k.KIND_SHOE, "ared": _k.KIND_ARED, "mv": _k.KIND_MV, "adaptive": _k.KIND_ADAPTIVE}
_STAT_COL = {"shoe": _k.SHOE, "ared": _k.ARED, "mv": _k.MV, "adaptive": _k.SHOE}


@dataclass(frozen=True)
class Decisions:
    """Samples the detector has decided, in time order, with what the INS needs of them."""

    rows: np.ndarray  # (m, 7): t (s), specific force (3, m/s², body), angular rate (3, rad/s, body)
    stationary: np.ndarray  # (m,) bool
    statistic: np.ndarray  # (m,) the detector's test statistic (SHOE: dimensionless; ARED rad²/s²; MV m²/s⁴)
    threshold: np.ndarray  # (m,) what it was compared with
    ared: np.ndarray  # (m,) rad²/s², mean squared angular rate of the window (for ZARU)
    quiet: np.ndarray  # (m,) bool, motionless by the strict test (SHOE below shoe_threshold; else stationary)

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    @property
    def t(self) -> np.ndarray:
        return self.rows[:, 0]

    @property
    def acc(self) -> np.ndarray:
        return self.rows[:, 1:4]

    @property
    def gyr(self) -> np.ndarray:
        return self.rows[:, 4:7]

    @staticmethod
    def empty() -> Decisions:
        z = np.empty(0)
        return Decisions(np.empty((0, _k.BUF_COLS)), np.empty(0, bool), z, z, z, np.empty(0, bool))

    def split(self, i: int) -> tuple[Decisions, Decisions]:
        f = Decisions.__dataclass_fields__
        return Decisions(*(getattr(self, k)[:i] for k in f)), Decisions(*(getattr(self, k)[i:] for k in f))

    @staticmethod
    def concatenate(a: Decisions, b: Decisions) -> Decisions:
        return Decisions(*(np.concatenate([getattr(a, k), getattr(b, k)]) for k in Decisions.__dataclass_fields__))


class ZeroVelocityDetector:
    """``decided = detector.update(t, acc, gyr)``; ``detector.finish()`` decides the rest.

    ``t`` (n,) s increasing, ``acc`` (n, 3) m/s² and ``gyr`` (n, 3) rad/s in the body frame.
    Returns the samples decided by this call (those whose window is complete), which lag
    the newest sample by half a window.
    """

    def __init__(self, settings: DetectorSettings | None = None):
        self.settings = s = settings or DetectorSettings()
        self._half = 0.5 * s.window_s
        self._kind = _KIND[s.detector]
        self._col = _STAT_COL[s.detector]
        self._n_bins = max(1, int(round(s.intensity_window_s / s.intensity_bin_s)))
        self._state = np.full(_k.state_size(self._n_bins), np.nan)
        self._buf = np.empty((0, _k.BUF_COLS))  # the undecided samples and the half window before them
        self._start = 0  # index in the buffer of the first undecided sample
        self._t_last = -math.inf
        self._args = (s.gravity, 1.0 / s.acc_sigma ** 2, 1.0 / s.gyro_sigma ** 2)
        self._decide_args = (self._kind, self._state, self._n_bins, s.intensity_bin_s, s.shoe_threshold,
                             s.adaptive_reference_m_s2, s.adaptive_exponent, s.adaptive_max_threshold,
                             s.adaptive_floor_factor, s.adaptive_ceiling, s.ared_threshold_rad_s ** 2,
                             s.mv_threshold_m_s2 ** 2)

    @property
    def name(self) -> str:
        return self.settings.detector

    def update(self, t, acc, gyr) -> Decisions:
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        n = t.shape[0]
        if n == 0:
            return Decisions.empty()
        rows = np.empty((n, _k.BUF_COLS))
        rows[:, 0] = t
        try:
            rows[:, 1:4] = acc
            rows[:, 4:7] = gyr
        except ValueError:
            raise ValueError(f"t has {n} samples but acc is {np.shape(acc)} and gyr {np.shape(gyr)}; "
                             f"expected ({n}, 3) each") from None
        if not math.isfinite(float(rows.sum())):
            raise ValueError("non-finite time, acceleration or angular rate in the batch")
        if t[0] <= self._t_last or (n > 1 and bool((t[1:] <= t[:-1]).any())):
            raise ValueError(f"sample times must increase (batch starts at {t[0]:.6f} s, previous sample at "
                             f"{self._t_last:.6f} s)")
        self._t_last = float(t[-1])
        self._buf = np.concatenate((self._buf, rows)) if self._buf.shape[0] else rows
        return self._decide(final=False)

    def finish(self) -> Decisions:
        """The stream has ended: the last half window is decided on the samples there are."""
        return self._decide(final=True)

    def _decide(self, final: bool) -> Decisions:
        buf = self._buf
        stats, m = _k.window_statistics(buf, self._start, final, self._half, *self._args)
        lo, hi = self._start, self._start + m
        rows = buf[lo:hi]
        zv, thr, quiet = _k.decide(rows, stats, *self._decide_args)
        out = Decisions(rows, zv, stats[:, self._col], thr, stats[:, _k.ARED], quiet)
        # keep the undecided samples and the half window before them
        keep = hi if hi >= buf.shape[0] else min(int(np.searchsorted(buf[:, 0], buf[hi, 0] - self._half)), hi)
        if keep:
            self._buf = buf[keep:]
        self._start = hi - keep
        return out
