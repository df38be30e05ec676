"""An incident as Foxglove messages (the ``foxglove-sdk`` package's schemas, ``[foxglove]`` extra).

One place builds every message the Foxglove file export (:mod:`service.review.foxglove_export`)
and the live WebSocket bridge (:mod:`service.shell.foxglove_live`) send, so a file and a live
session look the same in Foxglove:

- ``foxglove.LocationFix`` per pose: WGS-84 latitude, longitude and ellipsoidal height (the
  floor's elevation above the incident origin), and the position covariance. Foxglove's
  covariance is 3 x 3, row-major, in East-North-Up about the reported point (the ROS
  ``NavSatFix`` convention), so the pose's 2 x 2 ENU covariance goes in unchanged and the up
  variance is :data:`VERTICAL_SIGMA_M`² (the height is the floor's, known to about a metre).
- ``foxglove.PoseInFrame`` in the incident's ENU frame (:func:`enu_frame`, x East, y North,
  z Up, at the incident origin), z the floor's elevation, orientation the yaw alone:
  q = (cos(yaw/2), 0, 0, sin(yaw/2)), scalar first, body -> ENU, yaw counter-clockwise from
  East (the compass bearing b gives yaw = 90° − b).
- ``foxglove.FrameTransforms``: one frame per floor (:func:`floor_frame`), its origin lifted
  by the floor's elevation, so plans and checkpoints sit on their floor in the 3D panel.
- ``foxglove.SceneUpdate``: the floors' plan outlines and names, the checkpoints, UWB anchors
  and beacons (when the incident config has any), each in its floor's frame.
- ``foxglove.Grid``: a floor's plan image, in the floor's frame, one cell per
  :data:`PLAN_CELL_M` (the image averaged over blocks of pixels), coloured by its own
  ``red``, ``green``, ``blue``, ``alpha`` fields (the 3D panel's "RGBA (separate fields)" mode).
- ``foxglove.Log``: alarms and operator actions.

Times are Unix seconds (UTC); Foxglove's ``Timestamp`` carries them to the nanosecond.
"""
from __future__ import annotations

import math

import numpy as np
from foxglove.messages import (
    Color,
    FrameTransform,
    FrameTransforms,
    Grid,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    LocationFix,
    LocationFixPositionCovarianceType,
    Log,
    LogLevel,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    Pose,
    PoseInFrame,
    PosesInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector2,
    Vector3,
)

VERTICAL_SIGMA_M = 1.0  # m: 1-sigma of a pose's height, which is its floor's configured elevation
PLAN_CELL_M = 0.2  # m: a plan image's pixels are averaged into cells of about this size
PALETTE = ((0.89, 0.10, 0.11), (0.22, 0.49, 0.72), (0.30, 0.69, 0.29), (0.60, 0.31, 0.64),
           (1.00, 0.50, 0.00), (0.65, 0.34, 0.16), (0.97, 0.51, 0.75), (0.40, 0.40, 0.40))
LEVELS = {"debug": LogLevel.Debug, "info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}


def enu_frame(incident_id: str) -> str:
    """The incident's local ENU frame (x East, y North, z Up at the incident origin)."""
    return f"{incident_id}/enu"


def floor_frame(incident_id: str, floor: int) -> str:
    """Floor ``floor``'s frame: the ENU frame lifted by the floor's elevation."""
    return f"{incident_id}/floor_{floor}"


def stamp(unix_s: float) -> Timestamp:
    """A Foxglove timestamp of a Unix time in seconds."""
    return Timestamp.from_epoch_secs(float(unix_s))


def responder_color(index: int, alpha: float = 1.0) -> Color:
    r, g, b = PALETTE[index % len(PALETTE)]
    return Color(r=r, g=g, b=b, a=alpha)


def yaw_quaternion(yaw: float) -> Quaternion:
    """Rotation by ``yaw`` (rad, counter-clockwise from East) about Up, body -> ENU."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))


def location_fix(unix_s: float, lat: float, lon: float, alt: float, cov_xy=None, frame_id: str = "",
                 color: Color | None = None, responder: str | None = None) -> LocationFix:
    """A ``foxglove.LocationFix``; ``cov_xy`` the (2, 2) ENU position covariance (m²), or None."""
    if cov_xy is None:
        cov, kind = [0.0] * 9, LocationFixPositionCovarianceType.Unknown
    else:
        c = np.asarray(cov_xy, dtype=np.float64)
        cov = [c[0, 0], c[0, 1], 0.0, c[1, 0], c[1, 1], 0.0, 0.0, 0.0, VERTICAL_SIGMA_M ** 2]
        kind = LocationFixPositionCovarianceType.Known
    meta = [KeyValuePair(key="responder", value=responder)] if responder else None
    return LocationFix(timestamp=stamp(unix_s), frame_id=frame_id, latitude=float(lat), longitude=float(lon),
                       altitude=float(alt), position_covariance=[float(v) for v in cov],
                       position_covariance_type=kind, color=color, metadata=meta)


def pose_in_frame(unix_s: float, frame_id: str, x: float, y: float, z: float, yaw: float) -> PoseInFrame:
    return PoseInFrame(timestamp=stamp(unix_s), frame_id=frame_id, pose=_pose(x, y, z, yaw))


def path_in_frame(unix_s: float, frame_id: str, x, y, z, yaw) -> PosesInFrame:
    """A whole track as one ``foxglove.PosesInFrame`` (the 3D panel draws it as a path)."""
    return PosesInFrame(timestamp=stamp(unix_s), frame_id=frame_id,
                        poses=[_pose(a, b, c, d) for a, b, c, d in zip(x, y, z, yaw)])


def _pose(x: float, y: float, z: float, yaw: float) -> Pose:
    return Pose(position=Vector3(x=float(x), y=float(y), z=float(z)), orientation=yaw_quaternion(float(yaw)))


def floor_transforms(incident, unix_s: float) -> FrameTransforms:
    """The ENU frame -> each floor's frame: a lift by the floor's elevation (m)."""
    root = enu_frame(incident.id)
    return FrameTransforms(transforms=[
        FrameTransform(timestamp=stamp(unix_s), parent_frame_id=root, child_frame_id=floor_frame(incident.id, f.number),
                       translation=Vector3(x=0.0, y=0.0, z=float(f.elevation_m)), rotation=yaw_quaternion(0.0))
        for f in incident.floors])


def log(unix_s: float, level: str, message: str, name: str) -> Log:
    """A ``foxglove.Log``: ``level`` one of debug, info, warning, error; ``name`` who said it."""
    return Log(timestamp=stamp(unix_s), level=LEVELS[level], message=message, name=name)


# ------------------------------------------------------------------------------------------
# The building: floors, plans, checkpoints, anchors, beacons
# ------------------------------------------------------------------------------------------
def building_scene(incident, unix_s: float) -> SceneUpdate:
    """One entity per floor (its plan's outline and its name) and one per surveyed point
    (checkpoints, UWB anchors, beacons when the config has them), in their floors' frames."""
    from service.protocol.floorplan import plan_pixel_to_enu

    ts = stamp(unix_s)
    entities = []
    for f in incident.floors:
        plan = incident.floor_plan(f.number, fallback=True)
        lines, texts = [], []
        if plan is not None and plan.georeferenced and plan.size is not None:
            w, h = plan.size
            xs, ys = plan_pixel_to_enu(plan, np.array([0, w, w, 0, 0]), np.array([0, 0, h, h, 0]))
            lines.append(LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.15,
                                       points=[Point3(x=float(a), y=float(b), z=0.0) for a, b in zip(xs, ys)],
                                       color=Color(r=0.5, g=0.5, b=0.5, a=1.0)))
            label = (float(xs[0]), float(ys[0]))
        else:
            label = (0.0, 0.0)
        texts.append(TextPrimitive(pose=_pose(label[0], label[1], 0.5, 0.0), billboard=True, font_size=14.0,
                                   scale_invariant=True, color=Color(r=1.0, g=1.0, b=1.0, a=1.0), text=f.name or str(f.number)))
        entities.append(SceneEntity(timestamp=ts, frame_id=floor_frame(incident.id, f.number), id=f"floor/{f.number}",
                                    lines=lines, texts=texts))
    points = [("checkpoint", cp.name, cp.x, cp.y, cp.floor, 0.0, (0.1, 0.8, 0.1)) for cp in incident.checkpoints]
    for a in incident.uwb_anchors:
        floor = a.floor if a.floor is not None else _floor_below(incident, a.z)
        points.append(("uwb", a.id, a.x, a.y, floor, a.z - incident.floor(floor).elevation_m, (0.9, 0.6, 0.0)))
    points += [("beacon", b_id, bx, by, bf, 0.0, (0.2, 0.5, 1.0)) for b_id, bx, by, bf in _beacons(incident)]
    for kind, name, x, y, floor, z, rgb in points:
        col = Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0)
        entities.append(SceneEntity(
            timestamp=ts, frame_id=floor_frame(incident.id, floor), id=f"{kind}/{name}",
            metadata=[KeyValuePair(key="kind", value=kind), KeyValuePair(key="floor", value=str(floor))],
            spheres=[SpherePrimitive(pose=_pose(x, y, z, 0.0), size=Vector3(x=0.6, y=0.6, z=0.6), color=col)],
            texts=[TextPrimitive(pose=_pose(x, y, z + 0.8, 0.0), billboard=True, font_size=12.0, scale_invariant=True,
                                 color=col, text=f"{kind} {name}")]))
    return SceneUpdate(entities=entities)


def _floor_below(incident, z: float) -> int:
    """The highest floor whose elevation is at or below ``z`` (the lowest floor if none)."""
    below = [f.number for f in incident.floors if f.elevation_m <= z]
    return max(below) if below else incident.floors[0].number


def _beacons(incident) -> list[tuple[str, float, float, int]]:
    """(id, x, y, floor) of the incident's beacons, for configs that list them (``beacons``:
    items with ``id``, ``x``, ``y`` or ``lat``, ``lon``, and ``floor``); none otherwise."""
    out = []
    for b in getattr(incident, "beacons", None) or []:
        x, y = getattr(b, "x", None), getattr(b, "y", None)
        if x is None and getattr(b, "lat", None) is not None:
            x, y, _ = incident.to_enu(b.lat, b.lon)
        if x is not None:
            out.append((str(getattr(b, "id", getattr(b, "name", "?"))), float(x), float(y), int(getattr(b, "floor", 0) or 0)))
    return out


def plan_grids(incident, unix_s: float, cell_m: float = PLAN_CELL_M) -> dict[int, Grid]:
    """Each floor's plan (its own, or the nearest floor's when it has none, as the console
    does) as a ``foxglove.Grid`` in the floor's frame; floors without a usable plan are left out."""
    cache: dict = {}
    out = {}
    for f in incident.floors:
        plan = incident.floor_plan(f.number, fallback=True)
        if plan is None or not plan.available or not plan.georeferenced:
            continue
        if plan.path not in cache:
            cache[plan.path] = _plan_cells(plan, cell_m)
        pose, cell, cols, data = cache[plan.path]
        out[f.number] = Grid(timestamp=stamp(unix_s), frame_id=floor_frame(incident.id, f.number), pose=pose,
                             column_count=cols, cell_size=cell, row_stride=4 * cols, cell_stride=4,
                             fields=[PackedElementField(name=n, offset=k, type=PackedElementFieldNumericType.Uint8)
                                     for k, n in enumerate(("red", "green", "blue", "alpha"))],
                             data=data)
    return out


def _plan_cells(plan, cell_m: float):
    """The grid's pose, cell size, column count and RGBA bytes of a plan image.

    The plan's affine map sends pixel (u, v) (right, down) to ENU: [x, y] = a u + b v + c.
    The grid's origin is the image's bottom-left corner, its x axis along a (the image's
    rows), its y axis along −b (up the image), so its row 0 is the image's bottom row.
    """
    from PIL import Image

    from service.protocol.floorplan import plan_pixel_to_enu

    m = plan.matrix
    a, b = m[:, 0], m[:, 1]
    px = float(np.hypot(*a))
    k = max(1, int(round(cell_m / px)))
    with Image.open(plan.path) as im:
        im = im if im.mode == "RGBA" else im.convert("RGBA")  # a large plan: no second full-size copy
        cols, rows = max(1, im.size[0] // k), max(1, im.size[1] // k)
        small = im.resize((cols, rows), Image.Resampling.BOX, box=(0, 0, cols * k, rows * k))
    rgba = np.asarray(small, dtype=np.uint8)[::-1]  # bottom row first
    x0, y0 = plan_pixel_to_enu(plan, 0.0, float(rows * k))
    yaw = math.atan2(a[1], a[0])
    pose = _pose(x0, y0, 0.0, yaw)
    cell = Vector2(x=k * px, y=k * float(np.hypot(*b)))
    return pose, cell, cols, np.ascontiguousarray(rgba).tobytes()
