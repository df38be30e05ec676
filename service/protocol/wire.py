"""The wire schema: every message that crosses zenoh, defined once for both sides.

Imported by the service, the wearable publisher, the simulator, the recorder and the console,
so it depends on numpy, pydantic and msgpack only (never gtsam or zenoh).

Encoding
--------
A message is ONE msgpack map keyed by field name, plus two envelope keys:

* ``"v"``: the schema's major version (:data:`SCHEMA_VERSION`). Additions that old readers may
  ignore (a new optional field) keep the version; readers ignore keys they do not know. A
  change that breaks readers bumps it, and a reader rejects versions newer than its own
  (reason ``"version"``).
* ``"kind"``: ``"imu"``, ``"fix"``, ``"pose"`` or ``"status"``.

Optional fields that are ``None`` are left out of the map; a reader treats an absent key and
``nil`` alike. Sample arrays travel as msgpack ``bin``: packed little-endian IEEE-754 float64,
row-major (C order), never as lists, so a reader in any language takes them as one slice of
bytes. Their lengths follow from ``n = len(t) = len(bin(t)) / 8``: ``acc``, ``gyr`` and
``mag`` are ``n*3`` float64 (x0 y0 z0 x1 y1 z1 ...), ``pressure`` has as many values as
``pressure_t``, and :class:`Pose` ``cov`` is 4 float64, the 2x2 covariance row-major
(``[c_xx, c_xy, c_yx, c_yy]``, m²). In Python the arrays are read-only numpy float64 views of
the received bytes, shapes ``(n,)`` / ``(n, 3)`` / ``(2, 2)``.

Decoding checks, in this order, and names the first failure with one of
:data:`REJECT_REASONS` (the service counts rejects by reason and logs the detail): size,
msgpack validity, map, version, kind, the pydantic schema, array shapes (byte lengths whole
multiples of 8 and consistent with ``n``; ``1 <= n <= MAX_SAMPLES``), finiteness of every
number, strictly increasing ``t`` within a batch, and a sample rate judged from the batch's
median interval within ``[MIN_RATE_HZ, MAX_RATE_HZ]``. The same invariants hold for a message
built in Python (they raise pydantic's ``ValidationError`` there).

Key expressions
---------------
``firetrack/{incident}/{responder}/{kind}`` (:func:`key`), ``kind`` one of :data:`KEY_KINDS`:
``imu``, ``fix`` (wearable/operator -> service), ``pose``, ``status`` (service -> console),
``track`` (the service's queryable of a responder's track), ``presence`` (liveliness token of a
connected wearable) and ``truth`` (ground truth from a replayed recording or the simulator,
for scoring). Incident and responder ids match ``[A-Za-z0-9_.-]{1,64}``, so they never contain
a key-expression separator or wildcard (``/``, ``*``, ``$``, ``#``, ``?``).
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterator
from typing import Annotated, Any, ClassVar, Literal

import msgpack
import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    ValidationError,
    ValidationInfo,
    WithJsonSchema,
    model_validator,
)
from pydantic_core import PydanticCustomError

SCHEMA_VERSION = 1

LOST_CONTACT_S = 10.0  # s: a responder not heard for this long is in lost contact (service and console agree)
MAX_PAYLOAD_BYTES = 1 << 20  # 1 MiB: far above a real frame (10 samples ~ 0.8 kB), far below harm
MAX_SAMPLES = 4096  # samples per ImuBatch (about 20 s at 200 Hz)
MIN_RATE_HZ = 5.0  # slowest plausible IMU rate (median interval 0.2 s)
MAX_RATE_HZ = 2000.0  # fastest plausible IMU rate (median interval 0.5 ms)

REJECT_REASONS = (
    "oversize", "msgpack", "not_a_map", "version", "kind", "schema", "shape", "nonfinite", "time_order", "rate",
)

CARRY_POSITIONS = ("handheld", "pocket", "bag", "armband", "waist", "foot", "unknown")
KEY_KINDS = ("imu", "fix", "pose", "status", "track", "presence", "truth")
KEY_ROOT = "firetrack"
ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
_ID_RE = re.compile(ID_PATTERN)


class WireError(ValueError):
    """A payload that is not a valid message. ``reason`` is one of :data:`REJECT_REASONS`
    (a counter name), ``detail`` says what and where (field, sample index)."""

    def __init__(self, reason: str, detail: str):
        if reason not in REJECT_REASONS:
            raise ValueError(f"unknown reject reason {reason!r}; known: {REJECT_REASONS}")
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# ------------------------------------------------------------------------------------------
# Sample arrays: bin on the wire, read-only float64 numpy arrays in Python
# ------------------------------------------------------------------------------------------
def _first_bad(mask: np.ndarray) -> str:
    """Where the first True of a (n,) or (n, k) mask is, as ``[i]`` or ``[i, j]``."""
    idx = np.argwhere(mask)[0]
    return "[" + ", ".join(str(int(i)) for i in idx) + "]"


def _as_array(value: Any, info: ValidationInfo, shape: tuple[int | None, ...]) -> np.ndarray:
    """Bytes from the wire or an array-like from Python -> read-only float64 array of ``shape``
    (``None`` = any length). On the wire (context ``wire=True``) only ``bin`` is accepted."""
    row = math.prod(s for s in shape if s is not None)
    if isinstance(value, (bytes, bytearray, memoryview)):
        nbytes = value.nbytes if isinstance(value, memoryview) else len(value)
        fixed = None not in shape
        if (nbytes != 8 * row) if fixed else (nbytes % (8 * row)):
            if fixed:
                raise PydanticCustomError("shape", "{nbytes} bytes, expected {want} ({row} float64)",
                                          {"nbytes": nbytes, "want": 8 * row, "row": row})
            unit = "float64 (8 bytes)" if row == 1 else f"row of {row} float64 ({8 * row} bytes)"
            raise PydanticCustomError("shape", "{nbytes} bytes is not a whole number of {unit}",
                                      {"nbytes": nbytes, "unit": unit})
        arr = np.frombuffer(value, dtype="<f8").reshape([-1 if s is None else s for s in shape])
    elif info.context and info.context.get("wire"):
        raise PydanticCustomError(
            "bin_expected", "arrays travel as msgpack bin (packed little-endian float64), got {type}",
            {"type": type(value).__name__})
    else:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise PydanticCustomError("array_type", "not a numeric array: {error}", {"error": str(e)}) from None
        if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
            want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
            raise PydanticCustomError("shape", "expected shape {want}, got {got}", {"want": want, "got": str(arr.shape)})
        arr = np.ascontiguousarray(arr)
    arr = arr.view()  # a read-only view; the caller's array stays writable
    arr.flags.writeable = False
    finite = np.isfinite(arr)
    if not finite.all():
        raise PydanticCustomError("nonfinite", "{value} at index {where}",
                                  {"value": str(arr[tuple(np.argwhere(~finite)[0])]), "where": _first_bad(~finite)})
    return arr


def _array_type(shape: tuple[int | None, ...], unit: str, what: str):
    count = {(None,): "n", (None, 3): "n*3", (2, 2): "4"}[shape]
    schema = {
        "type": "string", "format": "binary", "contentMediaType": "application/octet-stream",
        "description": f"{what} ({unit}). msgpack bin: {count} little-endian float64, row-major.",
        "x-firetrack-array": {"dtype": "<f8", "shape": ["n" if s is None else s for s in shape], "unit": unit},
    }
    return Annotated[
        np.ndarray,
        BeforeValidator(lambda v, info: _as_array(v, info, shape)),
        PlainSerializer(lambda a: a.tolist(), when_used="json"),
        WithJsonSchema(schema),
    ]


Seconds = _array_type((None,), "s", "sample times on the device clock")
Acc = _array_type((None, 3), "m/s^2", "accelerometer, device frame")
Gyr = _array_type((None, 3), "rad/s", "gyroscope, device frame")
Mag = _array_type((None, 3), "uT", "magnetometer, device frame")
Hpa = _array_type((None,), "hPa", "barometric pressure")
Cov2 = _array_type((2, 2), "m^2", "horizontal position covariance [[xx, xy], [yx, yy]] in local ENU")

Id = Annotated[str, Field(pattern=ID_PATTERN, description="incident/responder id: [A-Za-z0-9_.-]{1,64}")]
Finite = Annotated[float, Field(allow_inf_nan=False)]


# ------------------------------------------------------------------------------------------
# Messages
# ------------------------------------------------------------------------------------------
class WireMessage(BaseModel):
    """Base of every message: a kind, field-wise equality that understands numpy arrays."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True, extra="ignore", allow_inf_nan=False)
    KIND: ClassVar[str] = ""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for name in type(self).model_fields:
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
                        and a.shape == b.shape and np.array_equal(a, b)):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # arrays make messages unhashable

    def to_wire(self) -> dict[str, Any]:
        """The msgpack map (before packing): envelope keys, arrays as little-endian bytes."""
        d: dict[str, Any] = {"v": SCHEMA_VERSION, "kind": self.KIND}
        for name in type(self).model_fields:
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, np.ndarray):
                value = value.astype("<f8", copy=False).tobytes()
            d[name] = value
        return d


class ImuBatch(WireMessage):
    """A frame of raw IMU samples from one device of one responder (wearable -> service).

    ``seq`` counts frames per device from the publisher's start (the service's
    :class:`service.core.gate.FrameGate` re-orders and detects loss with it). Pressure samples,
    on the same device clock, travel with the batch whose time span contains them, so their
    times may precede ``t[0]`` (they belong after the previous batch's end).
    """

    KIND: ClassVar[str] = "imu"
    responder: Id
    device: str = Field(min_length=1, max_length=128, description="the sensor's id (one clock, one seq counter)")
    seq: int = Field(ge=0, description="frame number per device, +1 per frame")
    t: Seconds
    acc: Acc
    gyr: Gyr
    mag: Mag | None = None
    pressure_t: Seconds | None = None
    pressure: Hpa | None = None
    carry: Literal["handheld", "pocket", "bag", "armband", "waist", "foot", "unknown"] = "unknown"

    @model_validator(mode="after")
    def _consistent(self) -> ImuBatch:
        n = self.t.shape[0]
        if not 1 <= n <= MAX_SAMPLES:
            raise PydanticCustomError("shape", "t: a batch holds 1..{max} samples, got {n}", {"max": MAX_SAMPLES, "n": n})
        for name in ("acc", "gyr", "mag"):
            a = getattr(self, name)
            if a is not None and a.shape[0] != n:
                raise PydanticCustomError("shape", "{name}: {m} rows for {n} samples in t",
                                          {"name": name, "m": a.shape[0], "n": n})
        if (self.pressure is None) != (self.pressure_t is None):
            raise PydanticCustomError("shape", "pressure and pressure_t come together (one is missing)")
        if self.pressure is not None:
            m = self.pressure_t.shape[0]
            if self.pressure.shape[0] != m:
                raise PydanticCustomError("shape", "pressure: {k} values for {m} times in pressure_t",
                                          {"k": self.pressure.shape[0], "m": m})
            if m > MAX_SAMPLES:
                raise PydanticCustomError("shape", "pressure_t: at most {max} samples, got {m}", {"max": MAX_SAMPLES, "m": m})
        _check_increasing("t", self.t, rate=True)
        if self.pressure_t is not None:
            _check_increasing("pressure_t", self.pressure_t)
        if self.pressure_t is not None and self.pressure_t.shape[0] == 0:
            object.__setattr__(self, "pressure_t", None)  # one spelling of "no pressure in this batch"
            object.__setattr__(self, "pressure", None)
        return self

    @property
    def n(self) -> int:
        return int(self.t.shape[0])


def _check_increasing(name: str, t: np.ndarray, rate: bool = False) -> None:
    """Strictly increasing times; with ``rate``, also the median sample interval within
    [1/MAX_RATE_HZ, 1/MIN_RATE_HZ]. The median, not the mean, so that one dropped sample or
    one late timestamp does not condemn a batch."""
    if t.shape[0] < 2:
        return
    dt = np.diff(t)
    shortest = dt.min()
    if not shortest > 0:
        i = int(np.argmax(~(dt > 0))) + 1
        raise PydanticCustomError(  # pre-formatted: templates take no format specs
            "time_order", f"{name}[{i}] = {float(t[i])!r} s is not after {name}[{i - 1}] = {float(t[i - 1])!r} s "
                          "(times must strictly increase)")
    lo, hi = 1.0 / MAX_RATE_HZ, 1.0 / MIN_RATE_HZ
    if not rate or (shortest >= lo and dt.max() <= hi):  # common case: every interval plausible, no median
        return
    med = float(np.median(dt))
    if not lo <= med <= hi:
        raise PydanticCustomError(
            "rate", f"{name}: median sample interval {med:.6g} s is {1.0 / med:.4g} Hz, outside "
                    f"[{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz")


_FIX_FIELDS = {
    "checkpoint": {"x", "y", "floor", "name", "sigma"},
    "gnss": {"lat", "lon", "accuracy"},
    "uwb": {"anchor", "range", "sigma"},
}
_FIX_OPTIONAL = {"x", "y", "floor", "name", "sigma", "lat", "lon", "accuracy", "anchor", "range"}


class Fix(WireMessage):
    """An absolute observation of a responder (wearable, operator or anchor -> service).

    One class for the three sources, so a subscriber has one type to check and one ``expect``
    to pass to :func:`decode`; the validator below enforces each source's fields:

    * ``checkpoint``: the responder stands at a known point: ``name`` (a checkpoint of the
      incident) or ``x``, ``y`` (local ENU, m), optional ``floor`` and ``sigma`` (m, 1-sigma).
    * ``gnss``: ``lat``, ``lon`` (deg, WGS-84), ``accuracy`` (m, the receiver's 1-sigma radius).
    * ``uwb``: a range to anchor ``anchor`` (an id of the incident's anchors): ``range`` (m),
      ``sigma`` (m).

    ``t`` is on the responder's device clock. ``operator`` names who sent the fix. Build with
    ``Fix(source=..., ...)`` or the :meth:`checkpoint`, :meth:`gnss`, :meth:`uwb` shortcuts.
    """

    KIND: ClassVar[str] = "fix"
    responder: Id
    t: Finite
    source: Literal["checkpoint", "gnss", "uwb"]
    x: Finite | None = None
    y: Finite | None = None
    floor: int | None = None
    name: str | None = Field(None, min_length=1, max_length=128)
    lat: Finite | None = Field(None, ge=-90.0, le=90.0)
    lon: Finite | None = Field(None, ge=-180.0, le=180.0)
    accuracy: Finite | None = Field(None, gt=0.0)
    anchor: str | None = Field(None, min_length=1, max_length=128)
    range: Finite | None = Field(None, ge=0.0)
    sigma: Finite | None = Field(None, gt=0.0)
    operator: str | None = Field(None, max_length=128)

    @model_validator(mode="after")
    def _fields_of_source(self) -> Fix:
        own = _FIX_FIELDS[self.source]
        foreign = sorted(f for f in _FIX_OPTIONAL - own if getattr(self, f) is not None)
        if foreign:
            raise PydanticCustomError("fix_fields", f"{', '.join(foreign)}: not part of a {self.source} fix "
                                                    f"(it takes {', '.join(sorted(own))})")
        if self.source == "checkpoint":
            if (self.x is None) != (self.y is None):
                raise PydanticCustomError("fix_fields", "a checkpoint fix gives x and y together")
            if self.name is None and self.x is None:
                raise PydanticCustomError("fix_fields", "a checkpoint fix needs a checkpoint name or x and y")
        else:
            required = ("lat", "lon", "accuracy") if self.source == "gnss" else ("anchor", "range", "sigma")
            missing = [f for f in required if getattr(self, f) is None]
            if missing:
                raise PydanticCustomError("fix_fields", f"a {self.source} fix needs {', '.join(required)}; "
                                                        f"missing: {', '.join(missing)}")
        return self

    @classmethod
    def checkpoint(cls, responder: str, t: float, *, name: str | None = None, x: float | None = None,
                   y: float | None = None, floor: int | None = None, sigma: float | None = None,
                   operator: str | None = None) -> Fix:
        return cls(responder=responder, t=t, source="checkpoint", name=name, x=x, y=y, floor=floor, sigma=sigma,
                   operator=operator)

    @classmethod
    def gnss(cls, responder: str, t: float, *, lat: float, lon: float, accuracy: float,
             operator: str | None = None) -> Fix:
        return cls(responder=responder, t=t, source="gnss", lat=lat, lon=lon, accuracy=accuracy, operator=operator)

    @classmethod
    def uwb(cls, responder: str, t: float, *, anchor: str, range: float, sigma: float,
            operator: str | None = None) -> Fix:
        return cls(responder=responder, t=t, source="uwb", anchor=anchor, range=range, sigma=sigma, operator=operator)


class Pose(WireMessage):
    """Where the service believes a responder is (service -> console).

    ``x``, ``y`` local ENU (m) at the incident origin and the same point as ``lat``/``lon``;
    ``heading_deg`` is a compass bearing, clockwise from North, in [0, 360). ``seq`` is the
    :class:`ImuBatch` seq this pose reflects; ``published_at`` the service's wall clock (unix s)
    when it published, so a receiver measures latency as ``now - published_at``.
    """

    KIND: ClassVar[str] = "pose"
    responder: Id
    t: Finite
    x: Finite
    y: Finite
    floor: int
    lat: Finite = Field(ge=-90.0, le=90.0)
    lon: Finite = Field(ge=-180.0, le=180.0)
    heading_deg: Finite = Field(ge=0.0, lt=360.0)
    cov: Cov2
    steps: int = Field(ge=0)
    source: Literal["pdr", "fused"]
    seq: int = Field(ge=0)
    published_at: Finite

    @model_validator(mode="after")
    def _covariance(self) -> Pose:
        c = self.cov
        if c[0, 0] < 0 or c[1, 1] < 0 or abs(c[0, 1] - c[1, 0]) > 1e-9 * max(1.0, abs(c[0, 1])):
            raise PydanticCustomError("covariance", f"cov must be symmetric with non-negative variances, got {c.tolist()}")
        return self


class Status(WireMessage):
    """Health of one responder's stream and pipeline (service -> console), about once a second.

    ``t`` is the device time of the last sample, ``last_heard`` the service's wall clock (unix
    s) of the last frame; ``frames`` accepted frames, ``gaps`` discontinuities (lost frames or
    time jumps), ``rejected`` counts per reject reason.
    """

    KIND: ClassVar[str] = "status"
    responder: Id
    t: Finite
    motion: Literal["walking", "still", "no_motion"]
    motion_since: Finite
    alarms: list[str] = Field(default_factory=list, description='e.g. "man_down", "lost_contact", "rejected_frames"')
    rejected: dict[str, int] = Field(default_factory=dict)
    frames: int = Field(0, ge=0)
    gaps: int = Field(0, ge=0)
    last_heard: Finite
    steps: int = Field(0, ge=0)


MESSAGE_TYPES: dict[str, type[WireMessage]] = {m.KIND: m for m in (ImuBatch, Fix, Pose, Status)}


# ------------------------------------------------------------------------------------------
# Codec
# ------------------------------------------------------------------------------------------
def encode(msg: WireMessage) -> bytes:
    """One message -> msgpack bytes (see the module docstring for the layout)."""
    if not isinstance(msg, WireMessage):
        raise TypeError(f"encode takes a wire message ({', '.join(MESSAGE_TYPES)}), got {type(msg).__name__}")
    return msgpack.packb(msg.to_wire(), use_bin_type=True)


_REASON_OF_ERROR = {"shape": "shape", "nonfinite": "nonfinite", "finite_number": "nonfinite",
                    "time_order": "time_order", "rate": "rate"}


def error_location(loc: tuple) -> str:
    """A pydantic error location as a field path: ``floors[2].elevation_m``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _shown(error: dict) -> str:
    """`` (got 'x')`` for a short scalar input, so the log says what was sent."""
    value = error.get("input")
    if error["type"] in _REASON_OF_ERROR or isinstance(value, (bytes, list, dict)) or error["type"] == "missing":
        return ""
    text = repr(value)
    return f" (got {text if len(text) <= 40 else text[:37] + '...'})"


def _wire_error(exc: ValidationError, kind: str) -> WireError:
    """The first error by REJECT_REASONS order names the reason; all errors go into the detail."""
    errors = exc.errors(include_url=False)
    reasons = [_REASON_OF_ERROR.get(e["type"], "schema") for e in errors]
    reason = min(reasons, key=REJECT_REASONS.index)
    parts = [f"{error_location(e['loc'])}: {e['msg']}{_shown(e)}" if e["loc"] else e["msg"] for e in errors]
    return WireError(reason, f"{kind}: " + "; ".join(parts))


def decode(payload: bytes, expect: type | None = None, max_bytes: int = MAX_PAYLOAD_BYTES) -> WireMessage:
    """msgpack bytes -> a validated message; raises :class:`WireError` and nothing else on bad
    input. ``expect`` (a message class) rejects any other kind with reason ``"kind"``."""
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise WireError("msgpack", f"payload is a {type(payload).__name__}, expected bytes")
    size = payload.nbytes if isinstance(payload, memoryview) else len(payload)
    if size > max_bytes:
        raise WireError("oversize", f"{size} bytes exceeds the limit of {max_bytes}")
    try:
        data = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as e:  # msgpack raises several types (ExtraData, FormatError, StackError, ValueError...)
        raise WireError("msgpack", f"{type(e).__name__}: {e or 'not valid msgpack'}") from None
    if not isinstance(data, dict):
        raise WireError("not_a_map", f"top level is a {type(data).__name__}, expected a map")
    v = data.get("v")
    if type(v) is not int:
        raise WireError("version", f"'v' must be an integer schema version, got {v!r}" if "v" in data else "no 'v' field")
    if v > SCHEMA_VERSION:
        raise WireError("version", f"schema version {v} is newer than this reader's {SCHEMA_VERSION}")
    if v < 1:
        raise WireError("version", f"schema version {v} does not exist")
    kind = data.get("kind")
    cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise WireError("kind", f"unknown kind {kind!r}; known: {', '.join(MESSAGE_TYPES)}")
    if expect is not None and cls is not expect:
        raise WireError("kind", f"expected {getattr(expect, 'KIND', expect)!s}, got {kind}")
    try:
        return cls.model_validate(data, strict=True, context={"wire": True})
    except ValidationError as e:
        raise _wire_error(e, kind) from None


# ------------------------------------------------------------------------------------------
# Recording -> frames
# ------------------------------------------------------------------------------------------
def imu_batches_from_arrays(responder: str, device: str, t, acc, gyr, mag=None, pressure_t=None, pressure=None,
                            carry: str = "unknown", per_batch: int = 10, seq0: int = 0) -> Iterator[ImuBatch]:
    """Cut a recording into frames of ``per_batch`` samples, seq ``seq0, seq0+1, ...``.

    Pressure sample ``p`` goes with the batch ``k`` whose span contains it:
    ``end_{k-1} < p_t <= end_k`` (``end_k`` the time of batch k's last IMU sample); the first
    batch also takes every earlier one, the last batch every later one, so no sample is lost.
    """
    if per_batch < 1:
        raise ValueError(f"per_batch must be at least 1, got {per_batch}")
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    n = t.shape[0]
    if n == 0:
        raise ValueError("t is empty: there is nothing to cut into frames")
    arrays = {}
    for name, a in (("acc", acc), ("gyr", gyr), ("mag", mag)):
        if a is None:
            continue
        a = np.ascontiguousarray(a, dtype=np.float64)
        if a.shape != (n, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({n}, 3) to match t")
        arrays[name] = a
    if (pressure_t is None) != (pressure is None):
        raise ValueError("pressure_t and pressure come together")
    starts = np.arange(0, n, per_batch)
    stops = np.minimum(starts + per_batch, n)
    if pressure is not None:
        pt = np.ascontiguousarray(pressure_t, dtype=np.float64).reshape(-1)
        p = np.ascontiguousarray(pressure, dtype=np.float64).reshape(-1)
        if p.shape != pt.shape:
            raise ValueError(f"pressure has {p.shape[0]} values for {pt.shape[0]} times")
        if pt.size > 1 and not (np.diff(pt) > 0).all():
            i = int(np.argmax(~(np.diff(pt) > 0))) + 1
            raise ValueError(f"pressure_t must strictly increase: pressure_t[{i}] = {pt[i]!r} follows {pt[i - 1]!r}")
        owner = np.minimum(np.searchsorted(t[stops - 1], pt, side="left"), starts.size - 1)
        bounds = np.searchsorted(owner, np.arange(starts.size + 1), side="left")
    for k, (a, b) in enumerate(zip(starts, stops)):
        kw = {name: arr[a:b] for name, arr in arrays.items()}
        if pressure is not None:
            lo, hi = bounds[k], bounds[k + 1]
            if hi > lo:
                kw["pressure_t"], kw["pressure"] = pt[lo:hi], p[lo:hi]
        yield ImuBatch(responder=responder, device=device, seq=seq0 + k, t=t[a:b], carry=carry, **kw)


# ------------------------------------------------------------------------------------------
# Key expressions
# ------------------------------------------------------------------------------------------
def _check_id(what: str, value: str) -> str:
    if not isinstance(value, str) or not _ID_RE.match(value):
        raise ValueError(f"{what} id {value!r} must match [A-Za-z0-9_.-]{{1,64}} "
                         "(no '/', '*', '$', '#', '?', spaces or empty)")
    return value


def _check_kind(kind: str) -> str:
    if kind not in KEY_KINDS:
        raise ValueError(f"unknown key kind {kind!r}; known: {', '.join(KEY_KINDS)}")
    return kind


def key(incident: str, responder: str, kind: str) -> str:
    """``firetrack/{incident}/{responder}/{kind}``: where one responder's messages of a kind go."""
    return f"{KEY_ROOT}/{_check_id('incident', incident)}/{_check_id('responder', responder)}/{_check_kind(kind)}"


def key_all(incident: str, kind: str) -> str:
    """``firetrack/{incident}/*/{kind}``: subscribe to a kind for every responder of an incident."""
    return f"{KEY_ROOT}/{_check_id('incident', incident)}/*/{_check_kind(kind)}"


def parse_key(k: str) -> tuple[str, str, str]:
    """``firetrack/{incident}/{responder}/{kind}`` -> ``(incident, responder, kind)``; ValueError
    for anything else (wrong root, wrong number of chunks, bad id, unknown kind)."""
    parts = str(k).split("/")
    if len(parts) != 4 or parts[0] != KEY_ROOT:
        raise ValueError(f"key {k!r} is not {KEY_ROOT}/{{incident}}/{{responder}}/{{kind}}")
    _, incident, responder, kind = parts
    return _check_id("incident", incident), _check_id("responder", responder), _check_kind(kind)


def is_valid_id(value: str) -> bool:
    return isinstance(value, str) and _ID_RE.match(value) is not None


# ------------------------------------------------------------------------------------------
# JSON Schema (for readers in other languages)
# ------------------------------------------------------------------------------------------
TRACK_FIELDS = ("t", "x", "y", "floor", "heading")


def encode_track(responder: str, track: dict, smoothed: bool) -> bytes:
    """The reply of a ``.../track`` query: a msgpack map with ``responder``, ``smoothed`` and
    the arrays t (s), x, y (m, ENU), floor, heading (ENU yaw, rad; NaN when unknown) as
    little-endian float64 bins, like every other array on the wire."""
    d = {"v": SCHEMA_VERSION, "kind": "track", "responder": responder, "smoothed": bool(smoothed)}
    for k in TRACK_FIELDS:
        d[k] = np.asarray(track[k], "<f8").tobytes()
    return msgpack.packb(d, use_bin_type=True)


def decode_track(payload: bytes) -> dict:
    """:func:`encode_track` back to numpy arrays."""
    d = msgpack.unpackb(payload, raw=False)
    out = {k: d[k] for k in ("responder", "smoothed")}
    for k in TRACK_FIELDS:
        out[k] = np.frombuffer(d[k], "<f8")
    return out


def json_schema() -> dict:
    """One JSON Schema document: a definition per message kind (with the envelope keys), the
    key-expression layout, the array encoding and the limits a reader enforces."""
    defs: dict[str, Any] = {}
    for kind, cls in MESSAGE_TYPES.items():
        s = cls.model_json_schema(mode="validation", ref_template="#/$defs/{model}")
        defs.update(s.pop("$defs", {}))
        s["properties"] = {
            "v": {"const": SCHEMA_VERSION, "type": "integer", "description": "schema major version"},
            "kind": {"const": kind, "type": "string"},
            **s["properties"],
        }
        s["required"] = ["v", "kind", *s.get("required", [])]
        s["description"] = " ".join((cls.__doc__ or "").split())
        defs[kind] = s
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": f"https://firetrack.invalid/wire/v{SCHEMA_VERSION}.json",
        "title": f"firetrack wire messages, schema version {SCHEMA_VERSION}",
        "description": "Each message is ONE msgpack map keyed by field name with envelope keys 'v' and 'kind'. "
                       "Optional fields that are null are omitted; readers treat absent and nil alike and "
                       "ignore unknown keys. A reader rejects a newer 'v'.",
        "oneOf": [{"$ref": f"#/$defs/{kind}"} for kind in MESSAGE_TYPES],
        "$defs": defs,
        "x-array-encoding": {
            "wire_type": "msgpack bin",
            "dtype": "IEEE-754 float64, little-endian",
            "order": "row-major: x0 y0 z0 x1 y1 z1 ...",
            "lengths": "n = len(t) = bytes(t)/8; acc, gyr, mag: n*3 values; pressure: as many as pressure_t; "
                       "pose cov: 4 values [xx, xy, yx, yy] (m^2)",
            "never": "lists",
        },
        "x-key-expressions": {
            "layout": f"{KEY_ROOT}/{{incident}}/{{responder}}/{{kind}}",
            "wildcard": f"{KEY_ROOT}/{{incident}}/*/{{kind}}",
            "id_pattern": ID_PATTERN,
            "kinds": {
                "imu": "ImuBatch, wearable -> service",
                "fix": "Fix (checkpoint, gnss, uwb), wearable/operator -> service",
                "pose": "Pose, service -> console",
                "status": "Status, service -> console",
                "track": "queryable of the service: a responder's track",
                "presence": "liveliness token of a connected wearable",
                "truth": "ground truth from a replayed recording or the simulator (for scoring)",
            },
        },
        "x-limits": {"max_payload_bytes": MAX_PAYLOAD_BYTES, "max_samples": MAX_SAMPLES,
                     "min_rate_hz": MIN_RATE_HZ, "max_rate_hz": MAX_RATE_HZ},
        "x-reject-reasons": list(REJECT_REASONS),
    }
