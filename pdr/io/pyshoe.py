"""PyShoe foot-mounted IMU recordings (MATLAB .mat) as a :class:`Recording`.

Source: Wagstaff, B., Peretroukhin, V., Kelly, J., "University of Toronto Foot-Mounted
Inertial Navigation Dataset", IEEE DataPort 2021, doi:10.21227/v1z6-9z84, in the annotated
form of github.com/mtahakoroglu/LLIO-aided-iPyShoe (MIT).

MATLAB v5 variables (N samples, S strides):

* ``imu_data`` N x 6: ax ay az (m/s²), gx gy gz (rad/s), a 3DM-GX3-25 on the shoe, 200 Hz;
* per-sample time in seconds: ``timestamps_all`` (1 x N) in the Vicon files, where
  ``timestamps`` (1 x S) holds the stride times; in the ``SensorConnectData_*`` files there is
  no ``timestamps_all`` and ``timestamps`` is per sample;
* ``gt`` N x 2: Vicon x, y (m) in the motion-capture room frame (Vicon files only);
* ``strideIndex`` 1 x S: 0-based sample index of each stride end (``timestamps_all[i]`` equals
  the stride time and ``gt[i]`` equals ``GCP``), ``GCP`` S x 2: positions at the stride ends
  (ground control points);
* ``pyshoeTrajectory`` N x 2: the published PyShoe ZUPT-aided INS result, a peer's answer.

Other variables (``euler_angles``, ``acc_n``, ``traj_wcf``, ...) are derived results and are
listed in ``meta["other_fields"]`` but not loaded.

Handedness. PyShoe navigates in a z-down frame (it adds +g to the vertical specific force,
as in NED), and ``gt``, ``GCP`` and ``pyshoeTrajectory`` are the x, y of that frame: with z
up they form a *left*-handed frame, the mirror image of ENU (an INS integrating the same
IMU in ENU draws the walk mirrored, and no rotation aligns the two). The loader therefore
swaps the two axes — ``(x, y)_loaded = (y, x)_file``, i.e. x = the file's y ("east" of a
north-east-down frame) and y = the file's x ("north") — so that every loaded position is
in a right-handed, z-up horizontal frame. ``meta["position_frame"]`` says so.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pdr.io._common import Notes, common_length, time_order
from pdr.io._mat import load_mat, matrix, vector
from pdr.io.errors import RecordingFormatError
from pdr.recording import Recording, Series

NOMINAL_RATE_HZ = 200.0  # the data set's IMU rate, used only when a file has no per-sample time
_PLAUSIBLE_RATE_HZ = (20.0, 5000.0)  # a per-sample time whose median rate falls outside is not seconds
_PLAUSIBLE_MEDIAN_ACC = (4.0, 40.0)  # m/s²; a file in g would have a median of 1-2
_TIME_UNITS = ((1.0, "s"), (1e-3, "ms"), (1e-6, "us"), (1e-9, "ns"))
_LOADED = {"imu_data", "timestamps_all", "timestamps", "gt", "strideIndex", "GCP", "pyshoeTrajectory"}


def load_pyshoe(path: str | Path) -> Recording:
    """Load a PyShoe/LLIO ``.mat`` file; ``position_ref`` is Vicon x, y when the file has ``gt``.

    meta: ``stride_index`` (0-based sample indices), ``stride_t`` (s), ``gcp`` (S x 2 m),
    ``pyshoe_trajectory`` (N x 2 m), ``rate_hz``. Sample-aligned arrays that differ by a few
    samples are trimmed to the shortest (see :func:`pdr.io._common.common_length`).
    """
    notes = Notes(path)
    m = load_mat(path)
    imu = matrix(m, "imu_data", 6, path)
    gt = matrix(m, "gt", 2, path, required=False)
    peer = matrix(m, "pyshoeTrajectory", 2, path, required=False, finite=False)
    stride_index = vector(m, "strideIndex", path, required=False)
    gcp = matrix(m, "GCP", 2, path, required=False, finite=False)
    t, time_field = _sample_time(m, imu.shape[0], stride_index, path, notes)
    gt, peer, gcp = (None if a is None else a[:, ::-1].copy() for a in (gt, peer, gcp))  # z-down x, y -> z-up

    aligned = {"imu_data": imu, time_field: t, "gt": gt, "pyshoeTrajectory": peer}
    aligned = {k: v for k, v in aligned.items() if v is not None}
    n_stored = imu.shape[0]
    n = common_length({k: v.shape[0] for k, v in aligned.items()}, path, notes)
    imu, t = imu[:n], t[:n]
    gt = None if gt is None else gt[:n]
    peer = None if peer is None else peer[:n]
    t, scale = _in_seconds(t, time_field, path, notes)

    t_stored = t
    order = time_order(t, time_field, notes)
    if order is not None:
        t, imu = t[order], imu[order]
        gt = None if gt is None else gt[order]
        peer = None if peer is None else peer[order]

    meta: dict = {
        "format": "PyShoe / LLIO foot-mounted IMU (.mat)",
        "imu": "3DM-GX3-25 on the shoe",
        "time_field": time_field,
        "rate_hz": float(1.0 / np.median(np.diff(t))),
        "other_fields": sorted(set(m) - _LOADED),
    }
    if peer is not None:
        meta["pyshoe_trajectory"] = peer
    meta["carry"] = "foot"  # a boot-mounted IMU (the wire's carry name)
    meta["position_frame"] = "x = the file's y, y = the file's x (the file's x, y are of a z-down frame), m"
    if gt is not None:
        meta["position_ref_frame"] = "Vicon room frame, axes swapped to right-handed z-up (see position_frame), m"
    if stride_index is not None:
        stride_t = None
        if time_field == "timestamps_all" and "timestamps" in m:
            stride_t = vector(m, "timestamps", path, finite=False) * scale
        _strides(stride_index, gcp, stride_t, t_stored, order, n_stored, path, meta, notes)
    _check_gravity(imu[:, :3], notes)

    return Recording(
        source=str(path),
        kind="pyshoe",
        acc=Series(t=t, values=imu[:, :3]),
        gyr=Series(t=t, values=imu[:, 3:6]),
        position_ref=None if gt is None else Series(t=t, values=gt),
        meta=meta,
        warnings=notes.messages,
    )


def _sample_time(m: dict, n: int, stride_index: np.ndarray | None, path, notes: Notes) -> tuple[np.ndarray, str]:
    """The per-sample time vector and the name of the field it came from."""
    if "timestamps_all" in m:
        return vector(m, "timestamps_all", path), "timestamps_all"
    ts = vector(m, "timestamps", path, required=False)
    per_stride = ts is not None and stride_index is not None and ts.size == stride_index.size and ts.size < n // 2
    if ts is not None and not per_stride:
        return ts, "timestamps"
    notes.warn(f"no per-sample timestamps; assuming the data set's {NOMINAL_RATE_HZ:g} Hz")
    return np.arange(n) / NOMINAL_RATE_HZ, "nominal_rate"


def _in_seconds(t: np.ndarray, field: str, path, notes: Notes) -> tuple[np.ndarray, float]:
    """Times in seconds, and the factor used: the unit whose median rate is plausible for an IMU."""
    if t.size < 2:
        raise RecordingFormatError(path, "fewer than two samples", field=field)
    dt = float(np.median(np.diff(t)))
    for scale, unit in _TIME_UNITS:
        rate = 1.0 / (dt * scale) if dt > 0 else float("inf")
        if _PLAUSIBLE_RATE_HZ[0] <= rate <= _PLAUSIBLE_RATE_HZ[1]:
            if unit != "s":
                notes.warn(f"{field} looks like {unit} (median step {dt:g}); converted to s")
            return t * scale, scale
    raise RecordingFormatError(path, f"median time step {dt:g} fits no unit (s, ms, us, ns) at an IMU rate", field=field)


def _strides(stride_index: np.ndarray, gcp: np.ndarray | None, stride_t: np.ndarray | None,
             t_stored: np.ndarray, order: np.ndarray | None, n_stored: int, path, meta: dict,
             notes: Notes) -> None:
    """Stride ends as 0-based sample indices into the loaded series, checked and repaired.

    ``t_stored`` is the sample time in file order (after trimming), ``order`` the sort
    applied to it, ``n_stored`` the file's sample count before trimming.
    """
    if np.any(stride_index != np.round(stride_index)):
        raise RecordingFormatError(path, "stride indices are not integers", field="strideIndex")
    idx = stride_index.astype(np.int64)
    if gcp is not None and gcp.shape[0] != idx.size:
        raise RecordingFormatError(path, f"{gcp.shape[0]} ground control points for {idx.size} strides", field="GCP")
    if stride_t is not None and stride_t.size != idx.size:
        raise RecordingFormatError(path, f"{stride_t.size} stride times for {idx.size} strides", field="timestamps")
    n = t_stored.size
    if idx.size and stride_t is not None and _one_based(idx, stride_t, t_stored):
        notes.warn("strideIndex is 1-based (MATLAB); converted to 0-based")
        idx = idx - 1
    if idx.size and (idx.min() < 0 or idx.max() >= n_stored):
        raise RecordingFormatError(
            path, f"stride indices span {idx.min()}..{idx.max()}, data has {n_stored} samples (0-based)",
            field="strideIndex",
        )
    lost = idx >= n  # stride ends in the samples trimmed off the end
    if lost.any():
        notes.warn(f"{int(lost.sum())} stride end(s) in the trimmed samples dropped")
        idx = idx[~lost]
        gcp = None if gcp is None else gcp[~lost]
    if order is not None:  # samples were reordered: follow each stride end to its new place
        idx = np.searchsorted(t_stored[order], t_stored[idx])
    meta["stride_index"] = idx
    meta["stride_t"] = t_stored[order][idx] if order is not None else t_stored[idx]
    if gcp is not None:
        meta["gcp"] = gcp


def _one_based(idx: np.ndarray, stride_t: np.ndarray, t: np.ndarray) -> bool:
    """True when the per-stride times match ``t[idx - 1]`` and not ``t[idx]``."""
    ok = (idx >= 1) & (idx < t.size)
    if not ok.any():
        return False
    half_step = 0.5 * float(np.median(np.diff(t)))
    zero = np.abs(t[idx[ok]] - stride_t[ok]) < half_step
    one = np.abs(t[idx[ok] - 1] - stride_t[ok]) < half_step
    return bool(one.mean() > 0.9 and zero.mean() < 0.5)


def _check_gravity(acc: np.ndarray, notes: Notes) -> None:
    """Catch an accelerometer in g: a shoe's median |acc| is 1-2 g, i.e. 10-20 m/s²."""
    g = float(np.median(np.linalg.norm(acc, axis=1)))
    if not _PLAUSIBLE_MEDIAN_ACC[0] < g < _PLAUSIBLE_MEDIAN_ACC[1]:
        notes.warn(f"median |acc| is {g:.2f}: not m/s² on a walking foot, check the units")
