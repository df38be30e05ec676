"""Oxford step-counter recordings (smartphone accelerometer, counted steps) as a :class:`Recording`.

Source: github.com/Oxford-step-counter/DataSet (CC BY 4.0); Salvi, D. et al., "An optimised
algorithm for accurate steps counting from smart-phone accelerometry", IEEE EMBC 2018.

Two layouts, both comma-separated without a header, timestamps in nanoseconds since boot
(the phone's sensor clock), acceleration in m/s² including gravity:

* ``optimisation/<Phone>_<User>_<Surface>_<Position>_<n>/accelerometer.csv.gz`` with rows
  ``timestamp_ns, sensor_accuracy, ax, ay, az``. The true step count of each walk is in
  ``optimisation/stats.csv`` (header ``#dir, user, phone, position, surface, duration(s),
  steps``, fields padded with spaces), keyed by the directory name. ``stepcounter.csv.gz``
  next to it has two undocumented 0/1 columns; each toggles about once per step, and the
  mean of their toggle counts matches ``stats.csv`` within one step on every walk, so it
  looks like the ground-truth device's trace rather than the phone's sensor. It is not read:
  ``stats.csv`` is the documented truth.
* ``validation/<user>_<position>_<unix_ms>.csv.gz`` (or ``stepcounter_<unix_ms>.csv``) with
  rows ``timestamp_ns, ax, ay, az, steps_their_algorithm, steps_ground_truth,
  steps_phone_hardware``; the three counts are running totals.

Times are kept on the phone's clock in seconds (nanoseconds / 1e9). There is no gyroscope.
"""
from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from pdr.io._common import Notes, file_must_exist, time_order
from pdr.io._text import drop_partial_last_line, parse_rows, read_text
from pdr.io.errors import RecordingFormatError
from pdr.recording import Recording, Series

_OPTIMISATION_FIELDS = 5  # timestamp_ns, sensor_accuracy, ax, ay, az
_VALIDATION_FIELDS = 7  # timestamp_ns, ax, ay, az, their_algorithm, ground_truth, phone_hardware
_ACCELEROMETER_NAMES = ("accelerometer.csv.gz", "accelerometer.csv")
_STATS_NAME = "stats.csv"

# Carry positions as the data set spells them (with varying case) -> one spelling.
_CARRY = {
    "inhand": "InHand",
    "hand": "InHand",
    "frontpocket": "FrontPocket",
    "backpocket": "BackPocket",
    "armband": "Armband",
    "neckpouch": "NeckPouch",
    "purse": "Purse",
    "bag": "Bag",
    "swingingarm": "SwingingArm",
}


def load_oxford(path: str | Path) -> Recording:
    """Load one Oxford walk: a walk directory, its ``accelerometer.csv.gz``, or a validation file.

    ``true_steps`` is the counted total (``stats.csv`` or the ground-truth running count's
    last minus first value); ``None`` with a warning when the walk has no count.
    ``meta["carry"]`` is the phone's position (``InHand``, ``FrontPocket``, ...) when known.
    For validation files ``step_count_ref`` is the ground-truth running count as recorded,
    and the authors' algorithm and the phone's hardware counter are in
    ``meta["their_algorithm_steps"]`` / ``meta["phone_hardware_steps"]`` (Series, like
    ``step_count_ref``) with their totals in ``..._total``.
    """
    p = file_must_exist(path)
    if p.is_dir():
        found = [p / name for name in _ACCELEROMETER_NAMES if (p / name).is_file()]
        if not found:
            raise RecordingFormatError(p, "no accelerometer.csv.gz in this walk directory")
        return _load_optimisation(found[0], walk=p.name, stats=p.parent / _STATS_NAME)
    if p.name in _ACCELEROMETER_NAMES:
        return _load_optimisation(p, walk=p.parent.name, stats=p.parent.parent / _STATS_NAME)
    notes = Notes(p)
    text = read_text(p, notes)
    n_fields = _first_row_fields(text)
    if n_fields == _VALIDATION_FIELDS:
        return _load_validation(p, text, notes)
    if n_fields == _OPTIMISATION_FIELDS:
        return _load_optimisation(p, walk=_stem(p), stats=None, text=text, notes=notes)
    raise RecordingFormatError(
        p, f"not an Oxford step-counter file: rows have {n_fields} fields, expected 5 or 7"
    )


def _load_optimisation(acc_file: Path, walk: str, stats: Path | None,
                       text: str | None = None, notes: Notes | None = None) -> Recording:
    notes = notes or Notes(acc_file)
    if text is None:
        text = read_text(acc_file, notes)
    data = _rows(acc_file, text, _OPTIMISATION_FIELDS, (0, 1, 2, 3, 4), notes)
    t, data = _in_time_order(data, notes)
    meta: dict = {"format": "Oxford step-counter, optimisation layout", "walk": walk}
    accuracy, counts = np.unique(data[:, 1].astype(int), return_counts=True)
    meta["sensor_accuracy_counts"] = {int(a): int(n) for a, n in zip(accuracy, counts)}

    if stats is None:
        notes.warn("no stats.csv for this file: true step count unknown")
        row = None
    else:
        row = _stats_row(stats, walk, notes)  # warns itself when there is no row
    true_steps = None
    if row is not None:
        true_steps = row["steps"]
        meta.update({k: row[k] for k in ("user", "phone", "surface") if row.get(k)})
        if row.get("duration_s") is not None:
            meta["stats_duration_s"] = row["duration_s"]
    _set_carry(meta, row.get("position") if row else None, walk)
    sensor = _sensor_name(acc_file.parent / "metadata.txt")
    if sensor:
        meta["sensor"] = sensor

    return Recording(
        source=str(acc_file),
        kind="oxford",
        acc=Series(t=t, values=data[:, 2:5]),
        true_steps=true_steps,
        meta=meta,
        warnings=notes.messages,
    )


def _load_validation(path: Path, text: str, notes: Notes) -> Recording:
    data = _rows(path, text, _VALIDATION_FIELDS, tuple(range(_VALIDATION_FIELDS)), notes)
    t, data = _in_time_order(data, notes)
    truth, theirs, hardware = data[:, 5], data[:, 4], data[:, 6]
    if np.any(np.diff(truth) < 0):
        notes.warn("ground-truth step count decreases somewhere; true_steps = last - first regardless")
    name = _stem(path)
    meta: dict = {
        "format": "Oxford step-counter, validation layout",
        "their_algorithm_steps": Series(t=t, values=theirs[:, None]),
        "their_algorithm_total": int(round(theirs[-1] - theirs[0])),
        "phone_hardware_steps": Series(t=t, values=hardware[:, None]),
        "phone_hardware_total": int(round(hardware[-1] - hardware[0])),
    }
    m = re.match(r"^(user\d+)_", name)
    if m:
        meta["user"] = m.group(1)
    m = re.search(r"_(\d{13})$", name)
    if m:
        meta["start_unix_s"] = int(m.group(1)) / 1000.0
    _set_carry(meta, None, name)
    return Recording(
        source=str(path),
        kind="oxford",
        acc=Series(t=t, values=data[:, 1:4]),
        step_count_ref=Series(t=t, values=truth[:, None]),
        true_steps=int(round(truth[-1] - truth[0])),
        meta=meta,
        warnings=notes.messages,
    )


def _rows(path: Path, text: str, n_fields: int, usecols: tuple[int, ...], notes: Notes) -> np.ndarray:
    lines = text.split("\n")
    drop_partial_last_line(
        lines, text, n_fields=lambda _l: n_fields, usecols=lambda _l: usecols, delimiter=",", notes=notes
    )
    if "" in lines[:-1] or "\n#" in text or text.startswith("#"):
        numbers = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
        rows = [lines[i] for i in numbers]
    else:
        rows = lines[:-1] if lines[-1] == "" else lines
        numbers = None
    data = parse_rows(
        rows,
        usecols,
        path,
        "row",
        line_of=lambda k: (numbers[k] if numbers is not None else k) + 1,
        delimiter=",",
    )
    if data.shape[0] == 0:
        raise RecordingFormatError(path, "no data rows")
    return data


def _in_time_order(data: np.ndarray, notes: Notes) -> tuple[np.ndarray, np.ndarray]:
    t = data[:, 0] * 1e-9
    order = time_order(t, "timestamps", notes)
    if order is not None:
        t, data = t[order], data[order]
    return t, data


def _first_row_fields(text: str) -> int:
    for line in text.split("\n", 50)[:50]:
        if line.strip() and not line.startswith("#"):
            return len(line.split(","))
    return 0


def _stem(p: Path) -> str:
    name = p.name
    for suffix in (".gz", ".csv", ".txt"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def _set_carry(meta: dict, position: str | None, name: str) -> None:
    """Carry position from stats.csv when given, else from a token of the file/dir name."""
    candidates = [position] if position else []
    candidates += name.split("_")
    for c in candidates:
        carry = _CARRY.get(c.strip().lower())
        if carry:
            meta["carry"] = carry
            return


def _sensor_name(metadata: Path) -> str | None:
    """The accelerometer's name from a walk's optional ``metadata.txt`` (``accelerometer : X``)."""
    try:
        text = metadata.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    m = re.search(r"^\s*accelerometer\s*:\s*(.+?)\s*$", text, re.MULTILINE | re.IGNORECASE)
    return m.group(1) if m else None


def _stats_row(stats: Path, walk: str, notes: Notes) -> dict | None:
    """The stats.csv row of ``walk`` as a dict (steps as int), or None with a warning."""
    if not stats.is_file():
        notes.warn(f"no {stats.name} next to the walk directory: true step count unknown")
        return None
    try:
        text = stats.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RecordingFormatError(stats, f"cannot read file: {exc}") from None
    reader = csv.reader(text.splitlines(), skipinitialspace=True)
    columns: list[str] | None = None
    for number, fields in enumerate(reader, start=1):
        fields = [f.strip() for f in fields]
        if not fields or not any(fields):
            continue
        if fields[0].startswith("#"):
            columns = [f.lstrip("#").strip().lower() for f in fields]
            continue
        if fields[0] != walk:
            continue
        columns = columns or ["dir", "user", "phone", "position", "surface", "duration(s)", "steps"]
        row = dict(zip(columns, fields))
        if "steps" not in row:
            raise RecordingFormatError(stats, f"row for {walk!r} has no steps column", line=number, field="steps")
        try:
            row["steps"] = int(row["steps"])
        except ValueError:
            raise RecordingFormatError(
                stats, f"steps {row['steps']!r} is not an integer", line=number, field="steps"
            ) from None
        try:
            row["duration_s"] = float(row["duration(s)"]) if row.get("duration(s)") else None
        except ValueError:
            row["duration_s"] = None
        return row
    notes.warn(f"no row for {walk!r} in {stats}: true step count unknown")
    return None
