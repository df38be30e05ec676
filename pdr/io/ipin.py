"""IPIN 2023 smartphone logfiles ('GetSensorData' Android logger) as a :class:`Recording`.

Source: Torres-Sospedra, J. et al., "Datasets and Supporting Materials for the IPIN 2023
Competition Track 3 (Smartphone-based, off-site)", Zenodo 2023, doi:10.5281/zenodo.8362205
(CC BY 4.0), recorded in the Museum Industriekultur, Nuremberg. The logger is
'GetSensorData' by the LOPSI group (CAR-CSIC, Spain).

Format: text, plain or gzip. A ``%`` comment header names the phone and documents every
line type; then one reading per line, ``;``-separated, the first field its type::

    ACCE;AppTs;SensorTs;ax;ay;az;accuracy        m/s^2   (GYRO rad/s, MAGN uT: same shape)
    PRES;AppTs;SensorTs;pressure;accuracy        hPa (the header says mbar: the same unit)
    AHRS;AppTs;SensorTs;pitch;roll;yaw;q2;q3;q4;accuracy    the phone's own orientation
    GNSS;AppTs;UnixTs;lat;lon;alt;bearing;accuracy_m;speed;sat_view;sat_used
    POSI;AppTs;counter;lat;lon;floor;building    ground truth: walker on a surveyed landmark
    BLE4;AppTs;iBeacon;MAC;RSSI;Power;Major;Minor;UUID     one BLE advertisement heard (dBm)
    BLE4;AppTs;Eddystone;MAC;RSSI;instanceID;...

The header writes ``Mag_X(uT);;Mag_Y`` but the files have single separators; both are read.
BLE4 lines become :class:`pdr.recording.BeaconReadings` (:func:`beacon_readings`): the beacon
named by its MAC, the iBeacon ``Power`` field (its calibrated RSSI at 1 m, dBm) as tx power when
it is not 0 (the IPIN beacons all say 0: unknown). WIFI, LIGH, SOUN and the other documented
types are skipped and only counted.

Clocks. ``SensorTs`` is the device sensor clock (seconds since boot), accurate sample to
sample: every series in the Recording is on it. ``AppTs`` is when the app read a value, on
one app clock shared by all lines. POSI has only an AppTs and GNSS carries a Unix time (a
third clock), so both are moved to the sensor clock by the offset
``median(SensorTs - AppTs)`` over the ACCE lines, kept as ``meta["app_to_sensor_offset_s"]``
(``sensor_t = app_t + offset``; stale GNSS fixes are the one exception, see
:func:`load_ipin`). The median includes the app's read latency (a few ms in
the IPIN files), which is far below the landmark timing accuracy.

Speed: lines are grouped by type and each group is converted by :func:`numpy.loadtxt` at
once; a bad line is located by a slower scan only when that fails.
"""
from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdr.io._common import Notes, time_order
from pdr.io._text import drop_partial_last_line, parse_rows, read_text
from pdr.io.errors import RecordingFormatError
from pdr.recording import BeaconReadings, GnssFixes, Landmarks, Recording, Series


@dataclass(frozen=True)
class _LineKind:
    n_fields: int  # fields of a complete line, type included
    usecols: tuple[int, ...]  # the numeric fields this loader reads


_ACCE, _GYRO, _MAGN, _PRES, _AHRS, _GNSS, _POSI = "ACCE", "GYRO", "MAGN", "PRES", "AHRS", "GNSS", "POSI"
_IMU_COLS = (1, 2, 3, 4, 5)  # AppTs, SensorTs, x, y, z
_PARSED = {
    _ACCE: _LineKind(7, _IMU_COLS),
    _GYRO: _LineKind(7, _IMU_COLS),
    _MAGN: _LineKind(7, _IMU_COLS),
    _PRES: _LineKind(5, (1, 2, 3)),
    _AHRS: _LineKind(10, (1, 2, 6, 7, 8)),  # AppTs, SensorTs, rotation vector x, y, z
    _GNSS: _LineKind(11, (1, 2, 3, 4, 5, 7)),  # AppTs, UnixTs, lat, lon, alt, accuracy
    _POSI: _LineKind(7, (1, 2, 3, 4, 5, 6)),  # AppTs, counter, lat, lon, floor, building
}
# The other types the logger documents: counted, not read.
_IGNORED = frozenset("LIGH PROX HUMI TEMP WIFI BLUE SOUN RFID IMUX IMUL IMUI".split())
_BLE4 = "BLE4"  # read field by field (text fields): beacon_readings()
# MAGN as the header spells it, with an empty field after Mag_X.
_MAGN_DOUBLE_SEP_COLS = (1, 2, 3, 5, 6)

# A GNSS fix that reaches the app later than this after its own fix time is stale.
MAX_GNSS_AGE_S = 2.0

_HEADER_FIELDS = {
    "Manufacturer": "phone_manufacturer",
    "Model": "phone_model",
    "API Android version": "android_api",
    "Android version Release": "android_release",
    "Date of creation": "created",
}
_HEADER_RE = re.compile(r"^%\s*([A-Za-z][A-Za-z ]*?)\s*:\s*(.*?)\s*$")
_VERSION_RE = re.compile(r"^%\s*Version\s+(.+?)\s*$")


def load_ipin(path: str | Path) -> Recording:
    """Load a GetSensorData logfile (``.txt`` or ``.txt.gz``); times in device seconds.

    ``device_orientation`` holds the phone's AHRS lines as quaternions (w, x, y, z),
    rotating body -> ENU. The logger writes Android's rotation vector (x, y, z) =
    sin(θ/2)·axis, whose world frame is x east, y magnetic north, z up; the scalar part is
    rebuilt as w = sqrt(max(0, 1 - x² - y² - z²)), which is Android's own choice
    (``SensorManager.getQuaternionFromVector``, w >= 0).

    Repairs, each reported in ``Recording.warnings``: a truncated gzip or last line is
    dropped; sensor timestamps out of order are sorted and repeated ones dropped; POSI
    lines repeating the previous landmark (same counter and position) are dropped. The
    logger writes every GNSS fix twice; the repeats are dropped silently and counted in
    ``meta["gnss_repeats_dropped"]``. A GNSS fix is timed when the app received it, except
    a stale one (cached or network fix, received more than :data:`MAX_GNSS_AGE_S` after
    its own Unix fix time), which is placed at its fix time; ``meta["gnss_age_s"]`` keeps
    each fix's age and ``meta["device_to_unix_offset_s"]`` relates the two clocks.
    """
    notes = Notes(path)
    text = read_text(path, notes)
    lines = text.split("\n")
    drop_partial_last_line(
        lines, text, n_fields=_expected_fields, usecols=_expected_cols, delimiter=";", notes=notes
    )
    header = _parse_header(lines)

    groups: defaultdict[str, list[str]] = defaultdict(list)
    for line in lines:
        groups[line[:5]].append(line)

    counts, unknown = _count_types(groups)
    if counts.get(_ACCE, 0) == 0:
        if not header and not counts:
            raise RecordingFormatError(path, "not a GetSensorData logfile (no '%' header and no sensor lines)")
        raise RecordingFormatError(path, "no accelerometer (ACCE) lines")
    if not header:
        notes.warn("no '%' header: phone make and model unknown")
    if unknown:
        _warn_unknown(unknown, lines, notes)

    def rows(kind: str, cols: tuple[int, ...] | None = None) -> np.ndarray:
        key = kind + ";"
        return parse_rows(
            groups.get(key, []),
            cols or _PARSED[kind].usecols,
            path,
            f"{kind} line",
            line_of=lambda k: _line_number(lines, key, k),
            delimiter=";",
        )

    acce = rows(_ACCE)
    offset = float(np.median(acce[:, 1] - acce[:, 0]))
    offset_mad = float(np.median(np.abs(acce[:, 1] - acce[:, 0] - offset)))

    def series(kind: str, arr: np.ndarray, values: np.ndarray) -> Series | None:
        if arr.shape[0] == 0:
            return None
        t = arr[:, 1]
        order = time_order(t, f"{kind} sensor timestamps", notes)
        if order is not None:
            t, values = t[order], values[order]
        return Series(t=t, values=values)

    magn_cols = _MAGN_DOUBLE_SEP_COLS if _magn_double_separator(groups.get(_MAGN + ";")) else None
    gyro, magn, pres, ahrs = rows(_GYRO), rows(_MAGN, magn_cols), rows(_PRES), rows(_AHRS)
    acc = series(_ACCE, acce, acce[:, 2:5])
    check_pressure(pres, notes)
    meta = {
        "format": "GetSensorData logfile (IPIN 2023 Track 3)",
        **header,
        "line_counts": counts,
        "app_to_sensor_offset_s": offset,
        "app_to_sensor_offset_mad_s": offset_mad,
        "device_orientation_source": "Android rotation vector: body -> ENU (x east, y magnetic north, z up)",
    }
    gnss = gnss_fixes(rows(_GNSS), offset, meta, notes)
    landmarks = landmark_table(rows(_POSI), offset, path, lambda k: _line_number(lines, "POSI;", k), meta, notes)
    warn_landmarks_outside(landmarks, acc, notes)
    ble = beacon_readings(groups.get(_BLE4 + ";", []), offset, notes, lambda k: _line_number(lines, "BLE4;", k))

    return Recording(
        source=str(path),
        kind="ipin",
        acc=acc,
        gyr=series(_GYRO, gyro, gyro[:, 2:5]),
        mag=series(_MAGN, magn, magn[:, 2:5]),
        pressure=series(_PRES, pres, pres[:, 2:3]),
        gnss=gnss,
        ble=ble,
        landmarks=landmarks,
        device_orientation=series(_AHRS, ahrs, quaternion_from_rotation_vector(ahrs[:, 2:5])),
        frame="ENU",
        meta=meta,
        warnings=notes.messages,
    )


def _expected_fields(line: str) -> int | None:
    kind = _PARSED.get(line[:4]) if line[4:5] == ";" else None
    return kind.n_fields if kind else None


def _expected_cols(line: str) -> tuple[int, ...] | None:
    kind = _PARSED.get(line[:4]) if line[4:5] == ";" else None
    if kind is None:
        return None
    if line.startswith(_MAGN) and _magn_double_separator([line]):
        return _MAGN_DOUBLE_SEP_COLS
    return kind.usecols


def _parse_header(lines: list[str]) -> dict[str, str]:
    header: dict[str, str] = {}
    for line in lines:
        if not line.startswith("%"):
            if line.strip():
                break
            continue
        m = _HEADER_RE.match(line)
        if m and m.group(1) in _HEADER_FIELDS:
            header[_HEADER_FIELDS[m.group(1)]] = m.group(2)
        m = _VERSION_RE.match(line)
        if m:
            header["logger_version"] = m.group(1)
    return header


def _count_types(groups: dict[str, list[str]]) -> tuple[dict[str, int], dict[str, int]]:
    counts: dict[str, int] = {}
    unknown: dict[str, int] = {}
    for key, members in groups.items():
        if key.startswith("%") or not key.strip():
            continue
        kind = key[:4]
        if key[4:5] == ";" and (kind in _PARSED or kind in _IGNORED or kind == _BLE4):
            counts[kind] = len(members)
        else:
            unknown[key] = len(members)
    return counts, unknown


def _warn_unknown(unknown: dict[str, int], lines: list[str], notes: Notes) -> None:
    first = next(i for i, line in enumerate(lines) if line[:5] in unknown)
    total = sum(unknown.values())
    notes.warn(
        f"{total} line(s) of unknown type skipped, first at line {first + 1}: {lines[first][:60]!r}"
    )


def _line_number(lines: list[str], key: str, k: int) -> int | None:
    """File line (1-based) of the k-th line starting with ``key``; only used on errors."""
    seen = -1
    for i, line in enumerate(lines):
        if line.startswith(key):
            seen += 1
            if seen == k:
                return i + 1
    return None


def _magn_double_separator(group: list[str] | None) -> bool:
    if not group:
        return False
    parts = group[0].split(";")
    return len(parts) == 8 and parts[4] == ""


def check_pressure(pres: np.ndarray, notes: Notes) -> None:
    """Warn when the pressure column (index 2: AppTs, SensorTs, hPa) is not plausibly in hPa."""
    if pres.shape[0] and not 300.0 < float(np.median(pres[:, 2])) < 1100.0:
        notes.warn(f"pressure median {np.median(pres[:, 2]):.1f} is not a plausible value in hPa")


def quaternion_from_rotation_vector(v: np.ndarray) -> np.ndarray:
    """Android rotation vector (x, y, z) = sin(θ/2)·axis -> unit quaternion (w, x, y, z), w >= 0."""
    w = np.sqrt(np.clip(1.0 - np.sum(v * v, axis=1), 0.0, None))
    q = np.column_stack([w, v])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def gnss_fixes(g: np.ndarray, offset: float, meta: dict, notes: Notes) -> GnssFixes | None:
    """GNSS rows (AppTs, UnixTs, lat, lon, alt, accuracy) -> fixes on the sensor clock
    (``offset``: app -> sensor), repeats dropped, stale fixes placed at their fix time."""
    if g.shape[0] == 0:
        return None
    # The logger reports each fix twice (same Unix time and values, later AppTs).
    repeat = np.zeros(g.shape[0], dtype=bool)
    repeat[1:] = np.all(g[1:, 1:] == g[:-1, 1:], axis=1)
    g = g[~repeat]
    meta["gnss_repeats_dropped"] = int(repeat.sum())
    received = g[:, 0] + offset
    unix = g[:, 1]
    # Most fixes reach the app within ~0.1 s of their fix time, so the median relates the
    # Unix clock to the device clock. Some phones also pass on cached or network fixes that
    # are many seconds old: those are placed at their own fix time, not at receipt.
    unix_offset = float(np.median(unix - received))
    fixed_at = unix - unix_offset
    age = received - fixed_at
    stale = age > MAX_GNSS_AGE_S
    t = np.where(stale, fixed_at, received)
    meta["device_to_unix_offset_s"] = unix_offset
    meta["gnss_stale_retimed"] = int(stale.sum())
    order = np.argsort(t, kind="stable") if stale.any() else None
    if order is not None:
        g, t, age = g[order], t[order], age[order]
    order = time_order(t, "GNSS times", notes)
    if order is not None:
        g, t, age = g[order], t[order], age[order]
    meta["gnss_unix_time_s"] = g[:, 1]
    meta["gnss_age_s"] = age
    return GnssFixes(t=t, lat=g[:, 2], lon=g[:, 3], alt=g[:, 4], accuracy_m=g[:, 5])


def warn_landmarks_outside(landmarks: Landmarks | None, acc: Series, notes: Notes) -> None:
    """A warning when landmark times fall outside the accelerometer's time span (both loaders)."""
    if landmarks is not None and len(landmarks):
        outside = (landmarks.t < acc.t[0]) | (landmarks.t > acc.t[-1])
        if outside.any():
            notes.warn(f"{int(outside.sum())} landmark time(s) fall outside the accelerometer's time span")


def landmark_table(p: np.ndarray, offset: float, path, line_of, meta: dict, notes: Notes) -> Landmarks | None:
    """POSI rows (AppTs, counter, lat, lon, floor, building) -> landmarks on the sensor clock.
    ``line_of(k)`` names where row ``k`` came from in error messages (a line, or None)."""
    if p.shape[0] == 0:
        return None
    for col, name in ((1, "counter"), (4, "floor"), (5, "building")):
        frac = (p[:, col] != np.round(p[:, col])) & ~((col == 5) & np.isnan(p[:, col]))  # building may be unknown
        if frac.any():
            k = int(np.argmax(frac))
            raise RecordingFormatError(
                path, f"POSI line: {name} {p[k, col]} is not an integer", line=line_of(k), field=name
            )
    same_counter = np.zeros(p.shape[0], dtype=bool)
    same_counter[1:] = p[1:, 1] == p[:-1, 1]
    same_place = np.zeros(p.shape[0], dtype=bool)
    same_place[1:] = np.all(p[1:, 2:5] == p[:-1, 2:5], axis=1)
    repeat = same_counter & same_place
    if repeat.any():
        where = ", ".join(str(line_of(int(k))) for k in np.flatnonzero(repeat)[:5])
        notes.warn(f"{int(repeat.sum())} POSI line(s) repeat the previous landmark and were dropped (line {where})")
    clash = same_counter & ~same_place
    if clash.any():
        k = int(np.argmax(clash))
        notes.warn(f"POSI counter {int(p[k, 1])} repeated with a different position at line {line_of(k)}; both kept")
    p = p[~repeat]
    t = p[:, 0] + offset
    order = time_order(t, "POSI timestamps", notes)
    if order is not None:
        p, t = p[order], t[order]
    meta["building_ids"] = sorted({int(b) for b in p[:, 5] if np.isfinite(b)})
    return Landmarks(
        t=t,
        lat=p[:, 2],
        lon=p[:, 3],
        floor=p[:, 4].astype(int),
        counter=p[:, 1].astype(int),
    )


def beacon_readings(lines: list[str], offset: float, notes: Notes, line_of) -> BeaconReadings | None:
    """BLE4 lines -> readings on the sensor clock (``offset``: app -> sensor; BLE4 has only the
    app's time). A line without a MAC or a numeric RSSI is skipped with one warning naming the
    first (``line_of(k)``: the file line of the k-th BLE4 line)."""
    if not lines:
        return None
    t, ids, rssi, tx, bad = [], [], [], [], []
    for k, line in enumerate(lines):
        f = line.rstrip().split(";")
        try:
            app_t, mac, level = float(f[1]), f[3].strip().upper(), float(f[4])
            power = float(f[5]) if f[2] == "iBeacon" and f[5].strip() else 0.0
        except (IndexError, ValueError):
            bad.append(k)
            continue
        if not mac or not (np.isfinite(app_t) and np.isfinite(level)):
            bad.append(k)
            continue
        t.append(app_t + offset)
        ids.append(mac)
        rssi.append(level)
        tx.append(power if power != 0.0 and np.isfinite(power) else np.nan)
    if bad:
        notes.warn(f"{len(bad)} BLE4 line(s) without a MAC or a numeric RSSI skipped, first at line {line_of(bad[0])}")
    return beacon_table(t, ids, rssi, tx)


def beacon_table(t, ids, rssi, tx) -> BeaconReadings | None:
    """Readings (times already on the sensor clock) in time order; None when there are none."""
    if len(t) == 0:
        return None
    t_arr = np.asarray(t, float)
    order = np.argsort(t_arr, kind="stable")
    return BeaconReadings(t=t_arr[order], beacon=np.asarray(ids, dtype=object)[order],
                          rssi=np.asarray(rssi, float)[order], tx_power=np.asarray(tx, float)[order])
