"""The 1-D signals the step detectors read, and the sampling rate their filters are designed at.

Every detector in :mod:`pdr.steps` takes one gravity-free acceleration per sample:

* **vertical linear acceleration** (Tupý 2023 §2.1; Ryšánek §3.5.2 steps 1-2): the specific
  force rotated to the navigation frame with the AHRS quaternion, minus gravity,

  .. math:: a_v = \\big(R(q)\\,\\mathbf f\\big)_z - g

  which needs a gyroscope (and ideally a magnetometer) for ``q``;
* **norm minus g** (Tupý §2.1 eq. 2.1, after Leppäkoski): :math:`a_n = \\lVert\\mathbf f\\rVert - g`,
  independent of how the phone is held, for pockets, bags and armbands and for
  accelerometer-only logs.

Phones time-stamp samples with jitter and the odd gap, so the rate a filter is designed at
comes from :func:`estimate_rate`, not from a nominal value.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from pdr import quaternion as quat
from pdr.constants import GRAVITY
from pdr.windows import norm3

GAP_FACTOR = 2.5  # an interval longer than this many median intervals is a gap, not jitter


def estimate_rate(t: np.ndarray) -> float:
    """Sampling rate (Hz) of timestamps ``t`` (s): the mean of the intervals that are not gaps.

    The median interval says what a gap is (longer than ``GAP_FACTOR`` medians); the
    mean of the remaining positive intervals is the rate. A plain median is biased when
    the jitter is skewed (a Samsung phone in the Oxford set: median 5.0 ms, true mean
    4.55 ms), and a plain mean is biased by dropped samples. (``Series.rate_hz`` reports
    the median, the nominal rate a person reads.)
    """
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    if dt.size == 0:
        raise ValueError("cannot estimate a sampling rate from fewer than two distinct timestamps")
    regular = dt[dt <= GAP_FACTOR * np.median(dt)]
    return float(1.0 / regular.mean())


def vertical_linear_acceleration(q: np.ndarray, acc: np.ndarray, g: float = GRAVITY) -> np.ndarray:
    """Upward linear acceleration (m/s²) from body-frame specific force and orientation.

    ``q`` (N, 4) are scalar-first Hamilton quaternions rotating **body -> ENU** (what
    ``make_filter("fscf").update`` returns); ``acc`` (N, 3) is the accelerometer in the body
    frame (m/s², gravity included). Returns :math:`(R(q)\\mathbf f)_z - g`, shape (N,):
    only the third row of :math:`R(q)` is needed,
    :math:`[2(xz - wy),\\ 2(yz + wx),\\ 1 - 2(x^2 + y^2)]`.
    """
    q = quat.normalize(np.asarray(q, dtype=float))
    acc = np.asarray(acc, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    up = (2 * (x * z - w * y)) * acc[..., 0] + (2 * (y * z + w * x)) * acc[..., 1] + (1 - 2 * (x * x + y * y)) * acc[..., 2]
    return up - g


def norm_minus_gravity(acc: np.ndarray, g: float = GRAVITY) -> np.ndarray:
    """:math:`\\lVert\\mathbf f\\rVert - g` (m/s²) per sample: orientation-free, shape (N,)."""
    return norm3(np.asarray(acc, dtype=float).reshape(-1, 3)) - g


def vertical_from_gravity_estimate(t: np.ndarray, acc: np.ndarray, tau: float = 1.0) -> np.ndarray:
    """Approximate vertical linear acceleration when there is no gyroscope (offline).

    Gravity's direction in the body frame is taken as the accelerometer low-passed with a
    first-order filter of time constant ``tau`` (s); the linear acceleration along it is
    :math:`\\mathbf f\\cdot\\hat{\\mathbf g} - \\lVert\\bar{\\mathbf f}\\rVert`. This works while
    the phone's attitude changes slowly compared with ``tau`` (held in the hand, strapped);
    a swinging arm or a pocket on the thigh violates that, and then the norm is the better
    signal. For comparisons on accelerometer-only logs, not for the live path.
    """
    t = np.asarray(t, dtype=float)
    acc = np.asarray(acc, dtype=float)
    alpha = 1.0 - np.exp(-1.0 / (tau * estimate_rate(t)))
    b, a = [alpha], [1.0, alpha - 1.0]
    zi = signal.lfilter_zi(b, a)
    grav = np.column_stack([signal.lfilter(b, a, acc[:, k], zi=zi * acc[0, k])[0] for k in range(3)])
    mag = np.linalg.norm(grav, axis=1)
    return (acc[:, 0] * grav[:, 0] + acc[:, 1] * grav[:, 1] + acc[:, 2] * grav[:, 2]) / mag - mag
