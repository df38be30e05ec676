"""IPIN 2023 smartphone walks in the organisers' MATLAB form (``ReadLogFile2022.m``) as a :class:`Recording`.

Three of the IPIN 2023 Track 3 training walks come only as the organisers' parse of the
GetSensorData text log (github Kenny5269/2023_IPIN_Competition_Track03, ``02 Supplementary
Materials/03 - Files for Matlab Tools/Parser/ReadLogFile2022.m``): a MATLAB v5 file with one
N x k matrix per line type, the type's first field dropped. The columns, checked against the
parser's ``sscanf`` formats and against the text log of the same trial (trial 52
repetition 01 against repetition 02: the same clocks, units, axes and landmark points):

==========  =================================================================  ==============
variable    columns                                                            text line
==========  =================================================================  ==============
``Acce``    AppTs, SensorTs, x, y, z (m/s²) — the accuracy field is dropped     ``ACCE``
``Gyro``    AppTs, SensorTs, x, y, z (rad/s)                                    ``GYRO``
``Magn``    AppTs, SensorTs, x, y, z (µT)                                       ``MAGN``
``Pres``    AppTs, SensorTs, pressure (hPa), accuracy                           ``PRES``
``Ahrs``    AppTs, SensorTs, pitch, roll, yaw (°), rotation vector x, y, z[, accuracy]  ``AHRS``
``Gnss``    AppTs, UnixTs, lat, lon, alt, bearing, accuracy (m), speed, sats in view, in use  ``GNSS``
``Posi``    AppTs, lat, lon, floor — the counter and building are dropped       ``POSI``
==========  =================================================================  ==============

So a walk reads exactly as :func:`pdr.io.ipin.load_ipin` reads the text log: every series on
the sensor clock, landmarks and GNSS moved onto it by the median ``SensorTs − AppTs`` of the
accelerometer, GNSS repeats dropped and stale fixes retimed. What the .mat has lost is said
in ``meta``: no header (phone model unknown), no landmark counter (numbered 1..M here) and no
building id.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pdr.io._common import Notes, time_order
from pdr.io._mat import load_mat, numeric
from pdr.io.errors import RecordingFormatError
from pdr.io.ipin import (
    beacon_table,
    check_pressure,
    gnss_fixes,
    landmark_table,
    quaternion_from_rotation_vector,
    warn_landmarks_outside,
)
from pdr.recording import Recording, Series

# variable -> least number of columns this loader needs
_COLUMNS = {"Acce": 5, "Gyro": 5, "Magn": 5, "Pres": 3, "Ahrs": 8, "Gnss": 7, "Posi": 4}
REQUIRED = ("Acce", "Gyro")
# the variables that tell an organisers' IPIN .mat apart from other MATLAB files
SIGNATURE = frozenset({"Acce", "Gyro", "Posi"})


def load_ipin_mat(path: str | Path) -> Recording:
    """Load an organisers' IPIN ``.mat`` walk; the same :class:`Recording` as the text log gives."""
    notes = Notes(path)
    m = load_mat(path)
    arr = {k: _table(m, k, n, path) for k, n in _COLUMNS.items()}
    acce = arr["Acce"]
    offset = float(np.median(acce[:, 1] - acce[:, 0]))
    offset_mad = float(np.median(np.abs(acce[:, 1] - acce[:, 0] - offset)))

    def series(kind: str, a: np.ndarray | None, values_of) -> Series | None:
        if a is None or a.shape[0] == 0:
            return None
        t, values = a[:, 1], values_of(a)
        order = time_order(t, f"{kind} sensor timestamps", notes)
        if order is not None:
            t, values = t[order], values[order]
        return Series(t=t, values=values)

    pres = arr["Pres"]
    if pres is not None:
        check_pressure(pres, notes)
    meta = {
        "format": "IPIN 2023 Track 3 organisers' MATLAB parse of a GetSensorData log (.mat)",
        "line_counts": {k.upper(): int(a.shape[0]) for k, a in arr.items() if a is not None},
        "app_to_sensor_offset_s": offset,
        "app_to_sensor_offset_mad_s": offset_mad,
        "device_orientation_source": "Android rotation vector: body -> ENU (x east, y magnetic north, z up)",
        "phone_model": None,
        "landmark_counter": "not in the .mat: numbered 1..M in time order",
    }
    g = arr["Gnss"]
    gnss = None if g is None or not len(g) else gnss_fixes(g[:, [0, 1, 2, 3, 4, 6]], offset, meta, notes)
    p = arr["Posi"]
    landmarks = None
    if p is not None and len(p):
        rows = np.column_stack([p[:, 0], np.arange(1, len(p) + 1), p[:, 1], p[:, 2], p[:, 3], np.full(len(p), np.nan)])
        landmarks = landmark_table(rows, offset, path, lambda k: None, meta, notes)
    acc = series("Acce", acce, lambda a: a[:, 2:5])
    warn_landmarks_outside(landmarks, acc, notes)
    ble = _ble4(m.get("Ble4"), offset, path, notes)
    return Recording(
        source=str(path),
        kind="ipin",
        acc=acc,
        gyr=series("Gyro", arr["Gyro"], lambda a: a[:, 2:5]),
        mag=series("Magn", arr["Magn"], lambda a: a[:, 2:5]),
        pressure=series("Pres", pres, lambda a: a[:, 2:3]),
        gnss=gnss,
        ble=ble,
        landmarks=landmarks,
        device_orientation=series("Ahrs", arr["Ahrs"], lambda a: quaternion_from_rotation_vector(a[:, 5:8])),
        frame="ENU",
        meta=meta,
        warnings=notes.messages,
    )


def _ble4(cells, offset: float, path, notes: Notes):
    """``Ble4``: a cell array N x 3 (AppTs, MAC, RSSI dBm) -> beacon readings on the sensor clock;
    rows that do not read as such are skipped with a warning."""
    if cells is None or getattr(cells, "size", 0) == 0:
        return None
    if cells.ndim != 2 or cells.shape[1] < 3:
        notes.warn(f"Ble4: expected N x 3 cells (AppTs, MAC, RSSI), found shape {cells.shape}; beacons skipped")
        return None
    t, ids, rssi, bad = [], [], [], 0
    for row in cells:
        try:
            app_t, mac, level = float(np.ravel(row[0])[0]), str(np.ravel(row[1])[0]).strip().upper(), float(np.ravel(row[2])[0])
        except (IndexError, TypeError, ValueError):
            bad += 1
            continue
        if not (mac and np.isfinite(app_t) and np.isfinite(level)):
            bad += 1
            continue
        t.append(app_t + offset)
        ids.append(mac)
        rssi.append(level)
    if bad:
        notes.warn(f"Ble4: {bad} row(s) without a time, a MAC or an RSSI skipped")
    return beacon_table(t, ids, rssi, np.full(len(t), np.nan))


def _table(m: dict, key: str, ncols: int, path) -> np.ndarray | None:
    """Variable ``key`` as an (N, >= ncols) float array; None when absent or empty (optional ones)."""
    if key not in m:
        if key in REQUIRED:
            present = ", ".join(sorted(m)) or "none"
            raise RecordingFormatError(path, f"missing (fields present: {present})", field=key)
        return None
    a = numeric(m, key, path)
    if a.size == 0:
        if key in REQUIRED:
            raise RecordingFormatError(path, "empty", field=key)
        return None
    if a.ndim != 2 or a.shape[1] < ncols:
        raise RecordingFormatError(path, f"expected an N x {ncols} (or wider) matrix, found shape {a.shape}", field=key)
    bad = ~np.isfinite(a[:, :ncols])
    if bad.any():
        k = int(np.argwhere(bad)[0][0])
        raise RecordingFormatError(path, f"{int(bad.sum())} value(s) are NaN or infinite, first in row {k + 1}", field=key)
    return a
