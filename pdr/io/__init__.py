"""Loaders for real recording formats, at the edge of pdr.

Each loader reads one format into :class:`pdr.recording.Recording` (SI units, device-clock
seconds) and raises :class:`RecordingFormatError` naming the file and the line or field
when the file is bad. Repairs it can make (a truncated last line, a few extra samples,
out-of-order timestamps) are kept in ``Recording.warnings`` and raised as
:class:`RecordingWarning`.

* :func:`load_ipin` - GetSensorData ``.txt`` / ``.txt.gz`` (IPIN 2023 Track 3, smartphone);
* :func:`load_ipin_mat` - the organisers' ``.mat`` parse of such a log (``Acce``, ``Gyro``, ``Posi``, ...);
* :func:`load_oxford` - walk directory or ``.csv.gz`` (Oxford step counter, smartphone);
* :func:`load_pyshoe` - ``.mat`` with ``imu_data`` (PyShoe / LLIO, foot IMU with Vicon);
* :func:`load_vicon_ahrs` - ``.mat`` with ``qViconReference`` (Justa AHRS set with Vicon);
* :func:`load_broad` - ``.mat`` with ``imu_gyr`` and ``opt_quat`` (BROAD benchmark trial);
* :func:`load` - any of the above, chosen from the name and content.
"""
from __future__ import annotations

import re
from pathlib import Path

from pdr.io._mat import mat_fields
from pdr.io._text import GZIP_MAGIC, inflate_member
from pdr.io.broad import is_broad, load_broad, load_broad_groups
from pdr.io.errors import RecordingFormatError, RecordingWarning
from pdr.io.ipin import load_ipin
from pdr.io.ipin_mat import SIGNATURE as _IPIN_MAT_FIELDS
from pdr.io.ipin_mat import load_ipin_mat
from pdr.io.oxford import load_oxford
from pdr.io.pyshoe import load_pyshoe
from pdr.io.vicon_ahrs import load_vicon_ahrs
from pdr.recording import Recording

__all__ = [
    "load",
    "load_broad",
    "load_broad_groups",
    "load_ipin",
    "load_ipin_mat",
    "load_oxford",
    "load_pyshoe",
    "load_vicon_ahrs",
    "RecordingFormatError",
    "RecordingWarning",
]

_SNIFF_BYTES = 8192
_IPIN_LINE = re.compile(r"^(ACCE|GYRO|MAGN|PRES|POSI|AHRS|GNSS);", re.MULTILINE)
_CSV_NUMBERS = re.compile(r"^\s*-?\d+(\.\d*)?([eE][-+]?\d+)?(\s*,\s*-?\d+(\.\d*)?([eE][-+]?\d+)?)+\s*$")


def load(path: str | Path) -> Recording:
    """Load any supported recording, choosing the loader from the name and content.

    * a directory holding ``accelerometer.csv(.gz)`` -> Oxford (optimisation layout);
    * ``.mat`` with ``imu_data`` -> PyShoe; with ``qViconReference`` -> Vicon AHRS;
      with ``imu_gyr``, ``imu_acc`` and ``opt_quat`` -> BROAD; with ``Acce``, ``Gyro`` and
      ``Posi`` -> IPIN (the organisers' parse of a GetSensorData log);
    * text (plain or gzip) with the GetSensorData header or its line types -> IPIN;
    * text whose rows are 5 or 7 comma-separated numbers -> Oxford.
    """
    p = Path(path)
    if not p.exists():
        raise RecordingFormatError(p, "file not found")
    if p.is_dir():
        if any((p / n).is_file() for n in ("accelerometer.csv.gz", "accelerometer.csv")):
            return load_oxford(p)
        raise RecordingFormatError(p, "directory holds no recording this package can read")
    if p.suffix.lower() == ".mat":
        fields = mat_fields(p)
        if "imu_data" in fields:
            return load_pyshoe(p)
        if "qViconReference" in fields:
            return load_vicon_ahrs(p)
        if is_broad(fields):
            return load_broad(p)
        if _IPIN_MAT_FIELDS <= set(fields):
            return load_ipin_mat(p)
        raise RecordingFormatError(
            p, "a .mat file with none of 'imu_data' (PyShoe), 'qViconReference' (Vicon AHRS), "
               f"'imu_gyr' + 'imu_acc' + 'opt_quat' (BROAD) or 'Acce'/'Gyro'/'Posi' (IPIN); fields: {fields}"
        )
    head = _head(p)
    if "GetSensorData" in head or _IPIN_LINE.search(head):
        return load_ipin(p)
    first = next((ln for ln in head.splitlines() if ln.strip() and not ln.startswith("#")), "")
    if _CSV_NUMBERS.match(first) and first.count(",") + 1 in (5, 7):
        return load_oxford(p)
    raise RecordingFormatError(p, "unknown recording format (not IPIN, Oxford, PyShoe, Vicon AHRS or BROAD)")


def _head(p: Path) -> str:
    """The first few kilobytes of a text file, gunzipped when needed, for sniffing."""
    try:
        with p.open("rb") as f:
            raw = f.read(_SNIFF_BYTES)
    except OSError as exc:
        raise RecordingFormatError(p, f"cannot read file: {exc}") from None
    if raw[:2] == GZIP_MAGIC:
        raw, _complete, _rest, error = inflate_member(raw)
        if not raw:
            raise RecordingFormatError(p, f"gzip data could not be decompressed ({error or 'truncated'})")
    return raw[:_SNIFF_BYTES].decode("utf-8", errors="replace")
