"""Reading MATLAB v5 files with errors that name the file and the field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io

from pdr.io._common import file_must_exist
from pdr.io.errors import RecordingFormatError


def mat_fields(path: str | Path) -> list[str]:
    """Names of the variables in a .mat file, without reading their data."""
    p = file_must_exist(path)
    try:
        return [name for name, _shape, _cls in scipy.io.whosmat(p)]
    except Exception as exc:  # scipy raises many kinds (ValueError, TypeError, OSError, ...)
        raise RecordingFormatError(p, f"cannot read as a MATLAB .mat file ({type(exc).__name__}: {exc})") from None


def load_mat(path: str | Path) -> dict[str, np.ndarray]:
    """All variables of a MATLAB v5 file (v7.3 / HDF5 files are not supported)."""
    p = file_must_exist(path)
    if p.stat().st_size == 0:
        raise RecordingFormatError(p, "empty file")
    try:
        m = scipy.io.loadmat(p)
    except Exception as exc:  # truncated, not a .mat, v7.3, ...: always the same answer
        raise RecordingFormatError(p, f"cannot read as a MATLAB .mat file ({type(exc).__name__}: {exc})") from None
    return {k: v for k, v in m.items() if not k.startswith("__")}


def numeric(m: dict, key: str, path: str | Path, required: bool = True) -> np.ndarray | None:
    """Field ``key`` as a float64 array; a clear error when it is missing or not numeric."""
    if key not in m:
        if not required:
            return None
        present = ", ".join(sorted(m)) or "none"
        raise RecordingFormatError(path, f"missing (fields present: {present})", field=key)
    try:
        arr = np.asarray(m[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordingFormatError(path, f"not numeric (MATLAB type {type(m[key]).__name__})", field=key) from None
    return arr


def matrix(m: dict, key: str, ncols: int, path: str | Path, required: bool = True,
           finite: bool = True) -> np.ndarray | None:
    """Field ``key`` as an (N, ncols) array; a (ncols, N) array is transposed."""
    arr = numeric(m, key, path, required)
    if arr is None:
        return None
    if arr.ndim == 2 and arr.shape[1] != ncols and arr.shape[0] == ncols:
        arr = arr.T
    if arr.ndim != 2 or arr.shape[1] != ncols or arr.shape[0] == 0:
        raise RecordingFormatError(path, f"expected an N x {ncols} matrix, found shape {arr.shape}", field=key)
    if finite:
        require_finite(arr, key, path)
    return arr


def vector(m: dict, key: str, path: str | Path, required: bool = True, finite: bool = True) -> np.ndarray | None:
    """Field ``key`` as a 1-D array (MATLAB stores vectors as 1 x N or N x 1)."""
    arr = numeric(m, key, path, required)
    if arr is None:
        return None
    if arr.ndim > 2 or (arr.ndim == 2 and min(arr.shape) > 1) or arr.size == 0:
        raise RecordingFormatError(path, f"expected a vector, found shape {arr.shape}", field=key)
    arr = arr.ravel()
    if finite:
        require_finite(arr, key, path)
    return arr


def require_finite(arr: np.ndarray, key: str, path: str | Path) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        k = int(np.argwhere(bad)[0][0])
        raise RecordingFormatError(
            path, f"{int(bad.sum())} value(s) are NaN or infinite, first at sample {k} (0-based)", field=key
        )
