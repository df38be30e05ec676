"""The wire messages: one pydantic model per kind (imu, fix, pose, status), defined once.

See :mod:`service.protocol.wire` for the encoding; :mod:`service.protocol.codec` encodes and
decodes them.
"""
from __future__ import annotations

from collections.abc import Iterator
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from pdr.frames import frame_bounds
from service.protocol.arrays import Acc, Cov2, Finite, Gyr, Hpa, Id, Mag, Seconds

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


class WireError(ValueError):
    """A payload that is not a valid message. ``reason`` is one of :data:`REJECT_REASONS`
    (a counter name), ``detail`` says what and where (field, sample index)."""

    def __init__(self, reason: str, detail: str):
        if reason not in REJECT_REASONS:
            raise ValueError(f"unknown reject reason {reason!r}; known: {REJECT_REASONS}")
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


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
    pt = p = None
    if pressure is not None:
        pt = np.ascontiguousarray(pressure_t, dtype=np.float64).reshape(-1)
        p = np.ascontiguousarray(pressure, dtype=np.float64).reshape(-1)
        if p.shape != pt.shape:
            raise ValueError(f"pressure has {p.shape[0]} values for {pt.shape[0]} times")
        if pt.size > 1 and not (np.diff(pt) > 0).all():
            i = int(np.argmax(~(np.diff(pt) > 0))) + 1
            raise ValueError(f"pressure_t must strictly increase: pressure_t[{i}] = {pt[i]!r} follows {pt[i - 1]!r}")
    starts, stops, p_lo, p_hi = frame_bounds(t, per_batch, pt)
    for k, (a, b) in enumerate(zip(starts, stops)):
        kw = {name: arr[a:b] for name, arr in arrays.items()}
        if pressure is not None:
            lo, hi = p_lo[k], p_hi[k]
            if hi > lo:
                kw["pressure_t"], kw["pressure"] = pt[lo:hi], p[lo:hi]
        yield ImuBatch(responder=responder, device=device, seq=seq0 + k, t=t[a:b], carry=carry, **kw)
