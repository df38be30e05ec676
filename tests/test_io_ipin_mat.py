"""The organisers' MATLAB form of IPIN logs (pdr.io.ipin_mat) reads as the text log does."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from pdr.io import RecordingFormatError, load, load_ipin, load_ipin_mat
from tests.test_io import ipin_text, write

# The organisers' parser (ReadLogFile2022.m): one matrix per line type, the type dropped,
# the accuracy dropped from ACCE/GYRO/MAGN, the counter and building dropped from POSI.
_KEEP = {"ACCE": "Acce", "GYRO": "Gyro", "MAGN": "Magn", "PRES": "Pres", "AHRS": "Ahrs", "GNSS": "Gnss", "POSI": "Posi"}


def organisers_parse(text: str) -> dict[str, np.ndarray]:
    """What ReadLogFile2022.m writes for a GetSensorData log (its sscanf formats, by hand)."""
    rows: dict[str, list[list[float]]] = {v: [] for v in _KEEP.values()}
    for line in text.splitlines():
        f = line.split(";")
        if f[0] not in _KEEP:
            continue
        x = [float(v) for v in f[1:] if v != ""]
        if f[0] in ("ACCE", "GYRO", "MAGN"):
            x = x[:5]
        elif f[0] == "POSI":
            x = [x[0], x[2], x[3], x[4]]
        rows[_KEEP[f[0]]].append(x)
    return {k: np.array(v, float) for k, v in rows.items()}


def write_mat(path, fields):
    scipy.io.savemat(path, fields)
    return path


def test_mat_parse_of_a_log_loads_as_the_log(tmp_path):
    text = ipin_text()
    ref = load_ipin(write(tmp_path / "log.txt", text))
    path = write_mat(tmp_path / "walk.mat", organisers_parse(text))
    rec = load(path)
    assert rec.kind == "ipin" and rec.warnings == []
    for name in ("acc", "gyr", "mag", "pressure", "device_orientation"):
        a, b = getattr(ref, name), getattr(rec, name)
        np.testing.assert_array_equal(a.t, b.t, err_msg=name)
        np.testing.assert_allclose(a.values, b.values, rtol=0, atol=1e-12, err_msg=name)
    assert rec.meta["app_to_sensor_offset_s"] == ref.meta["app_to_sensor_offset_s"]
    for name in ("t", "lat", "lon", "floor"):
        np.testing.assert_array_equal(getattr(rec.landmarks, name), getattr(ref.landmarks, name))
    assert list(rec.landmarks.counter) == [1, 2]  # numbered, since the parse drops the counter
    for name in ("t", "lat", "lon", "alt", "accuracy_m"):
        np.testing.assert_array_equal(getattr(rec.gnss, name), getattr(ref.gnss, name))
    assert rec.meta["gnss_repeats_dropped"] == 2 and rec.meta["gnss_stale_retimed"] == 1


def test_mat_without_optional_channels_loads(tmp_path):
    fields = organisers_parse(ipin_text())
    for k in ("Magn", "Pres", "Gnss", "Ahrs"):
        fields[k] = np.zeros((0, 5))
    rec = load_ipin_mat(write_mat(tmp_path / "w.mat", fields))
    assert rec.mag is None and rec.pressure is None and rec.gnss is None and rec.device_orientation is None
    assert len(rec.landmarks) == 2


@pytest.mark.parametrize("change, field, message", [
    (lambda f: f.pop("Gyro"), "Gyro", "missing"),
    (lambda f: f.__setitem__("Acce", f["Acce"][:, :4]), "Acce", "N x 5"),
    (lambda f: f["Posi"].__setitem__((1, 3), np.nan), "Posi", "NaN"),
])
def test_bad_mat_names_the_field(tmp_path, change, field, message):
    fields = organisers_parse(ipin_text())
    change(fields)
    with pytest.raises(RecordingFormatError, match=message) as err:
        load_ipin_mat(write_mat(tmp_path / "w.mat", fields))
    assert err.value.field == field and "w.mat" in str(err.value)


@pytest.mark.recording
@pytest.mark.parametrize("name", ["IPIN2023_T3_TrainingTrial52_repetition02.mat",
                                  "IPIN2023_T3_TrainingTrial53_repetition01.mat",
                                  "IPIN2023_T3_TrainingTrial53_repetition02.mat"])
def test_real_mat_walks_read_like_the_text_logs(shared_data, name):
    from pdr import quaternion as quat

    rec = load(shared_data(f"ipin2023/{name}"))
    txt = load(shared_data("ipin2023/IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"))
    assert rec.kind == "ipin" and rec.warnings == []
    # the beacons: some of the museum's six MACs, on the sensor clock, in dBm
    assert set(rec.ble.ids()) <= {f"BE:AC:20:23:00:0{k}" for k in range(1, 7)} and len(rec.ble) > 100
    assert rec.acc.t[0] - 10.0 < rec.ble.t[0] and rec.ble.t[-1] < rec.acc.t[-1] + 10.0 and rec.ble.rssi.max() < -30.0
    # same kind of walk: floors 0 and -2, landmarks inside the IMU span, 50 Hz accelerometer
    assert set(rec.landmarks.floor) == {0, -2} and rec.landmarks.floor[0] == 0
    assert rec.acc.t[0] < rec.landmarks.t[0] and rec.landmarks.t[-1] < rec.acc.t[-1]
    assert rec.acc.rate_hz == pytest.approx(txt.acc.rate_hz, rel=0.01)
    # units: gravity in m/s², the field in µT, pressure in hPa, GNSS in degrees and metres
    assert np.median(np.linalg.norm(rec.acc.values, axis=1)) == pytest.approx(9.8, abs=0.3)
    assert 20.0 < np.median(np.linalg.norm(rec.mag.values, axis=1)) < 70.0
    assert abs(np.median(rec.pressure.values) - np.median(txt.pressure.values)) < 10.0
    assert np.all(np.abs(rec.gnss.lat - 49.461) < 0.01) and np.all(rec.gnss.accuracy_m > 0)
    # axes and the rotation vector as in the text log: the phone's orientation maps gravity to +z
    q = rec.device_orientation
    acc = rec.acc.values[np.searchsorted(rec.acc.t, q.t).clip(0, len(rec.acc) - 1)]
    assert quat.rotate(q.values, acc).mean(axis=0) == pytest.approx([0.0, 0.0, 9.8], abs=0.3)
