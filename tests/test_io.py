"""Loaders in pdr.io: small synthetic files written here, plus the real recordings when present."""
from __future__ import annotations

import gzip
import math
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pdr import quaternion as quat
from pdr.io import (
    RecordingFormatError,
    RecordingWarning,
    load,
    load_ipin,
    load_oxford,
    load_pyshoe,
    load_vicon_ahrs,
)
from pdr.io._common import MAX_TRIM_SAMPLES

# --------------------------------------------------------------------------------------
# IPIN 'GetSensorData' logfiles
# --------------------------------------------------------------------------------------

IPIN_HEADER = """\
% LogFile created by the 'GetSensorData' App for Android.
% Date of creation: Wed Jun 14 10:00:58 GMT+02:00 2023
% Version 2.21 July 2021
%
% Phone used for this logfile:
% Manufacturer:            \tsamsung
% Model:                   \tSM-TEST1
% API Android version:     \t26
% Android version Release: \t8.0.0
%
% Magnetometer data:  \t'MAGN;AppTimestamp(s);SensorTimestamp(s);Mag_X(uT);;Mag_Y(uT);Mag_Z(uT);Accuracy(integer)'
% POSI Reference:    \t\t'POSI;Timestamp(s);Counter;Latitude(degrees); Longitude(degrees);floor ID(0,1,2..4);Building ID(0,1,2..3);'

"""
SENSOR_AT_APP_ZERO = 5000.0  # device clock reading when the app clock reads 0
READ_LATENCY = 0.004  # the app reads each sample this long after the sensor stamped it
OFFSET = SENSOR_AT_APP_ZERO - READ_LATENCY  # sensor_t = app_t + OFFSET
UNIX_AT_APP_ZERO = 1_686_729_000.0
N_ACCE = 100
YAW_90 = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))  # body x -> east... rotated to north


def ipin_text(n_acce: int = N_ACCE, posi_duplicate: bool = False, magn_double_sep: bool = False) -> str:
    """A 2-second GetSensorData log: ACCE/MAGN/AHRS 50 Hz, GYRO 100 Hz, PRES 5 Hz, two landmarks."""
    out = []
    for k in range(n_acce):
        ts = SENSOR_AT_APP_ZERO + 0.1 + 0.02 * k
        app = ts - SENSOR_AT_APP_ZERO + READ_LATENCY
        out.append(f"ACCE;{app:.4f};{ts:.4f};{0.01 * k:.5f};0.20000;9.80000;3")
        for h in (0.0, 0.01):
            out.append(f"GYRO;{app + h:.4f};{ts + h:.4f};0.01000;-0.02000;0.03000;3")
        sep = ";;" if magn_double_sep else ";"
        out.append(f"MAGN;{app:.4f};{ts:.4f};-2.10000{sep}20.50000;-45.42000;0")
        out.append(f"AHRS;{app:.4f};{ts:.4f};0.0;0.0;90.0;0.00000000;0.00000000;{YAW_90[3]:.8f};3")
        if k % 10 == 0:
            out.append(f"PRES;{app:.4f};{ts:.4f};1013.2500;3")
            out.append(f"WIFI;{app:.3f};{ts:.2f};SSID_1;20:23:00:00:00:01;2437;-60")
            out.append(f"SOUN;{app:.4f};3093.40;0.09441;73.48")
            out.append(f"BLE4;{app:.4f};iBeacon;BE:AC:20:23:00:01;-90;0;1;1;11111111-1111-BEAC-2023-111111111111")
        if k == 20:
            out.append(f"POSI;{app:.4f};1;49.461316433032;11.110964442580;0;100")
            if posi_duplicate:
                out.append(f"POSI;{app + 0.0012:.4f};1;49.461316433032;11.110964442580;0;100")
        if k == 80:
            out.append(f"POSI;{app:.4f};2;49.461275602490;11.110988346746;-1;100")
        if k in (10, 60):  # each fix is logged twice, as the real logger does
            unix = UNIX_AT_APP_ZERO + app
            for extra in (0.0, 0.005):
                out.append(f"GNSS;{app + extra:.4f};{unix:.4f};49.461269;11.111049;346.000;79.500;9.0;0.1;22;19")
        if k == 40:  # a cached fix, 20 s old when it arrives
            unix = UNIX_AT_APP_ZERO + app - 20.0
            out.append(f"GNSS;{app:.4f};{unix:.4f};49.461266;11.110846;366.000;0.000;748.0;0.0;23;21")
    return IPIN_HEADER + "\n".join(out) + "\n"


def write(path: Path, text: str, gz: bool = False) -> Path:
    data = text.encode()
    path.write_bytes(gzip.compress(data) if gz else data)
    return path


def line_number_of(text: str, prefix: str, nth: int) -> int:
    """1-based line number of the nth line (0-based count) starting with prefix."""
    hits = [i + 1 for i, line in enumerate(text.split("\n")) if line.startswith(prefix)]
    return hits[nth]


def test_ipin_values_units_and_one_device_clock(tmp_path):
    rec = load_ipin(write(tmp_path / "log.txt", ipin_text()))
    assert rec.kind == "ipin" and rec.frame == "ENU"
    assert rec.warnings == []
    # IMU series on the sensor clock, in SI units
    assert len(rec.acc) == N_ACCE and len(rec.gyr) == 2 * N_ACCE and len(rec.mag) == N_ACCE
    assert rec.acc.t[0] == pytest.approx(SENSOR_AT_APP_ZERO + 0.1)
    assert rec.acc.rate_hz == pytest.approx(50.0, rel=1e-3)
    assert rec.gyr.rate_hz == pytest.approx(100.0, rel=1e-3)
    np.testing.assert_allclose(rec.acc.values[5], [0.05, 0.2, 9.8])
    np.testing.assert_allclose(rec.gyr.values[0], [0.01, -0.02, 0.03])
    np.testing.assert_allclose(rec.mag.values[0], [-2.1, 20.5, -45.42])
    assert rec.pressure.values.shape == (10, 1)
    np.testing.assert_allclose(rec.pressure.values[:, 0], 1013.25)
    # the app -> sensor clock offset, and landmarks moved onto the sensor clock
    assert rec.meta["app_to_sensor_offset_s"] == pytest.approx(OFFSET, abs=1e-6)
    lm = rec.landmarks
    assert list(lm.counter) == [1, 2] and list(lm.floor) == [0, -1]
    expected_posi_app = np.array([20, 80]) * 0.02 + 0.1 + READ_LATENCY
    np.testing.assert_allclose(lm.t, expected_posi_app + OFFSET, atol=1e-6)
    np.testing.assert_allclose(lm.t, rec.acc.t[[20, 80]], atol=1e-6)  # same instants as those ACCE samples
    assert lm.lat[0] == pytest.approx(49.461316433032, abs=1e-12)
    assert rec.meta["building_ids"] == [100]
    # the phone's orientation: rotation vector (0, 0, sin 45°) -> w = cos 45°
    np.testing.assert_allclose(rec.device_orientation.values[0], YAW_90, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(rec.device_orientation.values, axis=1), 1.0)
    # header and line counts
    assert rec.meta["phone_manufacturer"] == "samsung" and rec.meta["phone_model"] == "SM-TEST1"
    assert rec.meta["android_api"] == "26" and rec.meta["logger_version"].startswith("2.21")
    counts = rec.meta["line_counts"]
    assert counts["ACCE"] == N_ACCE and counts["WIFI"] == 10 and counts["SOUN"] == 10 and counts["BLE4"] == 10
    assert counts["POSI"] == 2 and counts["GNSS"] == 5


def test_ipin_gnss_repeats_dropped_and_stale_fix_placed_at_its_fix_time(tmp_path):
    rec = load_ipin(write(tmp_path / "log.txt", ipin_text()))
    gnss = rec.gnss
    assert len(gnss) == 3 and rec.meta["gnss_repeats_dropped"] == 2 and rec.meta["gnss_stale_retimed"] == 1
    app = np.array([10, 60]) * 0.02 + 0.1 + READ_LATENCY
    np.testing.assert_allclose(gnss.t[1:], app + OFFSET, atol=1e-6)  # fresh fixes: received time
    stale_app = 40 * 0.02 + 0.1 + READ_LATENCY
    assert gnss.t[0] == pytest.approx(stale_app + OFFSET - 20.0, abs=1e-3)  # stale fix: its own time
    assert gnss.accuracy_m[0] == 748.0 and gnss.alt[1] == 346.0
    assert rec.meta["device_to_unix_offset_s"] == pytest.approx(UNIX_AT_APP_ZERO - OFFSET, abs=1e-3)
    assert np.all(np.diff(gnss.t) > 0)


def test_ipin_gzip_and_txt_give_the_same_recording(tmp_path):
    text = ipin_text()
    a = load_ipin(write(tmp_path / "log.txt", text))
    b = load_ipin(write(tmp_path / "log.txt.gz", text, gz=True))
    np.testing.assert_array_equal(a.acc.values, b.acc.values)
    np.testing.assert_array_equal(a.landmarks.t, b.landmarks.t)


def test_ipin_duplicated_landmark_dropped_with_warning(tmp_path):
    with pytest.warns(RecordingWarning, match="POSI"):
        rec = load_ipin(write(tmp_path / "log.txt", ipin_text(posi_duplicate=True)))
    assert list(rec.landmarks.counter) == [1, 2]
    assert any("repeat the previous landmark" in w for w in rec.warnings)


def test_ipin_magnetometer_with_the_headers_double_separator(tmp_path):
    rec = load_ipin(write(tmp_path / "log.txt", ipin_text(magn_double_sep=True)))
    np.testing.assert_allclose(rec.mag.values[0], [-2.1, 20.5, -45.42])


@pytest.mark.parametrize("prefix, nth, bad", [("ACCE;", 37, "9.8x"), ("GYRO;", 5, ""), ("POSI;", 1, "north")])
def test_ipin_bad_number_names_file_and_line(tmp_path, prefix, nth, bad):
    text = ipin_text()
    k = line_number_of(text, prefix, nth)
    lines = text.split("\n")
    fields = lines[k - 1].split(";")
    fields[3] = bad
    lines[k - 1] = ";".join(fields)
    path = write(tmp_path / "bad.txt", "\n".join(lines))
    with pytest.raises(RecordingFormatError) as err:
        load_ipin(path)
    assert err.value.line == k
    assert str(path) in str(err.value) and f"line {k}" in str(err.value)


def test_ipin_nan_in_a_reading_is_an_error_with_its_line(tmp_path):
    text = ipin_text()
    k = line_number_of(text, "MAGN;", 12)
    lines = text.split("\n")
    lines[k - 1] = lines[k - 1].replace("20.50000", "NaN")
    with pytest.raises(RecordingFormatError, match=f"line {k}.*not a finite"):
        load_ipin(write(tmp_path / "nan.txt", "\n".join(lines)))


def test_ipin_short_line_in_the_middle_is_an_error(tmp_path):
    text = ipin_text()
    k = line_number_of(text, "ACCE;", 50)
    lines = text.split("\n")
    lines[k - 1] = "ACCE;1.0;5001.0;0.1"
    with pytest.raises(RecordingFormatError, match=f"line {k}.*fields"):
        load_ipin(write(tmp_path / "short.txt", "\n".join(lines)))


def test_ipin_truncated_last_line_is_skipped_with_warning(tmp_path):
    text = ipin_text() + "ACCE;9.1000;5009.0960;0.12"  # cut mid-line, no newline
    with pytest.warns(RecordingWarning, match="truncated"):
        rec = load_ipin(write(tmp_path / "cut.txt", text))
    assert len(rec.acc) == N_ACCE
    assert any("truncated" in w for w in rec.warnings)


def test_ipin_truncated_gzip_loads_what_was_decompressed(tmp_path):
    text = ipin_text(n_acce=2000)
    packed = gzip.compress(text.encode())
    path = tmp_path / "cut.txt.gz"
    path.write_bytes(packed[: int(len(packed) * 0.6)])
    with pytest.warns(RecordingWarning):
        rec = load_ipin(path)
    assert 100 < len(rec.acc) < 2000
    assert any("gzip" in w for w in rec.warnings)
    assert np.all(np.diff(rec.acc.t) > 0)


def test_ipin_gzip_cut_inside_its_header_is_an_error(tmp_path):
    path = tmp_path / "stub.txt.gz"
    path.write_bytes(gzip.compress(ipin_text().encode())[:6])
    with pytest.raises(RecordingFormatError, match="nothing could be decompressed"):
        load_ipin(path)


def test_ipin_out_of_order_and_repeated_timestamps_sorted_with_warning(tmp_path):
    text = ipin_text()
    lines = text.split("\n")
    a, b = line_number_of(text, "ACCE;", 30) - 1, line_number_of(text, "ACCE;", 31) - 1
    lines[a], lines[b] = lines[b], lines[a]
    lines.insert(b + 1, lines[b])  # the same sample logged twice
    with pytest.warns(RecordingWarning, match="ACCE"):
        rec = load_ipin(write(tmp_path / "order.txt", "\n".join(lines)))
    assert len(rec.acc) == N_ACCE
    assert np.all(np.diff(rec.acc.t) > 0)
    np.testing.assert_allclose(rec.acc.values[30], [0.30, 0.2, 9.8])


def test_ipin_unknown_line_type_is_skipped_with_warning(tmp_path):
    text = ipin_text().replace("SOUN;", "ZZZZ;", 1)
    with pytest.warns(RecordingWarning, match="unknown type"):
        rec = load_ipin(write(tmp_path / "odd.txt", text))
    assert len(rec.acc) == N_ACCE


@pytest.mark.parametrize(
    "content, message",
    [("", "empty file"), (IPIN_HEADER, "no accelerometer"), ("hello\nworld\n", "not a GetSensorData")],
)
def test_ipin_files_without_readings(tmp_path, content, message):
    path = write(tmp_path / "x.txt", content)
    with pytest.raises(RecordingFormatError, match=message) as err:
        load_ipin(path)
    assert str(path) in str(err.value)


def test_missing_file_is_a_format_error(tmp_path):
    for loader in (load, load_ipin, load_oxford, load_pyshoe, load_vicon_ahrs):
        with pytest.raises(RecordingFormatError, match="not found"):
            loader(tmp_path / "nope.txt")


# --------------------------------------------------------------------------------------
# Oxford step counter
# --------------------------------------------------------------------------------------

T0_NS = 583_718_602_288_785
STATS_HEADER = "#dir, user, phone, position, surface, duration(s), steps \n"


def oxford_rows(n: int, validation: bool) -> list[str]:
    rows = []
    for k in range(n):
        ts = T0_NS + k * 5_000_000  # 200 Hz
        if validation:
            truth = 3 + k // 10
            rows.append(f"{ts},{0.1 * k:.4f},5.2,8.5,{4 + k // 10},{truth},{k // 11}")
        else:
            rows.append(f"{ts},3,{0.1 * k:.4f},2.5,9.5")
    return rows


def write_walk(root: Path, name: str = "Pixel_Test_Hard_FrontPocket_1", steps: str = "42",
               rows: list[str] | None = None, stats: bool = True) -> Path:
    walk = root / "optimisation" / name
    walk.mkdir(parents=True)
    rows = oxford_rows(400, validation=False) if rows is None else rows
    write(walk / "accelerometer.csv.gz", "\n".join(rows) + "\n", gz=True)
    if stats:
        write(root / "optimisation" / "stats.csv",
              STATS_HEADER + "Other_Walk_1, A, Nexus, InHand, Hard, 3, 7\n"
              f"{name}, Test, Pixel, FrontPocket, Hard, 2, {steps}\n")
    return walk


def test_oxford_optimisation_walk(tmp_path):
    walk = write_walk(tmp_path)
    for target in (walk, walk / "accelerometer.csv.gz"):
        rec = load_oxford(target)
        assert rec.kind == "oxford" and rec.true_steps == 42 and rec.warnings == []
        assert rec.meta["carry"] == "FrontPocket" and rec.meta["phone"] == "Pixel" and rec.meta["user"] == "Test"
        assert rec.acc.t[0] == pytest.approx(T0_NS * 1e-9) and rec.acc.rate_hz == pytest.approx(200.0)
        np.testing.assert_allclose(rec.acc.values[10], [1.0, 2.5, 9.5])
        assert rec.gyr is None


def test_oxford_walk_without_stats_row_loads_with_warning(tmp_path):
    walk = write_walk(tmp_path, name="_Patient_3", stats=False)
    write(tmp_path / "optimisation" / "stats.csv", STATS_HEADER + "Other_Walk_1, A, Nexus, InHand, Hard, 3, 7\n")
    with pytest.warns(RecordingWarning, match="true step count unknown"):
        rec = load_oxford(walk)
    assert rec.true_steps is None and "carry" not in rec.meta


def test_oxford_carry_from_the_name_when_stats_has_no_row(tmp_path):
    walk = write_walk(tmp_path, name="Samsung_Dario_Hard_Backpocket_2", stats=False)
    with pytest.warns(RecordingWarning):
        rec = load_oxford(walk)
    assert rec.meta["carry"] == "BackPocket"


def test_oxford_stats_with_a_bad_step_count_names_stats_file_and_line(tmp_path):
    walk = write_walk(tmp_path, steps="many")
    with pytest.raises(RecordingFormatError, match=r"stats\.csv, line 3, field 'steps'"):
        load_oxford(walk)


def test_oxford_validation_file(tmp_path):
    path = write(tmp_path / "user1_frontpocket_1506422223341.csv.gz", "\n".join(oxford_rows(405, True)) + "\n", gz=True)
    rec = load_oxford(path)
    assert rec.true_steps == 40  # running count 3 .. 43
    assert rec.step_count_ref.values.shape == (405, 1)
    assert rec.step_count_ref.values[0, 0] == 3 and rec.step_count_ref.values[-1, 0] == 43
    assert rec.meta["their_algorithm_total"] == 40 and rec.meta["phone_hardware_total"] == 36
    assert rec.meta["their_algorithm_steps"].values[-1, 0] == 44
    assert rec.meta["carry"] == "FrontPocket" and rec.meta["user"] == "user1"
    assert rec.meta["start_unix_s"] == pytest.approx(1506422223.341)
    np.testing.assert_allclose(rec.acc.values[20], [2.0, 5.2, 8.5])
    assert load(path).true_steps == 40


def test_oxford_bad_number_names_file_and_line(tmp_path):
    rows = oxford_rows(400, validation=False)
    rows[122] = rows[122].replace(",2.5,", ",2.5.1,")
    walk = write_walk(tmp_path, rows=rows)
    with pytest.raises(RecordingFormatError) as err:
        load_oxford(walk)
    assert err.value.line == 123 and "accelerometer.csv.gz" in str(err.value) and "2.5.1" in str(err.value)


def test_oxford_short_last_row_is_skipped_with_warning(tmp_path):
    rows = oxford_rows(400, validation=False)
    rows[-1] = rows[-1].rsplit(",", 2)[0]  # last row lost its last two fields
    walk = write_walk(tmp_path, rows=rows)
    with pytest.warns(RecordingWarning, match="line 400 looks truncated"):
        rec = load_oxford(walk)
    assert len(rec.acc) == 399 and rec.true_steps == 42


def test_oxford_unknown_csv_layout(tmp_path):
    path = write(tmp_path / "x.csv", "1,2,3\n4,5,6\n")
    with pytest.raises(RecordingFormatError, match="5 or 7"):
        load_oxford(path)


# --------------------------------------------------------------------------------------
# PyShoe .mat
# --------------------------------------------------------------------------------------

def pyshoe_fields(n: int = 1000, vicon: bool = True) -> dict:
    k = np.arange(n)
    t = 0.005 + 0.005 * k
    imu = np.column_stack([np.full(n, 0.1), np.full(n, -0.2), np.full(n, 9.8),
                           0.01 * np.ones(n), np.zeros(n), np.sin(k / 50.0)])
    strides = np.array([100, 300, 500, n - 1], dtype=np.int64)
    xy = np.column_stack([k * 0.001, k * -0.002])
    fields = {"imu_data": imu, "strideIndex": strides, "pyshoeTrajectory": xy + 0.01}
    if vicon:
        fields |= {"timestamps_all": t, "timestamps": t[strides], "gt": xy, "GCP": xy[strides]}
    else:
        fields |= {"timestamps": t - 0.005, "GCP": xy[strides] * 1.1, "traj_wcf": xy}
    return fields


def write_mat(path: Path, fields: dict) -> Path:
    scipy.io.savemat(path, fields)
    return path


def test_pyshoe_vicon_file(tmp_path):
    rec = load_pyshoe(write_mat(tmp_path / "walk_LLIO.mat", pyshoe_fields()))
    assert rec.kind == "pyshoe" and rec.warnings == []
    assert rec.meta["time_field"] == "timestamps_all" and rec.meta["rate_hz"] == pytest.approx(200.0)
    assert len(rec.acc) == 1000 and rec.acc.t[0] == pytest.approx(0.005)
    np.testing.assert_allclose(rec.acc.values[3], [0.1, -0.2, 9.8])
    np.testing.assert_allclose(rec.gyr.values[50], [0.01, 0.0, math.sin(1.0)])
    assert rec.position_ref.values.shape == (1000, 2)
    idx = rec.meta["stride_index"]
    assert list(idx) == [100, 300, 500, 999]
    np.testing.assert_allclose(rec.position_ref.values[idx], rec.meta["gcp"])  # GCP = gt at stride ends
    np.testing.assert_allclose(rec.meta["stride_t"], rec.acc.t[idx])
    assert rec.meta["pyshoe_trajectory"].shape == (1000, 2)
    assert load(tmp_path / "walk_LLIO.mat").kind == "pyshoe"


def test_pyshoe_positions_are_turned_into_a_right_handed_z_up_frame(tmp_path):
    # the file's x, y belong to PyShoe's z-down frame: loaded x is the file's y and y its x
    fields = pyshoe_fields()
    rec = load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    np.testing.assert_array_equal(rec.position_ref.values, fields["gt"][:, ::-1])
    np.testing.assert_array_equal(rec.meta["gcp"], fields["GCP"][:, ::-1])
    np.testing.assert_array_equal(rec.meta["pyshoe_trajectory"], fields["pyshoeTrajectory"][:, ::-1])
    assert "z-down" in rec.meta["position_frame"]


def test_pyshoe_file_with_per_sample_timestamps_and_no_vicon(tmp_path):
    rec = load_pyshoe(write_mat(tmp_path / "SensorConnectData_1_LLIO.mat", pyshoe_fields(vicon=False)))
    assert rec.meta["time_field"] == "timestamps" and rec.acc.t[0] == 0.0
    assert rec.position_ref is None and rec.meta["gcp"].shape == (4, 2)
    assert rec.meta["other_fields"] == ["traj_wcf"]


def test_pyshoe_one_based_stride_index_is_converted(tmp_path):
    fields = pyshoe_fields()
    fields["strideIndex"] = fields["strideIndex"] + 1
    with pytest.warns(RecordingWarning, match="1-based"):
        rec = load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    assert list(rec.meta["stride_index"]) == [100, 300, 500, 999]


def test_pyshoe_timestamps_in_ms_are_converted(tmp_path):
    fields = pyshoe_fields()
    fields["timestamps_all"] = fields["timestamps_all"] * 1000.0
    fields["timestamps"] = fields["timestamps"] * 1000.0
    with pytest.warns(RecordingWarning, match="ms"):
        rec = load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    assert rec.meta["rate_hz"] == pytest.approx(200.0)


def test_pyshoe_slightly_short_timestamps_are_trimmed_with_warning(tmp_path):
    fields = pyshoe_fields()
    fields["timestamps_all"] = fields["timestamps_all"][:998]
    with pytest.warns(RecordingWarning):
        rec = load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    assert len(rec.acc) == len(rec.gyr) == len(rec.position_ref) == 998
    assert "trimmed to 998" in rec.warnings[0]
    assert list(rec.meta["stride_index"]) == [100, 300, 500]  # the last stride end was trimmed off
    assert "stride end" in rec.warnings[1]


def test_pyshoe_out_of_order_samples_sorted_and_strides_follow(tmp_path):
    fields = pyshoe_fields()
    for key in ("timestamps_all", "imu_data", "gt"):
        fields[key][[299, 300]] = fields[key][[300, 299]]  # two samples stored swapped
    strides = fields["strideIndex"]  # stride ends index the file's order, as stored
    fields["GCP"], fields["timestamps"] = fields["gt"][strides], fields["timestamps_all"][strides]
    with pytest.warns(RecordingWarning, match="back in time"):
        rec = load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    assert np.all(np.diff(rec.acc.t) > 0)
    idx = rec.meta["stride_index"]
    assert list(idx) == [100, 299, 500, 999]  # stride end 300 (file order) now sits at 299
    np.testing.assert_allclose(rec.position_ref.values[idx], rec.meta["gcp"])
    np.testing.assert_allclose(rec.meta["stride_t"], fields["timestamps"])


def test_pyshoe_grossly_different_lengths_are_an_error(tmp_path):
    fields = pyshoe_fields()
    fields["gt"] = fields["gt"][: 1000 - MAX_TRIM_SAMPLES - 1]
    with pytest.raises(RecordingFormatError, match="differ in length") as err:
        load_pyshoe(write_mat(tmp_path / "w.mat", fields))
    assert err.value.field == "gt"


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda f: f.pop("imu_data"), "imu_data"),
        (lambda f: f.update(imu_data=f["imu_data"][:, :5]), "imu_data"),
        (lambda f: f["imu_data"].__setitem__((17, 2), np.nan), "imu_data"),
        (lambda f: f.update(timestamps_all=np.array(["a", "b"])), "timestamps_all"),
        (lambda f: f.update(GCP=f["GCP"][:2]), "GCP"),
        (lambda f: f.update(strideIndex=np.array([5, 300, 500, 20000])), "strideIndex"),
    ],
    ids=["missing", "wrong-shape", "nan", "not-numeric", "gcp-count", "stride-range"],
)
def test_pyshoe_bad_fields_are_named(tmp_path, change, field):
    fields = pyshoe_fields()
    change(fields)
    path = write_mat(tmp_path / "w.mat", fields)
    with pytest.raises(RecordingFormatError) as err:
        load_pyshoe(path)
    assert err.value.field == field and str(path) in str(err.value)


@pytest.mark.parametrize("content", [b"", b"not a mat file at all" * 20, "truncated"])
def test_unreadable_mat_files(tmp_path, content):
    path = tmp_path / "w.mat"
    if content == "truncated":
        write_mat(path, pyshoe_fields())
        path.write_bytes(path.read_bytes()[:3000])
    else:
        path.write_bytes(content)
    for loader in (load_pyshoe, load_vicon_ahrs, load):
        with pytest.raises(RecordingFormatError) as err:
            loader(path)
        assert str(path) in str(err.value)


# --------------------------------------------------------------------------------------
# Vicon AHRS (Justa)
# --------------------------------------------------------------------------------------

MAG_NWU = np.array([0.49, 0.0, 0.87]) / np.linalg.norm([0.49, 0.0, 0.87])


def vicon_fields(n: int = 200) -> dict:
    t = np.arange(n) / 81.0
    axis = np.column_stack([np.ones(n), 0.5 * np.ones(n), np.ones(n)])
    q = quat.from_axis_angle(axis, np.linspace(0.0, 1.5, n))  # body -> NWU
    acc_g = quat.rotate_inverse(q, np.array([0.0, 0.0, 1.0]))
    mag = quat.rotate_inverse(q, MAG_NWU)
    gyr = np.tile([0.01, -0.02, 0.03], (n, 1))
    return {"Accelerometer": acc_g, "Gyroscope": gyr, "Magnetometer": mag,
            "qViconReference": q * 1.0005, "time": t[None, :]}


def test_vicon_ahrs_units_frame_and_reference(tmp_path):
    rec = load_vicon_ahrs(write_mat(tmp_path / "Justa_dataset.mat", vicon_fields()))
    assert rec.kind == "vicon_ahrs" and rec.frame == "NWU" and rec.warnings == []
    assert len(rec.acc) == 200 and rec.acc.rate_hz == pytest.approx(81.0)
    np.testing.assert_allclose(np.linalg.norm(rec.acc.values, axis=1), 9.80665)
    q = rec.orientation_ref.values
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(quat.rotate(q, rec.acc.values), np.tile([0, 0, 9.80665], (200, 1)), atol=1e-9)
    np.testing.assert_allclose(quat.rotate(q, rec.mag.values), np.tile(MAG_NWU, (200, 1)), atol=1e-9)
    assert rec.meta["mag_units"] == "normalised"
    np.testing.assert_allclose(rec.gyr.values[7], [0.01, -0.02, 0.03])
    assert load(tmp_path / "Justa_dataset.mat").kind == "vicon_ahrs"


def test_vicon_ahrs_length_mismatch_trimmed_and_missing_field_named(tmp_path):
    fields = vicon_fields(1000)
    fields["time"] = fields["time"][:, :997]
    with pytest.warns(RecordingWarning, match="trimmed to 997"):
        rec = load_vicon_ahrs(write_mat(tmp_path / "a.mat", fields))
    assert len(rec.orientation_ref) == len(rec.mag) == 997

    fields = vicon_fields(200)  # 3 of 200 samples is more than 1 %: not a harmless tail
    fields["time"] = fields["time"][:, :197]
    with pytest.raises(RecordingFormatError, match="differ in length by 3") as err:
        load_vicon_ahrs(write_mat(tmp_path / "short.mat", fields))
    assert err.value.field == "time"

    fields = vicon_fields()
    del fields["qViconReference"]
    with pytest.raises(RecordingFormatError, match="qViconReference") as err:
        load_vicon_ahrs(write_mat(tmp_path / "b.mat", fields))
    assert err.value.field == "qViconReference"

    fields = vicon_fields()
    fields["qViconReference"] = fields["qViconReference"][:, :3]
    with pytest.raises(RecordingFormatError, match="N x 4"):
        load_vicon_ahrs(write_mat(tmp_path / "c.mat", fields))


# --------------------------------------------------------------------------------------
# load(): choosing the loader
# --------------------------------------------------------------------------------------

def test_load_picks_the_loader(tmp_path):
    assert load(write(tmp_path / "a.txt.gz", ipin_text(), gz=True)).kind == "ipin"
    assert load(write_walk(tmp_path)).kind == "oxford"
    with pytest.raises(RecordingFormatError, match="unknown recording format"):
        load(write(tmp_path / "notes.txt", "just some notes\n"))
    with pytest.raises(RecordingFormatError, match="neither"):
        load(write_mat(tmp_path / "other.mat", {"x": np.ones(3)}))
    with pytest.raises(RecordingFormatError, match="directory"):
        load(tmp_path)


# --------------------------------------------------------------------------------------
# Real recordings (../shared/data), skipped when absent
# --------------------------------------------------------------------------------------

@pytest.mark.recording
def test_real_ipin_trial01_rep01(shared_data):
    rec = load(shared_data("ipin2023/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"))
    assert rec.kind == "ipin" and rec.warnings == []
    assert rec.meta["line_counts"]["POSI"] == 14
    # 14 distinct presses (counters 1..14); 7 and 8 are the same spot 43 s apart (the walker
    # stood there), and 1 and 14 the same start/end spot: none is a duplicate record.
    assert list(rec.landmarks.counter) == list(range(1, 15))
    assert 45.0 < rec.acc.rate_hz < 105.0 and 45.0 < rec.gyr.rate_hz < 105.0
    assert np.median(np.linalg.norm(rec.acc.values, axis=1)) == pytest.approx(9.8, abs=0.3)
    assert rec.acc.t[0] < rec.landmarks.t[0] and rec.landmarks.t[-1] < rec.acc.t[-1]
    assert rec.meta["phone_model"] == "SM-A520F"
    # the phone's orientation rotates body -> ENU: gravity maps to +z
    q = rec.device_orientation
    acc = rec.acc.values[np.searchsorted(rec.acc.t, q.t).clip(0, len(rec.acc) - 1)]
    assert quat.rotate(q.values, acc).mean(axis=0) == pytest.approx([0.0, 0.0, 9.8], abs=0.3)


@pytest.mark.recording
def test_real_ipin_all_files_load(shared_data):
    files = sorted(shared_data("ipin2023").glob("*.txt.gz"))
    start = time.perf_counter()
    for f in files:
        rec = load_ipin(f)
        assert rec.warnings == [], f
        assert len(rec.landmarks) == rec.meta["line_counts"]["POSI"]
        assert rec.acc.t[0] <= rec.landmarks.t[0] and rec.landmarks.t[-1] <= rec.acc.t[-1]
    print(f"loaded {len(files)} IPIN files in {time.perf_counter() - start:.2f} s")


@pytest.mark.recording
def test_real_oxford(shared_data):
    rec = load(shared_data("oxford-steps/optimisation/Pixel_Jamie_Hard_InHand_1"))
    assert rec.true_steps == 292 and rec.meta["carry"] == "InHand"
    assert np.median(np.linalg.norm(rec.acc.values, axis=1)) == pytest.approx(9.8, abs=0.5)
    val = load(shared_data("oxford-steps/validation/user2_hand_1506421987098.csv.gz"))
    assert val.true_steps == 340 and val.meta["carry"] == "InHand"
    with pytest.warns(RecordingWarning, match="true step count unknown"):
        patient = load_oxford(shared_data("oxford-steps/optimisation/_Patient_3"))
    assert patient.true_steps is None


@pytest.mark.recording
def test_real_pyshoe(shared_data):
    rec = load(shared_data("pyshoe-vicon/2017-11-22-11-22-03_LLIO.mat"))
    assert rec.meta["rate_hz"] == pytest.approx(200.0, rel=0.01)
    idx = rec.meta["stride_index"]
    np.testing.assert_allclose(rec.position_ref.values[idx], rec.meta["gcp"], atol=1e-9)
    assert np.median(np.linalg.norm(rec.acc.values, axis=1)) == pytest.approx(9.8, abs=1.5)


@pytest.mark.recording
def test_real_vicon_ahrs(shared_data):
    with pytest.warns(RecordingWarning, match="not unit length"):  # the fast-rotation part
        rec = load(shared_data("ahrs-vicon/Justa_dataset.mat"))
    assert len(rec.acc) == 6707 and rec.frame == "NWU" and rec.meta["mag_units"] == "normalised"
    assert rec.acc.rate_hz == pytest.approx(81.0, rel=0.05)
    up = quat.rotate(rec.orientation_ref.values[:500], rec.acc.values[:500]).mean(axis=0)
    assert up == pytest.approx([0.0, 0.0, 9.8], abs=0.3)
