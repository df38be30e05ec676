"""The wire messages: one pydantic model per kind (imu, fix, pose, status), defined once.

See :mod:`service.protocol.wire` for the encoding; :mod:`service.protocol.codec` encodes and
decodes them.
"""
from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator
from pydantic_core import PydanticCustomError

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

CARRY_POSITIONS = ("handheld", "pocket", "bag", "armband", "waist", "chest", "foot", "unknown")


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
    :class:`service.core.gate.FrameGate` re-orders and detects loss with it). ``boot`` names
    that start: a wearable that restarts, or a second device for the same responder, sends a
    new one, and the service continues the responder's track as a new stream of it (without
    ``boot``, a new stream is recognised by a changed ``device``, a sequence number that goes
    back while time goes on, or a long silence). Pressure samples,
    on the same device clock, travel with the batch whose time span contains them, so their
    times may precede ``t[0]`` (they belong after the previous batch's end).
    """

    KIND: ClassVar[str] = "imu"
    responder: Id
    device: str = Field(min_length=1, max_length=128, description="the sensor's id (one clock, one seq counter)")
    seq: int = Field(ge=0, description="frame number per device, +1 per frame")
    boot: str | None = Field(None, min_length=1, max_length=64, description=(
        "names the publisher's start (a random id per start of the wearable): (device, boot) is one stream "
        "of seq numbers; a new boot continues the responder's track as a new stream"))
    t: Seconds
    acc: Acc
    gyr: Gyr
    mag: Mag | None = None
    pressure_t: Seconds | None = None
    pressure: Hpa | None = None
    carry: Literal["handheld", "pocket", "bag", "armband", "waist", "chest", "foot", "unknown"] = Field(
        "unknown", description="where the device is worn; chooses the motion model (foot: the ZUPT INS)")
    utc_offset: Finite | None = Field(
        None, description="s: UTC (Unix seconds) minus the device clock, the wearable's latest estimate; "
                          "a time t on the device clock is t + utc_offset in UTC")

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


class Fix(WireMessage):
    """An absolute observation of a responder (wearable, operator, anchor or another system ->
    service): the fields every fix carries. Each source is a subclass (a discriminated union
    on ``source``, see :mod:`service.protocol.fixes`): ``Fix(source="gnss", ...)`` and
    :meth:`decode` build the subclass of the source, and a new source is one subclass and one
    :func:`service.protocol.fixes.register_fix_message` call.

    ``t`` is the time of the observation: on the responder's device clock
    (``time_base="device"``, what the wearable itself sends), or Unix seconds UTC
    (``time_base="utc"``, what an outside system has: a GNSS receiver, a UWB server, an
    operator's console); the service converts UTC with the device-clock offset each wearable
    publishes (``ImuBatch.utc_offset``). ``operator`` names who or what sent the fix.
    """

    KIND: ClassVar[str] = "fix"
    SOURCE: ClassVar[str] = ""
    responder: Id
    t: Finite = Field(description="s: time of the observation, on the clock time_base names")
    source: str = Field(description="what observed the responder: checkpoint, gnss, uwb, ...")
    time_base: Literal["device", "utc"] = Field("device", description="the clock of t: the responder's device clock, "
                                                                      "or Unix seconds UTC")
    operator: str | None = Field(None, max_length=128, description="who or what sent the fix")

    def __new__(cls, *args, **data):
        if cls is Fix:  # Fix(source=..., ...) builds the subclass registered for the source
            try:
                cls = fix_message_class(data.get("source"))
            except ValueError:
                validate_fix(data)  # raises the union's ValidationError, which names the source
        return super().__new__(cls)

    @classmethod
    def model_validate(cls, obj, *args, **kw):
        if cls is Fix:
            return validate_fix(obj, *args, **kw)
        return super().model_validate(obj, *args, **kw)

    @model_validator(mode="before")
    @classmethod
    def _no_foreign_fields(cls, data: Any) -> Any:
        if cls is not Fix and isinstance(data, dict):
            foreign = foreign_fields(cls, data)
            if foreign:
                own = sorted(set(cls.model_fields) - set(Fix.model_fields))
                raise PydanticCustomError("fix_fields", f"{', '.join(foreign)}: not part of a {cls.SOURCE} fix "
                                                        f"(it takes {', '.join(own)})")
        return data

    @classmethod
    def checkpoint(cls, responder: str, t: float, **fields) -> Fix:
        """A checkpoint fix: ``name`` or ``x``, ``y``; optional ``floor``, ``sigma``."""
        return Fix(responder=responder, t=t, source="checkpoint", **fields)

    @classmethod
    def gnss(cls, responder: str, t: float, **fields) -> Fix:
        """A GNSS fix: ``lat``, ``lon``, ``accuracy``."""
        return Fix(responder=responder, t=t, source="gnss", **fields)

    @classmethod
    def uwb(cls, responder: str, t: float, **fields) -> Fix:
        """A UWB range: ``anchor``, ``range``, ``sigma``."""
        return Fix(responder=responder, t=t, source="uwb", **fields)


FIX_MESSAGES: dict[str, type[Fix]] = {}  # source -> model (service.protocol.fixes registers the built-in ones)
_fix_adapter: TypeAdapter | None = None


def register_fix_message(model: type[Fix]) -> type[Fix]:
    """Make ``model`` (a :class:`Fix` subclass with ``source: Literal[name]``) a fix source."""
    global _fix_adapter
    FIX_MESSAGES[model.SOURCE] = model
    models = tuple(FIX_MESSAGES.values())
    union = models[0] if len(models) == 1 else Annotated[Union[models], Field(discriminator="source")]  # noqa: UP007
    _fix_adapter = TypeAdapter(union)
    return model


def fix_message_class(source: Any) -> type[Fix]:
    try:
        return FIX_MESSAGES[source]
    except (KeyError, TypeError):
        raise ValueError(f"unknown fix source {source!r}; known: {', '.join(FIX_MESSAGES)}") from None


def validate_fix(obj: Any, *, strict: bool | None = None, context: Any = None, **kw) -> Fix:
    """The union's validation: the model of ``obj["source"]``; a pydantic ValidationError naming
    ``source`` for an unknown one."""
    return _fix_adapter.validate_python(obj, strict=strict, context=context)


def fix_json_schema() -> dict:
    """The JSON Schema of the union of every registered fix source."""
    return _fix_adapter.json_schema(mode="validation", ref_template="#/$defs/{model}")


def foreign_fields(model: type[Fix], data: dict) -> list[str]:
    """Keys of ``data`` that belong to another registered source (not to ``model``)."""
    own = set(model.model_fields)
    others = set().union(*(m.model_fields for m in FIX_MESSAGES.values())) - own
    return sorted(k for k in data if k in others and data[k] is not None)


class Pose(WireMessage):
    """Where the service believes a responder is (service -> console).

    ``x``, ``y`` local ENU (m) at the incident origin and the same point as ``lat``/``lon``;
    ``heading_deg`` is a compass bearing, clockwise from North, in [0, 360). ``seq`` is the
    :class:`ImuBatch` seq this pose reflects; ``published_at`` the service's wall clock (unix s)
    when it published, so a receiver measures latency as ``now - published_at``.
    """

    KIND: ClassVar[str] = "pose"
    responder: Id
    t: Finite = Field(description="s, device clock: the time of the step (or fix) this pose is at")
    x: Finite = Field(description="m, local ENU east of the incident origin")
    y: Finite = Field(description="m, local ENU north of the incident origin")
    floor: int = Field(description="floor number of the incident config (0 ground, negative below)")
    lat: Finite = Field(ge=-90.0, le=90.0, description="deg, WGS-84 latitude of (x, y)")
    lon: Finite = Field(ge=-180.0, le=180.0, description="deg, WGS-84 longitude of (x, y)")
    heading_deg: Finite = Field(ge=0.0, lt=360.0, description="deg, compass bearing of travel, clockwise from North")
    cov: Cov2
    steps: int = Field(ge=0, description="steps (strides) counted since the track started")
    source: Literal["pdr", "fused"] = Field(description="pdr: dead reckoning only so far; fused: a fix was applied")
    seq: int = Field(ge=0, description="the ImuBatch seq this pose reflects")
    published_at: Finite = Field(description="s, Unix time UTC of the service's clock when it published")
    utc: Finite | None = Field(None, description="s, Unix time UTC of t (device time + the wearable's clock offset)")

    @model_validator(mode="after")
    def _covariance(self) -> Pose:
        c = self.cov
        if c[0, 0] < 0 or c[1, 1] < 0 or abs(c[0, 1] - c[1, 0]) > 1e-9 * max(1.0, abs(c[0, 1])):
            raise PydanticCustomError("covariance", f"cov must be symmetric with non-negative variances, got {c.tolist()}")
        return self


class Status(WireMessage):
    """Health of one responder's stream and pipeline (service -> console), about once a second.

    ``t`` is the device time of the last sample, ``last_heard`` the service's wall clock (unix
    s) of the last frame; ``frames`` accepted frames, ``gaps`` discontinuities (lost frames,
    time jumps, new streams), ``lost`` the frames known lost in them and ``gap_s`` the seconds
    they span, ``rejected`` counts per reject reason. ``device``, ``boot`` and ``seq`` say what
    the service has taken of the current stream (the newest frame it released): a wearable
    reads them as its acknowledgement, and ``missing`` as a request to resend.
    """

    KIND: ClassVar[str] = "status"
    responder: Id
    t: Finite = Field(description="s, device clock: the newest sample the service has taken")
    motion: Literal["walking", "running", "crawling", "stairs", "still", "no_motion"] = Field(
        description="the motion state as of the newest frame (running, crawling, stairs: boot-mounted units)")
    motion_since: Finite = Field(description="s, device clock: when the motion state began")
    alarms: list[str] = Field(default_factory=list, description='e.g. "man_down", "lost_contact", "rejected_frames"')
    alarms_since: dict[str, float] = Field(default_factory=dict, description="per alarm: s, Unix time UTC of the "
                                                                             "service's clock when it began")
    rejected: dict[str, int] = Field(default_factory=dict, description="frames and fixes turned away, by reason "
                                                                       "(fixes as fix_<reason>)")
    frames: int = Field(0, ge=0, description="frames accepted")
    gaps: int = Field(0, ge=0, description="discontinuities: runs of lost frames and device-time jumps")
    last_heard: Finite = Field(description="s, Unix time UTC of the service's clock when the last frame arrived")
    steps: int = Field(0, ge=0, description="steps (strides) counted")
    fixes: dict[str, int] = Field(default_factory=dict, description="fixes applied and queued (waiting for a step); "
                                                                    "the rejected ones are in rejected")
    beacons_heard: dict[str, float] = Field(default_factory=dict, max_length=512,
                                            description="per beacon of the incident: s, device clock of the newest "
                                                        "ble scan of the responder that heard it")
    utc_offset: Finite | None = Field(None, description="s: UTC minus the device clock, as the wearable last said")
    lost: int = Field(0, ge=0, description="frames known lost (sequence numbers that never arrived)")
    gap_s: Finite = Field(0.0, ge=0.0, description="s of the responder's time not covered by frames, over all gaps")
    streams: int = Field(1, ge=0, description="streams (wearable starts, devices) the track has taken so far")
    device: str | None = Field(None, max_length=128, description="device of the current stream")
    boot: str | None = Field(None, max_length=64, description="boot id of the current stream (ImuBatch.boot)")
    seq: int | None = Field(None, ge=0, description="seq of the newest frame the service released from the current "
                                                    "stream: everything up to it is taken or counted in lost")
    missing: list[Annotated[int, Field(ge=0)]] | None = Field(
        None, min_length=2, max_length=2, description="[first, last] seq of the current stream that the service is "
                                                      "waiting for: the wearable resends them from its keep")
    last_fix: dict | None = Field(None, description="the last fix applied: source, and t (device s) it was for")
    first_heard: Finite | None = Field(None, description="s, Unix time UTC when the service first heard of the "
                                                         "responder (time in the building counts from here)")
    commands: dict[str, dict] = Field(default_factory=dict, description="per action (par, evacuate): the newest "
                                      "order's id, when it was issued (UTC s) and when it was acknowledged (or null)")
    man_down_at: Finite | None = Field(None, description="s, device clock: when man-down is (or will be) raised, "
                                       "present from the pre-alarm on (a phone asks its wearer then)")
    ok_at: Finite | None = Field(None, description="s, device clock: the wearer's latest answer \"I'm OK\" to the "
                                 "man-down prompt")
    lag_s: Finite | None = Field(None, ge=0.0, description="s: how much later than its quickest frame the newest "
                                                          "frame reached the service (queued in the network, the "
                                                          "router or a worker behind; service/core/lag.py)")


class Command(WireMessage):
    """An order to one responder's wearable (console or service -> wearable, ``.../command``).

    ``par``: a personnel accountability report, the roll call a commander starts; the
    responder confirms (the wearable acknowledges with an :class:`Ack`). ``evacuate``: leave the
    building now; the wearable alerts its wearer and acknowledges. The service receives the
    orders too, and says in ``Status.commands`` who has not answered.
    """

    KIND: ClassVar[str] = "command"
    responder: Id
    id: str = Field(min_length=1, max_length=64, description="the order's id; the acknowledgement repeats it")
    action: Literal["par", "evacuate"] = Field(description="par: roll call; evacuate: leave the building")
    issued_at: Finite = Field(description="s, Unix time UTC when the order was issued")
    issued_by: str | None = Field(None, max_length=128, description="who issued it (an operator's identity)")


class Ack(WireMessage):
    """A wearable's acknowledgement of a :class:`Command` (wearable -> service, ``.../ack``),
    or with ``action="ok"`` the wearer's answer "I'm OK" to the man-down prompt
    (``Status.man_down_at``): no order, ``t`` on the device clock, and the service's
    no-motion clock starts again from it (:mod:`service.core.alarms`)."""

    KIND: ClassVar[str] = "ack"
    responder: Id
    id: str = Field(min_length=1, max_length=64, description="the id of the order acknowledged (ok: the wearable's "
                                                             "name for the prompt answered)")
    action: Literal["par", "evacuate", "ok"] = Field(description="the kind of the command answered; ok: the man-down "
                                                                 "prompt")
    at: Finite = Field(description="s, Unix time UTC when the wearer acknowledged")
    t: Finite | None = Field(None, description="s, device clock (the frames' clock) when the wearer answered; "
                                               "required with ok")

    @model_validator(mode="after")
    def _ok_has_t(self) -> Ack:
        if self.action == "ok" and self.t is None:
            raise PydanticCustomError("schema", "t: an answer to the man-down prompt (ok) says when, on the device clock")
        return self


MESSAGE_TYPES: dict[str, type[WireMessage]] = {m.KIND: m for m in (ImuBatch, Fix, Pose, Status, Command, Ack)}
