"""9-axis IMU with a Vicon orientation reference (Justa's AHRS data set) as a :class:`Recording`.

Source: github.com/Josef4Sci/AHRS_Filter (MIT); Justa, J., Smidl, V., Hamacek, A., "Fast
AHRS Filter for Accelerometer, Magnetometer, and Gyroscope Combination with Separated
Sensor Corrections", Sensors 2020, 20(14):3824.

``Justa_dataset.mat`` (MATLAB v5), N samples at about 81 Hz with occasional gaps:

* ``Accelerometer`` N x 3 in g (converted here to m/s² with g0 = 9.80665);
* ``Gyroscope`` N x 3 in rad/s;
* ``Magnetometer`` N x 3, dimensionless, scaled to unit length (``meta["mag_units"] ==
  "normalised"``). In Justa_dataset.mat about a third of the samples, in the fast-rotation
  part, have norms of 1.25-1.6 with the right direction; they are kept as stored (a
  warning says so), since the published results were computed on them;
* ``qViconReference`` N x 4, (w, x, y, z), rotating body -> reference frame;
* ``time`` 1 x N in s.

The reference frame is NWU: at rest R(q_ref)·acc points along +z (up) and R(q_ref)·mag lies
in the x-z plane with a positive x component, so x points to magnetic north, y west, z up.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pdr.constants import GRAVITY
from pdr.io._common import Notes, common_length, time_order
from pdr.io._mat import load_mat, matrix, vector
from pdr.recording import Recording, Series

STANDARD_GRAVITY = GRAVITY  # m/s² per g
_UNIT_NORM_TOLERANCE = 0.05  # a magnetometer whose samples are this close to length 1 is normalised
_QUAT_NORM_TOLERANCE = 0.01  # reference quaternions further than this from unit length are reported
_FIELDS = ("Accelerometer", "Gyroscope", "Magnetometer", "qViconReference", "time")


def load_vicon_ahrs(path: str | Path) -> Recording:
    """Load ``Justa_dataset.mat``-style files; ``orientation_ref`` is q_ref (w, x, y, z), frame NWU.

    The reference quaternions are renormalised (the file's are off unit length by ~5e-4);
    ``meta["q_ref_norm_range"]`` keeps the stored range.
    """
    notes = Notes(path)
    m = load_mat(path)
    acc = matrix(m, "Accelerometer", 3, path)
    gyr = matrix(m, "Gyroscope", 3, path)
    mag = matrix(m, "Magnetometer", 3, path)
    q = matrix(m, "qViconReference", 4, path)
    t = vector(m, "time", path)

    n = common_length(
        {"Accelerometer": len(acc), "Gyroscope": len(gyr), "Magnetometer": len(mag),
         "qViconReference": len(q), "time": len(t)},
        path,
        notes,
    )
    acc, gyr, mag, q, t = acc[:n], gyr[:n], mag[:n], q[:n], t[:n]
    order = time_order(t, "time", notes)
    if order is not None:
        acc, gyr, mag, q, t = acc[order], gyr[order], mag[order], q[order], t[order]

    meta: dict = {"format": "Justa AHRS data set with Vicon reference (.mat)"}
    acc = _accelerometer_si(acc, meta, notes)
    _magnetometer_units(mag, meta, notes)
    norms = np.linalg.norm(q, axis=1)
    meta["q_ref_norm_range"] = (float(norms.min()), float(norms.max()))
    if np.any(np.abs(norms - 1.0) > _QUAT_NORM_TOLERANCE):
        notes.warn(f"reference quaternion norms span {norms.min():.3f}..{norms.max():.3f}; renormalised")
    q = q / norms[:, None]
    meta["other_fields"] = sorted(set(m) - set(_FIELDS))

    return Recording(
        source=str(path),
        kind="vicon_ahrs",
        acc=Series(t=t, values=acc),
        gyr=Series(t=t, values=gyr),
        mag=Series(t=t, values=mag),
        orientation_ref=Series(t=t, values=q),
        frame="NWU",
        meta=meta,
        warnings=notes.messages,
    )


def _accelerometer_si(acc: np.ndarray, meta: dict, notes: Notes) -> np.ndarray:
    """g -> m/s²; a file already in m/s² (median norm near 9.8) is left as it is."""
    g = float(np.median(np.linalg.norm(acc, axis=1)))
    if 5.0 < g < 15.0:
        notes.warn(f"Accelerometer median norm is {g:.2f}: already m/s², not g; not scaled")
        meta["acc_units_in_file"] = "m/s^2"
        return acc
    meta["acc_units_in_file"] = "g"
    return acc * STANDARD_GRAVITY


def _magnetometer_units(mag: np.ndarray, meta: dict, notes: Notes) -> None:
    """The file's magnetometer is dimensionless, scaled to unit length: check, never rescale."""
    norms = np.linalg.norm(mag, axis=1)
    meta["mag_norm_range"] = (float(norms.min()), float(norms.max()))
    if abs(float(np.median(norms)) - 1.0) > _UNIT_NORM_TOLERANCE:
        meta["mag_units"] = "unknown"
        notes.warn(f"Magnetometer median norm is {np.median(norms):.3g}, not 1: units unknown")
        return
    meta["mag_units"] = "normalised"
    off = np.abs(norms - 1.0) > _UNIT_NORM_TOLERANCE
    if off.any():
        k = np.flatnonzero(off)
        notes.warn(
            f"{off.mean():.0%} of Magnetometer samples are not unit length (norm up to {norms.max():.2f}, "
            f"samples {k[0]}..{k[-1]}); kept as stored"
        )
