"""Incident configuration (service.protocol.incident): the demo museum, frames, floor plans, bad configs."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pdr.floors import FloorElevations
from service.protocol.incident import (
    DEFAULT_INCIDENT_PATH,
    IncidentConfig,
    IncidentConfigError,
    default_incident,
    enu_to_plan_pixel,
    incident_from_dict,
    load_incident,
    plan_pixel_to_enu,
)

CAL = {"centre_lat": 49.46115181, "centre_lon": 11.11114911, "rotation_deg": -20.736, "metres_per_pixel": 0.01232008}
EARTH_RADIUS_M = 6_371_000.0


def minimal(**over) -> dict:
    cfg = {"origin": {"lat": 49.46115181, "lon": 11.11114911, "alt_m": 300.0}}
    cfg.update(over)
    return cfg


def write(tmp_path: Path, cfg, name="incident.json") -> Path:
    p = tmp_path / name
    p.write_text(cfg if isinstance(cfg, str) else json.dumps(cfg))
    return p


def problem(tmp_path: Path, cfg) -> str:
    path = write(tmp_path, cfg)
    with pytest.raises(IncidentConfigError) as e:
        load_incident(path)
    assert str(e.value).startswith(str(path) + ": ")
    return e.value.problem


def bearing(dx: float, dy: float) -> float:
    return math.degrees(math.atan2(dx, dy)) % 360.0


# --------------------------------------------------------------------------------------
# The demo incident
# --------------------------------------------------------------------------------------
def test_demo_incident_loads_with_its_floors_and_checkpoints():
    cfg = default_incident()
    assert DEFAULT_INCIDENT_PATH.name == "ipin-museum.json"
    assert cfg.id == "demo" and cfg.start_floor == 0 and cfg.declination_deg == pytest.approx(3.6)
    assert [(f.number, f.elevation_m) for f in cfg.floors] == [(-2, -6.0), (-1, -3.0), (0, 0.0)]
    assert FloorElevations(cfg.elevations()) == FloorElevations({-2: -6.0, -1: -3.0, 0: 0.0})
    assert (cfg.origin.lat, cfg.origin.lon) == (CAL["centre_lat"], CAL["centre_lon"])
    assert 3 <= len(cfg.checkpoints) <= 6 and cfg.notes
    for cp in cfg.checkpoints:  # both forms filled and agreeing
        x, y, _ = cfg.to_enu(cp.lat, cp.lon)
        assert math.hypot(x - cp.x, y - cp.y) < 1e-6
        assert abs(cp.x) < 150 and abs(cp.y) < 150  # inside the museum, not across town
    assert {cp.floor for cp in cfg.checkpoints} == {0, -2}


def test_demo_loads_without_the_floor_plan_images(tmp_path):
    copy = tmp_path / "deploy" / "incidents" / "ipin-museum.json"
    copy.parent.mkdir(parents=True)
    shutil.copy(DEFAULT_INCIDENT_PATH, copy)  # ../../../shared does not exist from here
    cfg = load_incident(copy)
    assert len(cfg.floor_plans) == 3
    for plan in cfg.floor_plans:
        assert not plan.available and "not found" in plan.problem
        assert plan.path == (copy.parent / plan.image).resolve()
    minus1 = cfg.floor_plan(-1)
    assert minus1.georeferenced and minus1.size == (10719, 5069)  # size_px keeps it usable
    assert not cfg.floor_plan(0).georeferenced and "size unknown" in cfg.floor_plan(0).problem
    assert cfg.floor_plan(0, fallback=True) is cfg.floor_plan(0)  # nothing available to fall back on


def test_demo_plans_resolve_against_shared_data(shared_data):
    image = shared_data("ipin2023/Map_Floor_-01.png")
    cfg = default_incident()
    plan = cfg.floor_plan(-1)
    assert plan.available and plan.path == image.resolve() and plan.size == (10719, 5069)
    assert cfg.floor_plan(0, fallback=True) is plan  # the only image in ../shared serves floor 0 on request


def test_demo_checkpoints_are_the_recordings_landmarks(shared_data):
    from pdr.io import load

    rec = load(shared_data("ipin2023/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"))
    lm = rec.landmarks
    cfg = default_incident()
    x, y, _ = cfg.to_enu(lm.lat, lm.lon)
    for k in range(4):
        cp = cfg.checkpoint(f"t01-lm{k + 1}")
        assert math.hypot(cp.x - x[k], cp.y - y[k]) < 0.01 and cp.floor == lm.floor[k]


# --------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------
def test_origin_is_zero_and_axes_point_east_and_north():
    cfg = incident_from_dict(minimal())
    assert np.allclose(cfg.to_enu(49.46115181, 11.11114911), (0, 0, 0), atol=1e-9)
    # 100 m north and east by the spherical-earth small-angle formulas (independent of pymap3d)
    dlat = math.degrees(100.0 / EARTH_RADIUS_M)
    dlon = math.degrees(100.0 / (EARTH_RADIUS_M * math.cos(math.radians(49.46115181))))
    x, y, _ = cfg.to_enu(49.46115181 + dlat, 11.11114911)
    assert abs(x) < 0.01 and y == pytest.approx(100.0, rel=5e-3)
    x, y, _ = cfg.to_enu(49.46115181, 11.11114911 + dlon)
    assert x == pytest.approx(100.0, rel=5e-3) and abs(y) < 0.01
    _, _, z = cfg.to_enu(49.46115181, 11.11114911, 303.0)
    assert z == pytest.approx(3.0, abs=1e-6)


@settings(max_examples=100)
@given(st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(-50, 50))
def test_enu_geodetic_round_trip(x, y, z):
    cfg = incident_from_dict(minimal())
    lat, lon, alt = cfg.to_geodetic(x, y, z)
    assert np.allclose(cfg.to_enu(lat, lon, alt), (x, y, z), atol=1e-6)


def test_conversions_take_arrays():
    cfg = incident_from_dict(minimal())
    lat, lon, _ = cfg.to_geodetic(np.array([0.0, 10.0]), np.array([0.0, -5.0]))
    x, y, _ = cfg.to_enu(lat, lon)
    assert isinstance(x, np.ndarray) and np.allclose(x, [0, 10], atol=1e-6) and np.allclose(y, [0, -5], atol=1e-6)


# --------------------------------------------------------------------------------------
# Floor plans
# --------------------------------------------------------------------------------------
def cal_plan(size=(10719, 5069), **origin):
    cfg = incident_from_dict(minimal(floor_plans=[{"floor": 0, "image": "nowhere.png", "size_px": list(size),
                                                   "georeference": CAL}], **origin))
    return cfg, cfg.floor_plans[0]


def test_cal_centre_pixel_is_the_cal_centre():
    cfg, plan = cal_plan()
    x, y = plan_pixel_to_enu(plan, 10719 / 2, 5069 / 2)
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-9)
    # with the ENU origin elsewhere, the centre still lands on the .cal's lat/lon
    cfg, plan = cal_plan(origin={"lat": 49.4610, "lon": 11.1100, "alt_m": 300.0})
    lat, lon, _ = cfg.to_geodetic(*plan_pixel_to_enu(plan, 10719 / 2, 5069 / 2))
    assert lat == pytest.approx(CAL["centre_lat"], abs=1e-9) and lon == pytest.approx(CAL["centre_lon"], abs=1e-9)


def test_cal_scale_and_rotation():
    _, plan = cal_plan()
    x0, y0 = plan_pixel_to_enu(plan, 1000.0, 1000.0)
    xr, yr = plan_pixel_to_enu(plan, 2000.0, 1000.0)  # 1000 px to the right
    xu, yu = plan_pixel_to_enu(plan, 1000.0, 0.0)  # 1000 px up
    assert math.hypot(xr - x0, yr - y0) == pytest.approx(1000 * CAL["metres_per_pixel"])
    assert bearing(xu - x0, yu - y0) == pytest.approx(360.0 + CAL["rotation_deg"])  # image up: 20.7 deg west of North
    assert bearing(xr - x0, yr - y0) == pytest.approx(90.0 + CAL["rotation_deg"])


@settings(max_examples=100)
@given(st.floats(-5000, 20000), st.floats(-5000, 10000))
def test_pixel_round_trip(u, v):
    _, plan = cal_plan()
    x, y = plan_pixel_to_enu(plan, u, v)
    uu, vv = enu_to_plan_pixel(plan, x, y)
    assert uu == pytest.approx(u, abs=1e-6) and vv == pytest.approx(v, abs=1e-6)


def test_pixel_functions_take_arrays():
    _, plan = cal_plan()
    u = np.array([0.0, 100.0, 5000.0])
    x, y = plan_pixel_to_enu(plan, u, u * 0.5)
    uu, vv = enu_to_plan_pixel(plan, x, y)
    assert np.allclose(uu, u) and np.allclose(vv, u * 0.5)


@pytest.mark.parametrize("count", [2, 3, 5])
def test_control_points_reproduce_the_cal_map(count):
    cfg, plan = cal_plan()
    pixels = [(100.0, 200.0), (9000.0, 4500.0), (5000.0, 300.0), (200.0, 4000.0), (7000.0, 2500.0)][:count]
    points = []
    for i, (u, v) in enumerate(pixels):
        x, y = plan_pixel_to_enu(plan, u, v)
        if i % 2:
            lat, lon, _ = cfg.to_geodetic(x, y)
            points.append({"u": u, "v": v, "lat": lat, "lon": lon})
        else:
            points.append({"u": u, "v": v, "x": x, "y": y})
    cp_cfg = incident_from_dict(minimal(floor_plans=[{"floor": 0, "image": "x.png",
                                                      "georeference": {"control_points": points}}]))
    cp = cp_cfg.floor_plans[0]
    assert cp.georeferenced and not cp.available
    assert np.allclose(cp.matrix, plan.matrix, atol=1e-6)


def test_a_real_landmark_lands_on_its_marker_in_the_image(shared_data):
    """floormap_references.csv's surveyed points are drawn as coloured discs on the -1 plan:
    the .cal georeference must put each within a metre of its disc. (A wrong rotation sign
    puts them tens of metres away; a scale a few per cent off, metres.)"""
    from PIL import Image
    from scipy import ndimage

    refs = shared_data("ipin2023/floormap_references.csv")
    shared_data("ipin2023/Map_Floor_-01.png")
    cfg = default_incident()
    plan = cfg.floor_plan(-1)
    rows = [line.split(",") for line in refs.read_text().splitlines()[1:] if line.strip()]
    assert len(rows) >= 5
    Image.MAX_IMAGE_PIXELS = None
    reach = int(1.5 / CAL["metres_per_pixel"])
    with Image.open(plan.path) as im:
        for point_id, lat, lon in rows:
            u, v = enu_to_plan_pixel(plan, *cfg.to_enu(float(lat), float(lon))[:2])
            box = (int(u) - reach, int(v) - reach, int(u) + reach, int(v) + reach)
            rgb = np.asarray(im.crop(box).convert("RGB")).astype(int)
            coloured = np.abs(rgb[..., 0] - rgb[..., 2]) > 60  # the orange markers; the plan is grey
            labels, count = ndimage.label(coloured)
            discs = []
            for k, sl in enumerate(ndimage.find_objects(labels), start=1):
                h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
                area = (labels[sl] == k).sum()
                if area > 100 and 0.7 < h / w < 1.4 and area > 0.6 * h * w:  # a filled disc, not the label text
                    cy, cx = ndimage.center_of_mass(labels == k)
                    discs.append(math.hypot(cx + box[0] - u, cy + box[1] - v) * CAL["metres_per_pixel"])
            assert discs, f"reference point {point_id}: no marker within 1.5 m of ({u:.0f}, {v:.0f})"
            assert min(discs) < 1.0, f"reference point {point_id}: marker {min(discs):.2f} m away"


# --------------------------------------------------------------------------------------
# Checkpoints
# --------------------------------------------------------------------------------------
def test_checkpoint_lookup_names_the_known_ones():
    cfg = default_incident()
    assert cfg.checkpoint("t01-lm1").floor == 0
    with pytest.raises(KeyError) as e:
        cfg.checkpoint("front door")
    assert "'front door'" in str(e.value) and "t01-lm1" in str(e.value) and "t52-lm2" in str(e.value)


def test_add_checkpoint():
    cfg = incident_from_dict(minimal(floors=[{"number": 0}, {"number": 1}]))
    cp = cfg.add_checkpoint("stairs", floor=1, lat=49.4612, lon=11.1112)
    assert cfg.checkpoint("stairs") is cp and cp.x is not None and cp.y > 0
    with pytest.raises(ValueError, match="exists already"):
        cfg.add_checkpoint("stairs", floor=0, x=1.0, y=2.0)
    moved = cfg.add_checkpoint("stairs", floor=0, x=1.0, y=2.0, replace=True)
    assert cfg.checkpoint("stairs") is moved and len(cfg.checkpoints) == 1
    assert moved.lat == pytest.approx(cfg.to_geodetic(1.0, 2.0)[0])
    with pytest.raises(ValueError, match="floor 7 is not configured"):
        cfg.add_checkpoint("roof", floor=7, x=0.0, y=0.0)


# --------------------------------------------------------------------------------------
# Bad configurations: file, field path, problem
# --------------------------------------------------------------------------------------
def test_missing_file():
    with pytest.raises(IncidentConfigError) as e:
        load_incident("/nonexistent/incident.json")
    assert str(e.value) == "/nonexistent/incident.json: file not found"


def test_invalid_json_says_where(tmp_path):
    assert "not valid JSON" in (p := problem(tmp_path, '{"origin": {"lat": 1,}}')) and "line 1 column" in p


def test_top_level_must_be_an_object(tmp_path):
    assert "top level" in problem(tmp_path, "[1, 2]")


@pytest.mark.parametrize("cfg, words", [
    (minimal(floors=[{"number": 0}, {"number": 1}, {"number": 2, "elevation_m": "high"}]),
     "floors[2].elevation_m: Input should be a valid number"),
    (minimal(floors=[{"number": "one"}]), "floors[0].number:"),
    ({"origin": {"lat": 95.0, "lon": 11.0}}, "origin.lat: Input should be less than or equal to 90"),
    ({}, "origin: Field required"),
    (minimal(floors=[{"number": 0}, {"number": 0}]), "floors[1].number: floor 0 is configured twice (also floors[0])"),
    (minimal(floors=[{"number": 0, "elevation_m": 0}, {"number": 1, "elevation_m": -1}]),
     "floors[1].elevation_m: -1.0 m for floor 1 is not above 0.0 m of floor 0"),
    (minimal(floors=[]), "floors: at least one floor"),
    (minimal(start_floor=3), "start_floor: floor 3 is not configured; floors: [0]"),
    (minimal(checkpoints=[{"name": "a", "x": 0, "y": 0, "floor": 2}]), "checkpoints[0].floor: floor 2 is not configured"),
    (minimal(checkpoints=[{"name": "a", "x": 0, "y": 0, "floor": 0}, {"name": "a", "x": 1, "y": 1, "floor": 0}]),
     "checkpoints[1].name: 'a' is used twice"),
    (minimal(checkpoints=[{"name": "a", "floor": 0}]), "checkpoints[0]: a checkpoint needs x, y"),
    (minimal(checkpoints=[{"name": "a", "x": 1, "floor": 0}]), "checkpoints[0]: give x and y together"),
    (minimal(checkpoints=[{"name": "a", "x": 100, "y": 0, "lat": 49.46115181, "lon": 11.11114911, "floor": 0}]),
     "checkpoints[0].x, y: (100.0, 0.0) m disagrees with lat, lon"),
    (minimal(checkpoints=[{"name": "a", "x": 0, "y": 0, "floor": 0, "sigma_m": -1}]), "checkpoints[0].sigma_m"),
    (minimal(uwb_anchors=[{"id": "A", "x": 0, "y": 0}, {"id": "A", "x": 1, "y": 0}]), "uwb_anchors[1].id: 'A' is used twice"),
    (minimal(uwb_anchors=[{"id": "A/1", "x": 0, "y": 0}]), "uwb_anchors[0].id"),
    (minimal(floor_plans=[{"floor": 4, "image": "a.png", "georeference": CAL}]), "floor_plans[0].floor: floor 4"),
    (minimal(floor_plans=[{"floor": 0, "image": "a.png", "georeference": {"centre_lat": 49.0}}]),
     "floor_plans[0].georeference: needs centre_lat, centre_lon, rotation_deg, metres_per_pixel (missing: centre_lon"),
    (minimal(floor_plans=[{"floor": 0, "image": "a.png", "georeference": {**CAL, "control_points": []}}]),
     "floor_plans[0].georeference: give either control_points or"),
    (minimal(floor_plans=[{"floor": 0, "image": "a.png", "georeference": {"control_points": [{"u": 0, "v": 0, "x": 0}]}}]),
     "floor_plans[0].georeference.control_points[0]: a control point needs either x, y or lat, lon"),
    (minimal(floor_plans=[{"floor": 0, "image": "a.png", "georeference": {"control_points": [
        {"u": 0, "v": 0, "x": 0, "y": 0}, {"u": 10, "v": 10, "x": 1, "y": 1}, {"u": 20, "v": 20, "x": 5, "y": 2}]}}]),
     "floor_plans[0].georeference: control points are collinear"),
    (minimal(floor_plans=[{"floor": 0, "image": "a.png", "georeference": {"control_points": [
        {"u": 0, "v": 0, "x": 0, "y": 0}, {"u": 0, "v": 0, "x": 1, "y": 1}]}}]),
     "floor_plans[0].georeference: the two control points must differ"),
    (minimal(declination=3.0), "declination: Extra inputs are not permitted"),
    (minimal(floors=[{"number": 0, "elevaton_m": 1}]), "floors[0].elevaton_m: Extra inputs are not permitted"),
    (minimal(id="a/b"), "id: String should match pattern"),
])
def test_bad_configs_name_the_field(tmp_path, cfg, words):
    assert words in problem(tmp_path, cfg)


def test_several_problems_are_reported_together(tmp_path):
    p = problem(tmp_path, minimal(start_floor=9, checkpoints=[{"name": "a", "x": 0, "y": 0, "floor": 5}]))
    assert "start_floor" in p and "checkpoints[0].floor" in p


def test_default_floor_height_and_names():
    cfg = incident_from_dict(minimal(floor_height_m=2.5, floors=[{"number": 2}, {"number": -1}, {"number": 0, "name": "lobby"}]))
    assert [(f.number, f.elevation_m, f.name) for f in cfg.floors] == [(-1, -2.5, "Floor -1"), (0, 0.0, "lobby"),
                                                                     (2, 5.0, "Floor 2")]
    assert incident_from_dict(minimal()).floors[0].elevation_m == 0.0
    assert IncidentConfig.model_fields["floor_height_m"].default == 3.0


def test_floor_plan_image_size_checks_and_unreadable_images(tmp_path):
    from PIL import Image

    Image.new("RGB", (40, 20), "white").save(tmp_path / "plan.png")
    (tmp_path / "broken.png").write_bytes(b"not a png")
    ok = {"floor": 0, "image": "plan.png", "georeference": CAL}
    cfg = load_incident(write(tmp_path, minimal(floor_plans=[ok])))
    plan = cfg.floor_plan(0)
    assert plan.available and plan.size == (40, 20) and plan.path == tmp_path / "plan.png"
    assert plan_pixel_to_enu(plan, 20, 10) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert "size_px: [41, 20] but plan.png is 40 x 20 pixels" in problem(tmp_path, minimal(floor_plans=[{**ok, "size_px": [41, 20]}]))
    cfg = load_incident(write(tmp_path, minimal(floor_plans=[{**ok, "image": "broken.png"}])))
    assert not cfg.floor_plan(0).available and "unreadable" in cfg.floor_plan(0).problem
    with pytest.raises(ValueError, match="no usable georeference"):
        plan_pixel_to_enu(cfg.floor_plan(0), 0, 0)


def test_toml_is_read_too(tmp_path):
    p = write(tmp_path, 'id = "drill"\n[origin]\nlat = 49.0\nlon = 11.0\n[[floors]]\nnumber = 0\n[[floors]]\nnumber = 1\n',
              "incident.toml")
    cfg = load_incident(p)
    assert cfg.id == "drill" and [f.elevation_m for f in cfg.floors] == [0.0, 3.0]
    bad = write(tmp_path, "id = \n", "bad.toml")
    with pytest.raises(IncidentConfigError, match="not valid TOML"):
        load_incident(bad)


# --------------------------------------------------------------------------------------
# Bounds (issue 32, part 6): depth, sizes, values, one short line
# --------------------------------------------------------------------------------------
def _one_line(p: str) -> str:
    assert "\n" not in p and len(p) <= 1100, p[:300]
    return p


@pytest.mark.parametrize("suffix, text, words", [
    (".json", "[" * 100_000 + "]" * 100_000, "nested 100,000 deep"),
    (".json", '{"origin": ' + "{" * 50 + "}" * 50 + "}", "nested 51 deep"),
    (".toml", "a = " + "[" * 100_000 + "]" * 100_000 + "\n", "nested 100,000 deep"),
    (".toml", "a" + ".a" * 5000 + " = 1\n", "nested more than 32 levels"),
    (".json", '{"name": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[", "origin": 1}', "origin: Input should be"),  # in a string
])
def test_deep_configs_are_one_line_not_a_recursion_error(tmp_path, suffix, text, words):
    f = tmp_path / f"deep{suffix}"
    f.write_text(text)
    with pytest.raises(IncidentConfigError) as e:
        load_incident(f)
    assert words in _one_line(str(e.value))


@pytest.mark.parametrize("cfg, words", [
    (minimal(floor_height_m=1e308), "floor_height_m: Input should be less than or equal to 100 (got 1e+308)"),
    (minimal(floors=[{"number": i} for i in range(200_000)]), "floors: 200,000 entries; at most 256"),
    (minimal(roster=[{"id": f"r{i}"} for i in range(5000)]), "roster: 5,000 entries; at most 4,096"),
    (minimal(name="x" * 1_000_000), "name: String should have at most 256 characters"),
    (minimal(floors=[{"number": 0, "elevation_m": 1e20}]), "floors[0].elevation_m"),
    (minimal(uwb_anchors=[{"id": "A", "x": 1e9, "y": 0}]), "uwb_anchors[0].x"),
    (minimal(uwb_anchors=[{"id": "A", "x": 6000, "y": 0}]), "uwb_anchors[0]: (6000.0, 0.0) m is outside the incident's extent_m"),
    (minimal(checkpoints=[{"name": "far", "x": 4000, "y": 4000, "floor": 0}]), "checkpoints[0].x, y: (4000.0, 4000.0) m is outside"),
    (minimal(floors=[{"number": 0, "elevation_m": "x" * 100_000}] + [{"number": i, "name": 5} for i in range(1, 200)]),
     "and 192 more problems"),
])
def test_sizes_and_values_are_bounded_and_errors_are_one_short_line(tmp_path, cfg, words):
    assert words in _one_line(problem(tmp_path, cfg))


def test_nan_and_infinity_are_refused(tmp_path):
    f = tmp_path / "nan.json"
    f.write_text(json.dumps(minimal(floor_height_m=float("inf"))))  # json writes Infinity
    with pytest.raises(IncidentConfigError, match="Infinity is not a number"):
        load_incident(f)
