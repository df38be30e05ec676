"""Track exports: GeoJSON geometry and axis order, CSV columns, TUM read back as evo would."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from pdr.floors import FloorElevations
from service.review.export import IncidentOrigin, to_csv, to_geojson, to_tum

ORIGIN = IncidentOrigin(lat=50.0875, lon=14.4213, alt=200.0)
M_PER_DEG_LAT = 111_229.0  # WGS84 meridian arc per degree near 50 deg N


def _track(n=50, seed=0, floors=None):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.4, 0.6, n))
    heading = np.unwrap(np.cumsum(rng.normal(0, 0.3, n)))
    x = np.cumsum(0.7 * np.cos(heading))
    y = np.cumsum(0.7 * np.sin(heading))
    floor = np.zeros(n, dtype=int) if floors is None else np.asarray(floors)
    return {"t": t, "x": x, "y": y, "heading": heading, "floor": floor}


def test_geojson_lon_lat_order_and_floor_segments():
    east = {"t": [0.0, 1.0, 2.0], "x": [0.0, 100.0, 200.0], "y": [0.0, 0.0, 0.0], "heading": [0.0] * 3, "floor": [0, 0, 0]}
    north = {"t": [0.0, 1.0], "x": [0.0, 0.0], "y": [0.0, 100.0], "heading": [math.pi / 2] * 2, "floor": [1, 1]}
    gj = to_geojson({"east": east, "north": north}, ORIGIN)
    text = json.dumps(gj, allow_nan=False)  # strict JSON: every number finite
    gj = json.loads(text)
    assert gj["type"] == "FeatureCollection" and len(gj["features"]) == 2
    e, n = (f["geometry"]["coordinates"] for f in gj["features"])
    # [lon, lat]: walking East moves the first number, walking North the second
    assert e[0] == pytest.approx([ORIGIN.lon, ORIGIN.lat], abs=1e-7)
    m_per_deg_lon = M_PER_DEG_LAT * math.cos(math.radians(ORIGIN.lat))
    assert (e[2][0] - ORIGIN.lon) * m_per_deg_lon == pytest.approx(200.0, rel=5e-3)
    assert e[2][1] == pytest.approx(ORIGIN.lat, abs=1e-6)
    assert (n[1][1] - ORIGIN.lat) * M_PER_DEG_LAT == pytest.approx(100.0, rel=5e-3)
    assert n[1][0] == pytest.approx(ORIGIN.lon, abs=1e-6)
    assert gj["features"][0]["properties"]["bearing_deg_end"] == 90.0  # yaw 0 = East = bearing 90
    assert gj["features"][1]["properties"]["bearing_deg_end"] == 0.0

    stairs = _track(7, floors=[0, 0, 0, 1, 1, 2, 2])
    stairs["floor"] = np.array([0, 0, 0, 1, 1, 2, 1])
    feats = to_geojson({"ff1": stairs}, ORIGIN, FloorElevations.uniform(3.0, 0, 3))["features"]
    assert [(f["geometry"]["type"], f["properties"]["floor"]) for f in feats] == \
        [("LineString", 0), ("LineString", 1), ("Point", 2), ("Point", 1)]
    assert [len(f["geometry"]["coordinates"]) for f in feats[:2]] == [3, 2]
    assert [f["properties"]["elevation_m"] for f in feats] == [0.0, 3.0, 6.0, 3.0]
    assert feats[1]["properties"]["t_start"] == stairs["t"][3] and feats[1]["properties"]["t_end"] == stairs["t"][4]
    for f in feats:
        for lon, lat in np.reshape(f["geometry"]["coordinates"], (-1, 2)):
            assert -180 <= lon <= 180 and -90 <= lat <= 90


def test_csv_columns_and_quoting(tmp_path):
    tracks = {"ff1": _track(20, 1), "crew, B": _track(5, 2)}
    n = to_csv(tracks, tmp_path / "t.csv", origin=ORIGIN)
    assert n == 25
    with open(tmp_path / "t.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["responder", "t", "x", "y", "floor", "heading_deg", "lat", "lon"]
    assert [r["responder"] for r in rows] == ["ff1"] * 20 + ["crew, B"] * 5
    got = np.array([[float(r[k]) for k in ("t", "x", "y", "heading_deg")] for r in rows[:20]])
    tr = tracks["ff1"]
    np.testing.assert_allclose(got[:, 0], tr["t"], atol=1e-6)
    np.testing.assert_allclose(got[:, 1:3], np.column_stack([tr["x"], tr["y"]]), atol=1e-3)
    bearing = np.mod(90.0 - np.degrees(tr["heading"]), 360.0)
    np.testing.assert_allclose(np.cos(np.radians(got[:, 3] - bearing)), 1.0, atol=1e-6)
    lat = np.array([float(r["lat"]) for r in rows[:20]])
    np.testing.assert_allclose((lat - ORIGIN.lat) * M_PER_DEG_LAT, tr["y"], atol=0.5)

    to_csv({"ff1": _track(3)}, tmp_path / "plain.csv")
    with open(tmp_path / "plain.csv", newline="") as f:
        assert [r["lat"] for r in csv.DictReader(f)] == ["", "", ""]


def test_tum_reads_back_with_the_yaw(tmp_path):
    track = _track(40, 3, floors=[0] * 20 + [2] * 20)
    floors = FloorElevations({0: 0.0, 1: 3.5, 2: 7.0})
    assert to_tum(track, tmp_path / "ff1.tum", floors) == 40
    table = np.loadtxt(tmp_path / "ff1.tum")
    assert table.shape == (40, 8)
    t, x, y, z, qx, qy, qz, qw = table.T
    np.testing.assert_allclose(t, track["t"], atol=1e-6)
    np.testing.assert_allclose(np.column_stack([x, y]), np.column_stack([track["x"], track["y"]]), atol=1e-4)
    np.testing.assert_allclose(z, np.where(np.arange(40) < 20, 0.0, 7.0))
    np.testing.assert_allclose(qx**2 + qy**2 + qz**2 + qw**2, 1.0, atol=1e-8)
    np.testing.assert_allclose(qx, 0.0, atol=1e-12)
    np.testing.assert_allclose(qy, 0.0, atol=1e-12)
    # yaw of the quaternion (ZYX extraction) against the track's heading, modulo 2 pi
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
    np.testing.assert_allclose(np.cos(yaw - track["heading"]), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.sin(yaw - track["heading"]), 0.0, atol=1e-6)

    to_tum(_track(5), tmp_path / "flat.tum")
    assert np.all(np.loadtxt(tmp_path / "flat.tum")[:, 3] == 0.0)


def test_bad_tracks_are_named():
    bad = _track(10)
    bad["x"][4] = np.nan
    with pytest.raises(ValueError, match=r"'ff7'.*x.*sample 4"):
        to_geojson({"ff7": bad}, ORIGIN)
    short = _track(10)
    short["y"] = short["y"][:9]
    with pytest.raises(ValueError, match=r"'ff2'.*y has 9 samples"):
        to_geojson({"ff2": short}, ORIGIN)
    with pytest.raises(ValueError, match="floor 5 is not configured"):
        to_geojson({"ff1": _track(3, floors=[0, 5, 5])}, ORIGIN, FloorElevations.uniform(3.0, 0, 2))
    with pytest.raises(ValueError, match="heading"):
        to_geojson({"ff1": {k: v for k, v in _track(3).items() if k != "heading"}}, ORIGIN)
    with pytest.raises(ValueError, match="WGS84"):
        to_geojson({"ff1": _track(3)}, (123.0, 14.0, 0.0))
