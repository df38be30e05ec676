"""An incident's configuration: where the building is, its floors, checkpoints, anchors, plans.

Loaded from JSON (or TOML) by :func:`load_incident`; every problem becomes an
:class:`IncidentConfigError` naming the file, the field path (``floors[2].elevation_m``) and
what is wrong. The navigation frame is local ENU (x East, y North, z Up, metres) on the tangent
plane at ``origin``; conversions go through pymap3d on the WGS-84 ellipsoid.

Floor plans
-----------
An image pixel is ``(u, v)``: ``u`` to the right, ``v`` down, in pixels from the image's
top-left corner (pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)``, so the image centre is
``(W/2, H/2)``). A plan's georeference is an affine map pixel -> ENU,
``[x, y] = A [u, v] + b``, given either

* IPIN ``.cal`` style: the image centre's ``centre_lat``/``centre_lon``, ``metres_per_pixel``
  ``s`` and ``rotation_deg`` ``r``, the compass bearing of the image's "up" (clockwise from
  North; the IPIN 2023 museum's -20.736 deg puts up 20.7 deg west of North, which is what
  lines the surveyed reference points of ``floormap_references.csv`` up with the dots drawn
  on ``Map_Floor_-01.png``). With ``phi = -r`` (counter-clockwise)::

      a = s (u - W/2),  b = s (H/2 - v)                 (image right, image up; m)
      x = x_c + a cos(phi) - b sin(phi)
      y = y_c + a sin(phi) + b cos(phi)                  ((x_c, y_c) the centre in ENU)

  It needs the image size, read from the image or given as ``size_px``. The plane of the
  image is taken as the ENU plane: over a building (100 m) the two differ by far less than a
  pixel's worth of metres.
* control points: two or more ``{u, v}`` with ``{x, y}`` or ``{lat, lon}``. Two give a
  similarity (scale, rotation, shift; ``v`` flipped); three or more a least-squares affine map.

A plan whose image is missing still loads: ``available`` is False and ``problem`` says why, so
a console can draw without it.
"""
from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    model_validator,
)
from pydantic_core import PydanticCustomError

from service.protocol.wire import ID_PATTERN, error_location

DEFAULT_INCIDENT_PATH = Path(__file__).resolve().parents[2] / "deploy" / "incidents" / "ipin-museum.json"
DEFAULT_FLOOR_HEIGHT_M = 3.0
POSITION_AGREEMENT_M = 0.05  # x, y and lat, lon given together must agree this well


class IncidentConfigError(ValueError):
    """A configuration file that cannot be used: ``path`` and ``problem`` (field path + what)."""

    def __init__(self, path: str | Path, problem: str):
        super().__init__(f"{path}: {problem}")
        self.path = str(path)
        self.problem = problem


class UnknownCheckpointError(KeyError):
    """A checkpoint name the incident does not know (message lists the known ones)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=False)


class Origin(_Config):
    """The ENU origin: WGS-84 latitude, longitude (deg) and ellipsoidal height (m)."""

    lat: float = Field(ge=-90.0, le=90.0)
    lon: float = Field(ge=-180.0, le=180.0)
    alt_m: float = 0.0


class Floor(_Config):
    """A floor: its integer number, a name people use, and its elevation (m, any common datum;
    default ``number * floor_height_m``)."""

    number: int
    name: str | None = None
    elevation_m: float | None = None


class Checkpoint(_Config):
    """A named point an operator can place a responder at (a :class:`service.protocol.wire.Fix` with
    ``source="checkpoint"`` and ``name``). Give ``x, y`` (ENU, m) or ``lat, lon`` (deg); after
    loading both are filled. ``sigma_m`` is the 1-sigma horizontal uncertainty."""

    name: str = Field(min_length=1, max_length=128)
    x: float | None = None
    y: float | None = None
    lat: float | None = Field(None, ge=-90.0, le=90.0)
    lon: float | None = Field(None, ge=-180.0, le=180.0)
    floor: int
    sigma_m: float = Field(0.5, gt=0.0)
    note: str | None = None

    @model_validator(mode="after")
    def _position_given(self) -> Checkpoint:
        if (self.x is None) != (self.y is None):
            raise PydanticCustomError("position", "give x and y together")
        if (self.lat is None) != (self.lon is None):
            raise PydanticCustomError("position", "give lat and lon together")
        if self.x is None and self.lat is None:
            raise PydanticCustomError("position", "a checkpoint needs x, y (local ENU, m) or lat, lon (deg)")
        return self


class UwbAnchor(_Config):
    """A UWB anchor at ENU ``x, y, z`` (m)."""

    id: str = Field(pattern=ID_PATTERN)
    x: float
    y: float
    z: float = 0.0
    floor: int | None = None


class ControlPoint(_Config):
    """A pixel ``u, v`` of a plan and where it is: ``x, y`` (ENU, m) or ``lat, lon`` (deg)."""

    u: float
    v: float
    x: float | None = None
    y: float | None = None
    lat: float | None = Field(None, ge=-90.0, le=90.0)
    lon: float | None = Field(None, ge=-180.0, le=180.0)

    @model_validator(mode="after")
    def _one_position(self) -> ControlPoint:
        enu, geo = self.x is not None and self.y is not None, self.lat is not None and self.lon is not None
        if enu == geo or (self.x is None) != (self.y is None) or (self.lat is None) != (self.lon is None):
            raise PydanticCustomError("position", "a control point needs either x, y or lat, lon")
        return self


class Georeference(_Config):
    """Either the IPIN ``.cal`` four (``centre_lat``, ``centre_lon``, ``rotation_deg``,
    ``metres_per_pixel``) or ``control_points`` (see the module docstring)."""

    centre_lat: float | None = Field(None, ge=-90.0, le=90.0)
    centre_lon: float | None = Field(None, ge=-180.0, le=180.0)
    rotation_deg: float | None = None
    metres_per_pixel: float | None = Field(None, gt=0.0)
    control_points: list[ControlPoint] | None = None

    @model_validator(mode="after")
    def _one_style(self) -> Georeference:
        cal = ("centre_lat", "centre_lon", "rotation_deg", "metres_per_pixel")
        given = [f for f in cal if getattr(self, f) is not None]
        if self.control_points is not None:
            if given:
                raise PydanticCustomError("georeference", "give either control_points or {cal}, not both",
                                          {"cal": ", ".join(cal)})
            if len(self.control_points) < 2:
                raise PydanticCustomError("georeference", "control_points: need at least 2, got {n}",
                                          {"n": len(self.control_points)})
        elif len(given) != len(cal):
            missing = [f for f in cal if f not in given]
            raise PydanticCustomError("georeference", "needs {cal} (missing: {missing}) or control_points",
                                      {"cal": ", ".join(cal), "missing": ", ".join(missing)})
        return self

    @property
    def is_cal(self) -> bool:
        return self.control_points is None


class FloorPlan(_Config):
    """A floor's plan image and its georeference. ``image`` relative to the config file."""

    floor: int
    image: str = Field(min_length=1)
    georeference: Georeference
    size_px: tuple[int, int] | None = Field(None, description="image width, height in pixels (read from the image if absent)")

    _path: Path | None = PrivateAttr(None)
    _available: bool = PrivateAttr(False)
    _problem: str | None = PrivateAttr(None)
    _size: tuple[int, int] | None = PrivateAttr(None)
    _matrix: np.ndarray | None = PrivateAttr(None)  # (2, 3): [x, y] = M @ [u, v, 1]

    @property
    def path(self) -> Path | None:
        """The image file, resolved against the config file's folder."""
        return self._path

    @property
    def available(self) -> bool:
        """True when the image file exists and could be read."""
        return self._available

    @property
    def problem(self) -> str | None:
        """Why the image (or its georeference) is unavailable."""
        return self._problem

    @property
    def size(self) -> tuple[int, int] | None:
        """(width, height) in pixels, when known."""
        return self._size

    @property
    def georeferenced(self) -> bool:
        return self._matrix is not None

    @property
    def matrix(self) -> np.ndarray:
        """The (2, 3) affine matrix pixel -> ENU: ``[x, y] = M @ [u, v, 1]``."""
        if self._matrix is None:
            raise ValueError(f"the plan of floor {self.floor} has no usable georeference: {self._problem}")
        return self._matrix


class IncidentConfig(_Config):
    """Everything the service and console know about the place of an incident."""

    id: str = Field("demo", pattern=ID_PATTERN)
    name: str = ""
    notes: str | list[str] | None = None
    origin: Origin
    declination_deg: float = Field(0.0, ge=-180.0, le=180.0, description="magnetic declination, East positive")
    field_inclination_deg: float | None = Field(None, ge=-90.0, le=90.0, description="magnetic dip (down positive), e.g. from the WMM; lets the compass reject fields with the wrong dip")
    field_norm_ut: float | None = Field(None, gt=0.0, description="magnetic field strength (µT), e.g. from the WMM")
    floor_height_m: float = Field(DEFAULT_FLOOR_HEIGHT_M, gt=0.0, description="default floor spacing")
    floors: list[Floor] = Field(default_factory=lambda: [Floor(number=0, name="Ground floor", elevation_m=0.0)])
    start_floor: int = 0
    checkpoints: list[Checkpoint] = Field(default_factory=list)
    uwb_anchors: list[UwbAnchor] = Field(default_factory=list)
    floor_plans: list[FloorPlan] = Field(default_factory=list)

    _base_dir: Path = PrivateAttr(default_factory=Path.cwd)

    # -- validation across fields -------------------------------------------------------
    @model_validator(mode="after")
    def _resolve(self, info: ValidationInfo) -> IncidentConfig:
        base = (info.context or {}).get("base_dir") if info is not None else None
        if base is not None:
            self._base_dir = Path(base)
        problems: list[str] = []
        self._resolve_floors(problems)
        numbers = {f.number for f in self.floors}
        if self.start_floor not in numbers:
            problems.append(f"start_floor: floor {self.start_floor} is not configured; floors: {sorted(numbers)}")
        seen: dict[str, int] = {}
        for i, cp in enumerate(self.checkpoints):
            if cp.name in seen:
                problems.append(f"checkpoints[{i}].name: {cp.name!r} is used twice (also checkpoints[{seen[cp.name]}])")
            seen.setdefault(cp.name, i)
            problems += [f"checkpoints[{i}].{p}" for p in self._resolve_checkpoint(cp)]
        ids: dict[str, int] = {}
        for i, a in enumerate(self.uwb_anchors):
            if a.id in ids:
                problems.append(f"uwb_anchors[{i}].id: {a.id!r} is used twice (also uwb_anchors[{ids[a.id]}])")
            ids.setdefault(a.id, i)
            if a.floor is not None and a.floor not in numbers:
                problems.append(f"uwb_anchors[{i}].floor: floor {a.floor} is not configured; floors: {sorted(numbers)}")
        for i, plan in enumerate(self.floor_plans):
            problems += [f"floor_plans[{i}].{p}" for p in self._resolve_plan(plan)]
        if problems:
            raise PydanticCustomError("incident", "{problems}", {"problems": "; ".join(problems)})
        return self

    def _resolve_floors(self, problems: list[str]) -> None:
        if not self.floors:
            problems.append("floors: at least one floor is needed")
            return
        first: dict[int, int] = {}
        for i, f in enumerate(self.floors):
            if f.number in first:
                problems.append(f"floors[{i}].number: floor {f.number} is configured twice (also floors[{first[f.number]}])")
            first.setdefault(f.number, i)
            if f.elevation_m is None:
                f.elevation_m = f.number * self.floor_height_m
            if f.name is None:
                f.name = "Ground floor" if f.number == 0 else f"Floor {f.number}"
        order = sorted(range(len(self.floors)), key=lambda i: self.floors[i].number)
        for a, b in zip(order, order[1:]):
            fa, fb = self.floors[a], self.floors[b]
            if fa.number != fb.number and not fb.elevation_m > fa.elevation_m:
                problems.append(f"floors[{b}].elevation_m: {fb.elevation_m} m for floor {fb.number} is not above "
                                f"{fa.elevation_m} m of floor {fa.number} (elevations must rise with the number)")
        self.floors = [self.floors[i] for i in order]

    def _resolve_checkpoint(self, cp: Checkpoint) -> list[str]:
        problems = []
        if cp.floor not in {f.number for f in self.floors}:
            problems.append(f"floor: floor {cp.floor} is not configured; floors: {[f.number for f in self.floors]}")
        if cp.lat is not None:
            x, y, _ = self.to_enu(cp.lat, cp.lon)
            if cp.x is not None and math.hypot(x - cp.x, y - cp.y) > POSITION_AGREEMENT_M:
                problems.append(f"x, y: ({cp.x}, {cp.y}) m disagrees with lat, lon ({cp.lat}, {cp.lon}), which is "
                                f"({x:.3f}, {y:.3f}) m from the origin")
            cp.x, cp.y = x, y
        else:
            cp.lat, cp.lon, _ = self.to_geodetic(cp.x, cp.y)
        return problems

    def _resolve_plan(self, plan: FloorPlan) -> list[str]:
        if plan.floor not in {f.number for f in self.floors}:
            return [f"floor: floor {plan.floor} is not configured; floors: {[f.number for f in self.floors]}"]
        path = Path(plan.image).expanduser()
        plan._path = path if path.is_absolute() else (self._base_dir / path).resolve()
        plan._size = tuple(plan.size_px) if plan.size_px is not None else None
        if not plan._path.is_file():
            plan._available, plan._problem = False, f"image {plan._path} not found"
        else:
            try:
                size = _image_size(plan._path)
            except Exception as e:  # a corrupt or unsupported image: the plan is unavailable, the config still loads
                plan._available, plan._problem = False, f"image {plan._path} unreadable: {e}"
            else:
                if plan.size_px is not None and tuple(plan.size_px) != size:
                    return [f"size_px: {list(plan.size_px)} but {plan._path.name} is {size[0]} x {size[1]} pixels"]
                plan._available, plan._size = True, size
        g = plan.georeference
        try:
            if g.is_cal:
                if plan._size is None:
                    why = "image size unknown (give size_px), so the .cal centre cannot be placed"
                    plan._problem = f"{plan._problem}; {why}" if plan._problem else why
                    return []
                plan._matrix = self._cal_matrix(g, plan._size)
            else:
                plan._matrix = self._control_point_matrix(g.control_points)
        except ValueError as e:
            return [f"georeference: {e}"]
        return []

    def _cal_matrix(self, g: Georeference, size: tuple[int, int]) -> np.ndarray:
        xc, yc, _ = self.to_enu(g.centre_lat, g.centre_lon)
        s, phi = g.metres_per_pixel, math.radians(-g.rotation_deg)
        c, sn = math.cos(phi), math.sin(phi)
        a = np.array([[s * c, s * sn], [s * sn, -s * c]])  # d[x, y] / d[u, v], from the docstring's equations
        centre = np.array([size[0] / 2.0, size[1] / 2.0])
        return np.column_stack([a, np.array([xc, yc]) - a @ centre])

    def _control_point_matrix(self, points: list[ControlPoint]) -> np.ndarray:
        uv = np.array([[p.u, p.v] for p in points], dtype=np.float64)
        xy = np.array([[p.x, p.y] if p.x is not None else self.to_enu(p.lat, p.lon)[:2] for p in points], dtype=np.float64)
        if len(points) == 2:
            # similarity with v flipped: x + iy = alpha (u - iv) + beta
            w = uv[:, 0] - 1j * uv[:, 1]
            z = xy[:, 0] + 1j * xy[:, 1]
            if abs(w[1] - w[0]) < 1e-9 or abs(z[1] - z[0]) < 1e-9:
                raise ValueError("the two control points must differ in pixels and in position")
            alpha = (z[1] - z[0]) / (w[1] - w[0])
            beta = z[0] - alpha * w[0]
            return np.array([[alpha.real, alpha.imag, beta.real], [alpha.imag, -alpha.real, beta.imag]])
        design = np.column_stack([uv, np.ones(len(points))])
        if np.linalg.matrix_rank(design, tol=1e-6 * max(1.0, np.abs(uv).max())) < 3:
            raise ValueError("control points are collinear in the image")
        sol, *_ = np.linalg.lstsq(design, xy, rcond=None)
        m = sol.T
        if abs(np.linalg.det(m[:, :2])) < 1e-12:
            raise ValueError("control points give a degenerate map (their positions are collinear)")
        return m

    # -- frames -------------------------------------------------------------------------
    def to_enu(self, lat, lon, alt=None):
        """WGS-84 (deg, deg, m; ``alt`` default the origin's height) -> local ENU (x, y, z) m."""
        o = self.origin
        x, y, z = pymap3d.geodetic2enu(lat, lon, o.alt_m if alt is None else alt, o.lat, o.lon, o.alt_m)
        return _scalar_or_array(x), _scalar_or_array(y), _scalar_or_array(z)

    def to_geodetic(self, x, y, z=0.0):
        """Local ENU (m) -> WGS-84 (lat deg, lon deg, ellipsoidal height m)."""
        o = self.origin
        lat, lon, alt = pymap3d.enu2geodetic(x, y, z, o.lat, o.lon, o.alt_m)
        return _scalar_or_array(lat), _scalar_or_array(lon), _scalar_or_array(alt)

    def elevations(self) -> dict[int, float]:
        """Configured elevation (m) of each floor number: a prior for the floor tracker
        (``pdr.floors.FloorElevations(cfg.elevations())``)."""
        return {f.number: float(f.elevation_m) for f in self.floors}

    def floor(self, number: int) -> Floor:
        for f in self.floors:
            if f.number == number:
                return f
        raise ValueError(f"floor {number} is not configured; floors: {[f.number for f in self.floors]}")

    # -- checkpoints --------------------------------------------------------------------
    def checkpoint(self, name: str) -> Checkpoint:
        for cp in self.checkpoints:
            if cp.name == name:
                return cp
        known = ", ".join(cp.name for cp in self.checkpoints) or "none"
        raise UnknownCheckpointError(f"incident {self.id!r} has no checkpoint {name!r}; known: {known}")

    def add_checkpoint(self, name: str, *, floor: int, x: float | None = None, y: float | None = None,
                       lat: float | None = None, lon: float | None = None, sigma_m: float = 0.5,
                       note: str | None = None, replace: bool = False) -> Checkpoint:
        """Add (or with ``replace`` overwrite) a checkpoint; positions as in the config file."""
        cp = Checkpoint(name=name, floor=floor, x=x, y=y, lat=lat, lon=lon, sigma_m=sigma_m, note=note)
        problems = self._resolve_checkpoint(cp)
        if problems:
            raise ValueError(f"checkpoint {name!r}: " + "; ".join(problems))
        existing = [i for i, c in enumerate(self.checkpoints) if c.name == name]
        if existing and not replace:
            raise ValueError(f"checkpoint {name!r} exists already (pass replace=True to move it)")
        if existing:
            self.checkpoints[existing[0]] = cp
        else:
            self.checkpoints.append(cp)
        return cp

    # -- plans --------------------------------------------------------------------------
    def floor_plan(self, floor: int, fallback: bool = False) -> FloorPlan | None:
        """The plan of ``floor``; with ``fallback``, when it has no available image, the available
        plan of the nearest floor (buildings keep their outline; the IPIN museum's .cal gives
        one geometry for all its floors)."""
        own = next((p for p in self.floor_plans if p.floor == floor), None)
        if own is not None and (own.available or not fallback):
            return own
        if not fallback:
            return None
        usable = [p for p in self.floor_plans if p.available and p.georeferenced]
        return min(usable, key=lambda p: (abs(p.floor - floor), p.floor)) if usable else own


def _scalar_or_array(v):
    return float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=np.float64)


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image header (Pillow opens lazily: no pixels are decoded)."""
    from PIL import Image

    with Image.open(path) as im:
        return int(im.size[0]), int(im.size[1])


def plan_pixel_to_enu(plan: FloorPlan, u, v):
    """Image pixel ``(u, v)`` (right, down from the top-left corner) -> local ENU ``(x, y)`` m."""
    m = plan.matrix
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    x = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    y = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    return _scalar_or_array(x), _scalar_or_array(y)


def enu_to_plan_pixel(plan: FloorPlan, x, y):
    """Local ENU ``(x, y)`` m -> image pixel ``(u, v)`` (the inverse of :func:`plan_pixel_to_enu`)."""
    m = plan.matrix
    inv = np.linalg.inv(m[:, :2])
    dx = np.asarray(x, dtype=np.float64) - m[0, 2]
    dy = np.asarray(y, dtype=np.float64) - m[1, 2]
    return _scalar_or_array(inv[0, 0] * dx + inv[0, 1] * dy), _scalar_or_array(inv[1, 0] * dx + inv[1, 1] * dy)


# ------------------------------------------------------------------------------------------
# Loading
# ------------------------------------------------------------------------------------------
def _describe(exc: ValidationError) -> str:
    parts = []
    for e in exc.errors(include_url=False):
        where = error_location(e["loc"])
        msg = e["msg"]
        if e["type"] not in ("incident", "missing") and not isinstance(e.get("input"), (dict, list)):
            msg += f" (got {e.get('input')!r})"
        parts.append(f"{where}: {msg}" if where else msg)
    return "; ".join(parts)


def incident_from_dict(data: Any, base_dir: str | Path | None = None, source: str | Path = "<config>") -> IncidentConfig:
    """Validate an already parsed configuration; relative image paths resolve against ``base_dir``."""
    if not isinstance(data, dict):
        raise IncidentConfigError(source, f"the top level must be a table/object, got {type(data).__name__}")
    try:
        return IncidentConfig.model_validate(data, context={"base_dir": Path(base_dir) if base_dir else Path.cwd()})
    except ValidationError as e:
        raise IncidentConfigError(source, _describe(e)) from None


def load_incident(path: str | Path) -> IncidentConfig:
    """Read an incident configuration (``.json``, or ``.toml``)."""
    path = Path(path)
    if not path.is_file():
        raise IncidentConfigError(path, "file not found" if not path.exists() else "not a file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise IncidentConfigError(path, f"cannot read: {e}") from None
    try:
        data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
    except json.JSONDecodeError as e:
        raise IncidentConfigError(path, f"not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except tomllib.TOMLDecodeError as e:
        raise IncidentConfigError(path, f"not valid TOML: {e}") from None
    return incident_from_dict(data, base_dir=path.resolve().parent, source=path)


def default_incident() -> IncidentConfig:
    """The demo incident: the IPIN 2023 museum in Nuremberg (``deploy/incidents/ipin-museum.json``)."""
    return load_incident(DEFAULT_INCIDENT_PATH)
