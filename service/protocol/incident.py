"""An incident's configuration: where the building is, its floors, checkpoints, anchors, plans.

Loaded from JSON (or TOML) by :func:`load_incident`; every problem becomes an
:class:`IncidentConfigError` naming the file, the field path (``floors[2].elevation_m``) and
what is wrong. The navigation frame is local ENU (x East, y North, z Up, metres) on the tangent
plane at ``origin``; conversions go through pymap3d on the WGS-84 ellipsoid.

Floor plans and their georeference: :mod:`service.protocol.floorplan`.
"""
from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path
from typing import Any

import pymap3d
from pydantic import (
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    model_validator,
)
from pydantic_core import PydanticCustomError

from service.protocol.floorplan import (  # noqa: F401  (re-exported: the config's plan types)
    ControlPoint,
    FloorPlan,
    Georeference,
    _Config,
    _scalar_or_array,
    enu_to_plan_pixel,
    plan_pixel_to_enu,
    resolve_plan,
)
from service.protocol.wire import ID_PATTERN, error_location

DEFAULT_INCIDENT_PATH = Path(__file__).resolve().parents[2] / "deploy" / "incidents" / "ipin-museum.json"
DEFAULT_FLOOR_HEIGHT_M = 3.0
POSITION_AGREEMENT_M = 0.05  # x, y and lat, lon given together must agree this well

# Bounds of a configuration: whatever a file says, loading it costs bounded time and memory and
# every number in it is one the service can compute with.
MAX_CONFIG_BYTES = 8 * 1024 * 1024  # a config file (plans are separate image files)
MAX_DEPTH = 32  # nesting of arrays and tables (the schema needs 6)
MAX_FLOORS = 256  # floors of a building (basements included)
MAX_CHECKPOINTS = 10_000
MAX_ANCHORS = 4096
MAX_ROSTER = 4096
MAX_EXTENT_M = 100_000.0  # m from the origin: nothing of one incident is further
MAX_ELEVATION_M = 10_000.0  # m, |elevation| of floors and anchors, |alt| of the origin
DEFAULT_EXTENT_M = 5_000.0  # m: a fix further from the origin than the incident's extent_m is refused
MAX_PROBLEM_CHARS = 1000  # an error's one line is cut here
MAX_PROBLEMS = 8  # problems listed in one error (the rest counted)


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


class Origin(_Config):
    """The ENU origin: WGS-84 latitude, longitude (deg) and ellipsoidal height (m)."""

    lat: float = Field(ge=-90.0, le=90.0)
    lon: float = Field(ge=-180.0, le=180.0)
    alt_m: float = Field(0.0, ge=-MAX_ELEVATION_M, le=MAX_ELEVATION_M)


class Floor(_Config):
    """A floor: its integer number, a name people use, and its elevation (m, any common datum;
    default ``number * floor_height_m``)."""

    number: int = Field(ge=-MAX_FLOORS, le=MAX_FLOORS)
    name: str | None = Field(None, max_length=256)
    elevation_m: float | None = Field(None, ge=-MAX_ELEVATION_M, le=MAX_ELEVATION_M)


class Checkpoint(_Config):
    """A named point an operator can place a responder at (a :class:`service.protocol.wire.Fix` with
    ``source="checkpoint"`` and ``name``). Give ``x, y`` (ENU, m) or ``lat, lon`` (deg); after
    loading both are filled. ``sigma_m`` is the 1-sigma horizontal uncertainty."""

    name: str = Field(min_length=1, max_length=128)
    x: float | None = Field(None, ge=-MAX_EXTENT_M, le=MAX_EXTENT_M)
    y: float | None = Field(None, ge=-MAX_EXTENT_M, le=MAX_EXTENT_M)
    lat: float | None = Field(None, ge=-90.0, le=90.0)
    lon: float | None = Field(None, ge=-180.0, le=180.0)
    floor: int
    sigma_m: float = Field(0.5, gt=0.0, le=1000.0)
    note: str | None = Field(None, max_length=4096)

    @model_validator(mode="after")
    def _position_given(self) -> Checkpoint:
        _point_given(self, "a checkpoint")
        return self


def _point_given(point, what: str) -> None:
    if (point.x is None) != (point.y is None):
        raise PydanticCustomError("position", "give x and y together")
    if (point.lat is None) != (point.lon is None):
        raise PydanticCustomError("position", "give lat and lon together")
    if point.x is None and point.lat is None:
        raise PydanticCustomError("position", f"{what} needs x, y (local ENU, m) or lat, lon (deg)")


class UwbAnchor(_Config):
    """A surveyed UWB anchor. Ranges to it are 3D: the service takes the anchor's height and the
    tag's (the responder's floor elevation + ``uwb_tag_height_m``) to get the horizontal distance.

    Config: ``{"id": "A1", "x": 12.5, "y": -3.0, "z": 2.4, "floor": 0}``.
    """

    id: str = Field(pattern=ID_PATTERN, description="the id UWB fixes name in their 'anchor' field")
    x: float = Field(ge=-MAX_EXTENT_M, le=MAX_EXTENT_M, description="m, local ENU east of the incident origin")
    y: float = Field(ge=-MAX_EXTENT_M, le=MAX_EXTENT_M, description="m, local ENU north of the incident origin")
    z: float = Field(0.0, ge=-MAX_ELEVATION_M, le=MAX_ELEVATION_M,
                     description="m, height above the incident origin's altitude (the datum of floors' elevation_m)")
    floor: int | None = Field(None, description="the floor it is mounted on (informative)")


MAX_BEACONS = 512  # a building's beacons and a crew's dropped ones; bounded like every list that reaches the core


class Beacon(_Config):
    """A radio beacon (BLE) at a known place: surveyed, or dropped by a crew (a breadcrumb).

    ``id`` is what a scan names it by (the MAC address the wearable hears, e.g.
    ``BE:AC:20:23:00:02``, or ``uuid:major:minor``). Give ``x, y`` (ENU, m) or ``lat, lon``
    (deg); after loading both are filled. ``tx_power_dbm`` is its RSSI at 1 m when known (an
    iBeacon's "measured power", or calibrated: ``firetrack eval ble``); ``sigma_m`` the 1-sigma
    of its position (a surveyed one: decimetres; a dropped one: the responder's uncertainty).

    Config: ``{"id": "BE:AC:20:23:00:02", "lat": 49.46129708, "lon": 11.11152175, "floor": -2,
    "tx_power_dbm": -62}``.
    """

    id: str = Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9:._\-]+$",
                    description="what scans name it by: its MAC address, or uuid:major:minor")
    name: str | None = Field(None, max_length=128, description="a name people use (e.g. the survey's BLE3)")
    x: float | None = Field(None, description="m, local ENU east of the incident origin")
    y: float | None = Field(None, description="m, local ENU north of the incident origin")
    lat: float | None = Field(None, ge=-90.0, le=90.0)
    lon: float | None = Field(None, ge=-180.0, le=180.0)
    floor: int
    height_m: float = Field(1.0, ge=0.0, le=10.0, description="m above its floor")
    tx_power_dbm: float | None = Field(None, ge=-120.0, le=20.0, description="dBm, RSSI at 1 m (None: the fusion's default)")
    sigma_m: float = Field(0.5, gt=0.0, le=100.0, description="m, 1-sigma of its position")
    note: str | None = None

    @model_validator(mode="after")
    def _position_given(self) -> Beacon:
        _point_given(self, "a beacon")
        return self


class Member(_Config):
    """A responder expected at the incident: the roster that accountability (PAR) is counted
    against. ``id`` is the responder id their wearable publishes under."""

    id: str = Field(pattern=ID_PATTERN, description="the responder id of their wearable")
    name: str | None = Field(None, max_length=256, description="how people call them")
    team: str | None = Field(None, max_length=256, description="crew or company, e.g. 'Engine 1'")
    role: str | None = Field(None, max_length=256, description="e.g. 'officer', 'nozzle', 'search', 'safety'")


def _duplicates(field: str, attr: str, items: list) -> list[str]:
    """``field[i].attr: 'x' is used twice (also field[j])`` for every repeated value."""
    first: dict[str, int] = {}
    out = []
    for i, item in enumerate(items):
        v = getattr(item, attr)
        if v in first:
            out.append(f"{field}[{i}].{attr}: {v!r} is used twice (also {field}[{first[v]}])")
        first.setdefault(v, i)
    return out


class IncidentConfig(_Config):
    """Everything the service and console know about the place of an incident."""

    id: str = Field("demo", pattern=ID_PATTERN)
    name: str = Field("", max_length=256)
    notes: str | list[str] | None = Field(None, max_length=65_536)
    origin: Origin
    declination_deg: float = Field(0.0, ge=-180.0, le=180.0, description="magnetic declination, East positive")
    field_inclination_deg: float | None = Field(None, ge=-90.0, le=90.0, description="magnetic dip (down positive), e.g. from the WMM; lets the compass reject fields with the wrong dip")
    field_norm_ut: float | None = Field(None, gt=0.0, le=1000.0, description="magnetic field strength (µT), e.g. from the WMM")
    floor_height_m: float = Field(DEFAULT_FLOOR_HEIGHT_M, gt=0.0, le=100.0, description="default floor spacing (m)")
    floors: list[Floor] = Field(default_factory=lambda: [Floor(number=0, name="Ground floor", elevation_m=0.0)],
                                max_length=MAX_FLOORS)
    start_floor: int = 0
    extent_m: float = Field(DEFAULT_EXTENT_M, gt=0.0, le=MAX_EXTENT_M,
                            description="m from the origin that the incident covers: checkpoints and anchors are "
                                        "within it, an operator's fix beyond it is refused")
    checkpoints: list[Checkpoint] = Field(default_factory=list, max_length=MAX_CHECKPOINTS)
    uwb_anchors: list[UwbAnchor] = Field(default_factory=list, max_length=MAX_ANCHORS)
    beacons: list[Beacon] = Field(default_factory=list, max_length=MAX_BEACONS,
                                  description="BLE beacons at known places (scans of them are 'ble' fixes)")
    roster: list[Member] = Field(default_factory=list, max_length=MAX_ROSTER,
                                 description="the responders expected, with team and role")
    uwb_tag_height_m: float = Field(1.2, ge=0.0, le=3.0, description="m, height of a responder's UWB tag above the "
                                                                       "floor (shoulder or helmet)")
    floor_plans: list[FloorPlan] = Field(default_factory=list, max_length=MAX_FLOORS)

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
        problems += _duplicates("checkpoints", "name", self.checkpoints)
        for i, cp in enumerate(self.checkpoints):
            problems += [f"checkpoints[{i}].{p}" for p in self.resolve_point(cp)]
        problems += _duplicates("beacons", "id", self.beacons)
        for i, b in enumerate(self.beacons):
            problems += [f"beacons[{i}].{p}" for p in self.resolve_point(b)]
        problems += _duplicates("uwb_anchors", "id", self.uwb_anchors)
        for i, a in enumerate(self.uwb_anchors):
            if not self.within_extent(a.x, a.y):
                problems.append(f"uwb_anchors[{i}]: ({a.x}, {a.y}) m is outside the incident's extent_m "
                                f"({self.extent_m:g} m from the origin)")
            if a.floor is not None and a.floor not in numbers:
                problems.append(f"uwb_anchors[{i}].floor: floor {a.floor} is not configured; floors: {sorted(numbers)}")
        problems += _duplicates("roster", "id", self.roster)
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

    def resolve_point(self, cp: Checkpoint | Beacon) -> list[str]:
        """A point's floor checked, and its x, y and lat, lon both filled (checkpoints, beacons)."""
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
        if not self.within_extent(cp.x, cp.y):
            problems.append(f"x, y: ({cp.x:.1f}, {cp.y:.1f}) m is outside the incident's extent_m "
                            f"({self.extent_m:g} m from the origin)")
        return problems

    def within_extent(self, x: float, y: float) -> bool:
        """Is the ENU point (m) within ``extent_m`` of the origin (and finite)?"""
        return bool(math.isfinite(x) and math.isfinite(y) and math.hypot(x, y) <= self.extent_m)

    def _resolve_plan(self, plan: FloorPlan) -> list[str]:
        if plan.floor not in {f.number for f in self.floors}:
            return [f"floor: floor {plan.floor} is not configured; floors: {[f.number for f in self.floors]}"]
        return resolve_plan(plan, self._base_dir, self.to_enu)

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
        problems = self.resolve_point(cp)
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

    def beacon(self, beacon_id: str) -> Beacon | None:
        """The beacon a scan names (ids compare without case: MAC addresses come in both)."""
        wanted = beacon_id.upper()
        return next((b for b in self.beacons if b.id.upper() == wanted), None)

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


# ------------------------------------------------------------------------------------------
# Loading
# ------------------------------------------------------------------------------------------
def _describe(exc: ValidationError) -> str:
    """The validation errors on one line: at most :data:`MAX_PROBLEMS` of them, each input
    echoed in at most 60 characters, the whole cut at :data:`MAX_PROBLEM_CHARS`."""
    parts = []
    errors = exc.errors(include_url=False)
    for e in errors[:MAX_PROBLEMS]:
        where = error_location(e["loc"])
        msg = e["msg"]
        if e["type"] not in ("incident", "missing") and not isinstance(e.get("input"), (dict, list)):
            msg += f" (got {_short(repr(e.get('input')), 60)})"
        parts.append(f"{where}: {msg}" if where else msg)
    if len(errors) > MAX_PROBLEMS:
        parts.append(f"and {len(errors) - MAX_PROBLEMS} more problems")
    return _short(" ".join("; ".join(parts).split()), MAX_PROBLEM_CHARS)


_LIST_LIMITS = {"floors": MAX_FLOORS, "checkpoints": MAX_CHECKPOINTS, "uwb_anchors": MAX_ANCHORS,
                "roster": MAX_ROSTER, "floor_plans": MAX_FLOORS}


def _short(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 25] + f"... ({len(text):,} characters)"


def nesting_depth(text: str, toml: bool = False) -> int:
    """How deep arrays and tables nest in JSON (or TOML) ``text``, strings (and TOML comments)
    left out; found without parsing (the parsers recurse, and a file 100,000 deep would blow
    their stack). TOML's dotted keys nest too: their depth is checked on the parsed data."""
    strip = r'"(?:[^"\\\n]|\\.)*"' + (r"|'[^'\n]*'|#[^\n]*" if toml else "")
    depth = deepest = 0
    for m in re.finditer(r"[\[\]{}]", re.sub(strip, "", text)):
        depth += 1 if m.group() in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


def _data_depth(data: Any, limit: int) -> int:
    """The depth of parsed data, counted without recursion and no further than ``limit`` + 1."""
    deepest, todo = 0, [(data, 0)]
    while todo and deepest <= limit:
        item, d = todo.pop()
        if isinstance(item, dict):
            item = list(item.values())
        if isinstance(item, list):
            deepest = max(deepest, d + 1)
            todo += [(v, d + 1) for v in item if isinstance(v, (dict, list))]
    return deepest


def incident_from_dict(data: Any, base_dir: str | Path | None = None, source: str | Path = "<config>") -> IncidentConfig:
    """Validate an already parsed configuration; relative image paths resolve against ``base_dir``."""
    if not isinstance(data, dict):
        raise IncidentConfigError(source, f"the top level must be a table/object, got {type(data).__name__}")
    if _data_depth(data, MAX_DEPTH) > MAX_DEPTH:
        raise IncidentConfigError(source, f"nested more than {MAX_DEPTH} levels deep: not an incident configuration")
    for name, limit in _LIST_LIMITS.items():  # before validation, which would look at every item first
        if isinstance(data.get(name), list) and len(data[name]) > limit:
            raise IncidentConfigError(source, f"{name}: {len(data[name]):,} entries; at most {limit:,}")
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
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise IncidentConfigError(path, f"{size:,} bytes: a configuration is at most {MAX_CONFIG_BYTES:,}")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise IncidentConfigError(path, _short(f"cannot read: {e}", MAX_PROBLEM_CHARS)) from None
    toml = path.suffix.lower() == ".toml"
    depth = nesting_depth(text, toml)
    if depth > MAX_DEPTH:
        raise IncidentConfigError(path, f"arrays and tables nested {depth:,} deep; a configuration nests at most "
                                        f"{MAX_DEPTH}")
    try:
        data = tomllib.loads(text) if toml else json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as e:
        raise IncidentConfigError(path, f"not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except tomllib.TOMLDecodeError as e:
        raise IncidentConfigError(path, _short(f"not valid TOML: {e}", MAX_PROBLEM_CHARS)) from None
    except (RecursionError, ValueError) as e:  # the depth check above should have caught it
        raise IncidentConfigError(path, _short(f"cannot be read: {e}", MAX_PROBLEM_CHARS)) from None
    return incident_from_dict(data, base_dir=path.resolve().parent, source=path)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number a configuration may hold")


def default_incident() -> IncidentConfig:
    """The demo incident: the IPIN 2023 museum in Nuremberg (``deploy/incidents/ipin-museum.json``)."""
    return load_incident(DEFAULT_INCIDENT_PATH)
