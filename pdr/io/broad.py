"""BROAD trials (9-axis IMU with an optical orientation reference) as a :class:`Recording`.

Source: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7):72, 2021 (CC BY 4.0); github.com/dlaidig/broad.

One MATLAB v5 file per trial, N samples at one fixed rate (about 286 Hz):

* ``imu_gyr`` N x 3 in rad/s, ``imu_acc`` N x 3 in m/s², ``imu_mag`` N x 3 in µT;
* ``opt_quat`` N x 4, (w, x, y, z): the orientation of the IMU's own axes with respect to
  ENU (x east, y north, z up), rotating body -> ENU; already aligned to the IMU by the data
  set's authors. Rows are NaN where the cameras lost the markers;
* ``opt_pos`` N x 3 in m (not used here);
* ``movement`` N x 1, boolean (stored as 0/1): the samples that count in the benchmark's
  metric;
* ``sampling_rate`` 1 x 1 in Hz; the time of sample i is ``i / sampling_rate``;
* ``info`` a text describing the trial.

Frame convention (stated here, never guessed by a filter): the reference and the filter
output are both body -> ENU, so ``Recording.frame == "ENU"``.

``trials.json`` (next to the files) lists every trial of the benchmark and its groups;
:func:`load_broad_groups` reads it.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pdr.io._common import Notes, file_must_exist
from pdr.io._mat import load_mat, matrix, numeric
from pdr.io.errors import RecordingFormatError
from pdr.recording import Recording, Series

FIELDS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")
_PLAUSIBLE_RATE_HZ = (1.0, 10000.0)  # a sampling_rate outside this is not in Hz
_PLAUSIBLE_MEDIAN_ACC = (4.0, 40.0)  # m/s²; a file in g would have a median near 1
_QUAT_NORM_TOLERANCE = 0.01  # reference quaternions further than this from unit length are reported


def is_broad(fields: list[str]) -> bool:
    """Whether a .mat file's variable names are those of a BROAD trial."""
    return {"imu_gyr", "imu_acc", "opt_quat"} <= set(fields)


def load_broad(path: str | Path) -> Recording:
    """Load one BROAD trial; ``orientation_ref`` is ``opt_quat`` (body -> ENU, NaN rows kept).

    meta: ``movement`` (N bools), ``trial`` (file stem), ``rate_hz``, ``info``,
    ``reference_missing`` (fraction of NaN reference rows).
    """
    notes = Notes(path)
    m = load_mat(path)
    gyr = matrix(m, "imu_gyr", 3, path)
    acc = matrix(m, "imu_acc", 3, path)
    mag = matrix(m, "imu_mag", 3, path)
    q = matrix(m, "opt_quat", 4, path, finite=False)
    movement = _movement(m, path)
    rate = _rate(m, path)

    lengths = {"imu_gyr": len(gyr), "imu_acc": len(acc), "imu_mag": len(mag), "opt_quat": len(q),
               "movement": len(movement)}
    if len(set(lengths.values())) != 1:
        listing = ", ".join(f"{k} {v}" for k, v in lengths.items())
        raise RecordingFormatError(path, f"sample-aligned fields differ in length ({listing})")
    n = len(gyr)

    missing = ~np.isfinite(q).all(axis=1)
    if missing.all():
        raise RecordingFormatError(path, "no finite reference quaternion", field="opt_quat")
    partial = ~np.isfinite(q).all(axis=1) & np.isfinite(q).any(axis=1)
    if partial.any():
        notes.warn(f"opt_quat: {int(partial.sum())} row(s) partly NaN; treated as missing")
    q = q.copy()
    q[missing] = np.nan
    norms = np.linalg.norm(q[~missing], axis=1)
    if np.any(np.abs(norms - 1.0) > _QUAT_NORM_TOLERANCE):
        notes.warn(f"opt_quat norms span {norms.min():.3f}..{norms.max():.3f}; renormalised")
    q[~missing] /= norms[:, None]

    g = float(np.median(np.linalg.norm(acc, axis=1)))
    if not _PLAUSIBLE_MEDIAN_ACC[0] < g < _PLAUSIBLE_MEDIAN_ACC[1]:
        raise RecordingFormatError(path, f"median norm {g:.3g} is not that of m/s² (BROAD stores m/s²)",
                                   field="imu_acc")
    if not movement.any():
        notes.warn("movement marks no sample; the benchmark's metric has nothing to score")

    t = np.arange(n) / rate
    info = m.get("info")
    meta = {
        "format": "BROAD benchmark trial (.mat)",
        "trial": Path(path).stem,
        "rate_hz": rate,
        "movement": movement,
        "reference_missing": float(missing.mean()),
        "info": str(np.ravel(info)[0]) if info is not None and np.size(info) else "",
        "other_fields": sorted(set(m) - set(FIELDS) - {"info"}),
    }
    return Recording(
        source=str(path),
        kind="broad",
        acc=Series(t=t, values=acc),
        gyr=Series(t=t, values=gyr),
        mag=Series(t=t, values=mag),
        orientation_ref=Series(t=t, values=q),
        frame="ENU",
        meta=meta,
        warnings=notes.messages,
    )


def _movement(m: dict, path) -> np.ndarray:
    mv = numeric(m, "movement", path)
    if mv.ndim > 2 or (mv.ndim == 2 and min(mv.shape) > 1) or mv.size == 0:
        raise RecordingFormatError(path, f"expected an N x 1 vector, found shape {mv.shape}", field="movement")
    mv = mv.ravel()
    if not np.isin(mv, (0.0, 1.0)).all():
        bad = np.flatnonzero(~np.isin(mv, (0.0, 1.0)))[0]
        raise RecordingFormatError(path, f"expected booleans (0/1), found {mv[bad]!r} at sample {bad}",
                                   field="movement")
    return mv.astype(bool)


def _rate(m: dict, path) -> float:
    r = numeric(m, "sampling_rate", path)
    if r.size != 1:
        raise RecordingFormatError(path, f"expected one number (Hz), found shape {r.shape}", field="sampling_rate")
    rate = float(r.ravel()[0])
    if not (np.isfinite(rate) and _PLAUSIBLE_RATE_HZ[0] <= rate <= _PLAUSIBLE_RATE_HZ[1]):
        raise RecordingFormatError(path, f"{rate!r} is not a plausible rate in Hz", field="sampling_rate")
    return rate


def load_broad_groups(path: str | Path) -> dict[str, list[str]]:
    """``trials.json`` of BROAD: trial name -> the groups it belongs to (e.g. "disturbed")."""
    p = file_must_exist(path)
    try:
        doc = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordingFormatError(p, f"cannot read as JSON ({exc})") from None
    trials = doc.get("trials") if isinstance(doc, dict) else None
    if not isinstance(trials, dict):
        raise RecordingFormatError(p, "expected an object with a 'trials' mapping", field="trials")
    groups = {}
    for name, entry in trials.items():
        g = entry.get("groups") if isinstance(entry, dict) else None
        if not isinstance(g, list) or not all(isinstance(x, str) for x in g):
            raise RecordingFormatError(p, f"trial {name!r} has no list of group names", field="groups")
        groups[name] = list(g)
    return groups
