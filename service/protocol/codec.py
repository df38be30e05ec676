"""Encoding and decoding of wire messages, the track reply, and the JSON Schema for other languages."""
from __future__ import annotations

import math
import re
from typing import Any, Literal

import msgpack
import msgspec
import numpy as np
from pydantic import ValidationError

from service.protocol import actions, fixes  # noqa: F401  (register the fix sources and the action kinds before any decode)
from service.protocol.keys import ID_PATTERN, KEY_ROOT
from service.protocol.schema import (
    CARRY_POSITIONS,
    MAX_PAYLOAD_BYTES,
    MAX_RATE_HZ,
    MAX_SAMPLES,
    MESSAGE_TYPES,
    MIN_RATE_HZ,
    REJECT_REASONS,
    SCHEMA_VERSION,
    WireError,
    ImuBatch,
    WireMessage,
    fix_json_schema,
)


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


def decode(payload: bytes, expect: type | None = None, max_bytes: int = MAX_PAYLOAD_BYTES,
           fast: bool = True) -> WireMessage:
    """msgpack bytes -> a validated message; raises :class:`WireError` and nothing else on bad
    input. ``expect`` (a message class) rejects any other kind with reason ``"kind"``.

    A frame (``expect=ImuBatch``) first tries :func:`_fast_imu`, which accepts only what the
    schema certainly accepts and hands everything else to the schema's own validation, so a
    rejected frame gets the same reason and detail either way."""
    if fast and expect is ImuBatch and type(payload) is bytes and len(payload) <= max_bytes:
        fast = _fast_imu(payload)
        if fast is not None:
            return fast
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
    if expect is not None and not issubclass(cls, expect) and not issubclass(expect, cls):
        raise WireError("kind", f"expected {getattr(expect, 'KIND', expect)!s}, got {kind}")
    try:
        return cls.model_validate(data, strict=True, context={"wire": True})
    except ValidationError as e:
        raise _wire_error(e, kind) from None


# ---------------------------------------------------------------------------- the frames' fast path
class _ImuWire(msgspec.Struct, forbid_unknown_fields=True):
    """The msgpack layout of :class:`ImuBatch` for msgspec's compiled decoder: types only; the
    constraints are checked in :func:`_fast_imu`. A frame with keys of its own takes the slow
    path (the schema ignores them, but their values must still be valid msgpack for it)."""

    v: int
    kind: str
    responder: str
    device: str
    seq: int
    t: bytes
    acc: bytes
    gyr: bytes
    mag: bytes | None = None
    pressure_t: bytes | None = None
    pressure: bytes | None = None
    carry: Literal[CARRY_POSITIONS] = "unknown"  # type: ignore[valid-type]
    utc_offset: float | None = None
    boot: str | None = None


_IMU_DECODER = msgspec.msgpack.Decoder(_ImuWire)
_ID_FULL = re.compile(ID_PATTERN.removeprefix("^").removesuffix("$"))  # fullmatch: no trailing newline, as the schema
_IMU_FIELDS = frozenset(ImuBatch.model_fields)
_LO_DT, _HI_DT = 1.0 / MAX_RATE_HZ, 1.0 / MIN_RATE_HZ


def _fast_imu(payload: bytes) -> ImuBatch | None:
    """A frame the schema certainly accepts, as an :class:`ImuBatch`, in a few microseconds; None
    for anything else (the caller then runs the full validation, which gives the reason).

    Conservative by construction: msgspec's typed decoder checks the msgpack and the field
    types (strict: no bool for an int, bin for every array, a known carry; a key of its own
    sends the frame to the slow path), then every constraint of the schema is checked on the
    common case only: every number finite, every sample interval within the rate limits (the
    schema's median rule is needed only otherwise). A key given twice keeps its last value in both decoders.
    The arrays are read-only views of one copy of the payload's bytes."""
    try:
        m = _IMU_DECODER.decode(payload)
    except Exception:  # DecodeError, ValidationError, UnicodeDecodeError, ...: the schema will say what
        return None
    if (not 1 <= m.v <= SCHEMA_VERSION or m.kind != "imu" or m.seq < 0
            or not 1 <= len(m.device) <= 128 or _ID_FULL.fullmatch(m.responder) is None):
        return None
    nb = len(m.t)
    n = nb >> 3
    if nb & 7 or not 1 <= n <= MAX_SAMPLES or len(m.acc) != 24 * n or len(m.gyr) != 24 * n:
        return None
    parts = [m.t, m.acc, m.gyr]
    has_mag = m.mag is not None
    if has_mag:
        if len(m.mag) != 24 * n:
            return None
        parts.append(m.mag)
    if (m.pressure is None) != (m.pressure_t is None):
        return None
    k = 0
    if m.pressure is not None:
        kb = len(m.pressure_t)
        k = kb >> 3
        if kb & 7 or len(m.pressure) != kb or k > MAX_SAMPLES:
            return None
        if k:
            parts += [m.pressure_t, m.pressure]
    if m.utc_offset is not None and not m.utc_offset - m.utc_offset == 0.0:
        return None
    if m.boot is not None and not 1 <= len(m.boot) <= 64:
        return None
    values = np.frombuffer(b"".join(parts), dtype="<f8")
    if not math.isfinite(values @ values):  # NaN or ±inf anywhere makes it so (and |x| > 1e154: the slow path decides)
        return None
    t = values[:n]
    if n > 1 and not _times_plausible(t, _LO_DT, _HI_DT):
        return None
    at = 10 * n if has_mag else 7 * n  # t, acc, gyr[, mag], then pressure_t and pressure
    pt = p = None
    if k:
        pt, p = values[at:at + k], values[at + k:at + 2 * k]
        if k > 1 and not _times_plausible(pt, 0.0, math.inf):
            return None
    out = object.__new__(ImuBatch)
    object.__setattr__(out, "__dict__", {
        "responder": m.responder, "device": m.device, "seq": m.seq, "t": t, "acc": values[n:4 * n].reshape(n, 3),
        "gyr": values[4 * n:7 * n].reshape(n, 3), "mag": values[7 * n:10 * n].reshape(n, 3) if has_mag else None,
        "pressure_t": pt, "pressure": p, "carry": m.carry,
        "utc_offset": None if m.utc_offset is None else float(m.utc_offset), "boot": m.boot,
    })
    object.__setattr__(out, "__pydantic_fields_set__", _IMU_FIELDS)
    object.__setattr__(out, "__pydantic_extra__", None)
    object.__setattr__(out, "__pydantic_private__", None)
    return out


def _times_plausible(t: np.ndarray, lo: float, hi: float) -> bool:
    """Every interval of ``t`` strictly positive and within [lo, hi] (Python for a frame, numpy for more)."""
    if t.shape[0] <= 32:
        v = t.tolist()
        prev = v[0]
        for x in v[1:]:
            d = x - prev
            if not (d > 0.0 and lo <= d <= hi):
                return False
            prev = x
        return True
    d = t[1:] - t[:-1]
    return bool(d.min() > 0.0 and d.min() >= lo and d.max() <= hi)


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
        if kind == "fix":  # the common fields, and one of the registered sources (discriminated by "source")
            union = fix_json_schema()
            defs.update(union.pop("$defs", {}))
            s["oneOf"] = union.get("oneOf", [union])
            if "discriminator" in union:
                s["discriminator"] = union["discriminator"]
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
                "command": "Command (par: roll call; evacuate), console/service -> wearable",
                "ack": "Ack of a command, wearable -> service",
                "op": "OperatorAction, console/operator -> service; the id chunk is the actor (its certificate)",
                "audit": "Audit, service -> consoles: the verdict on an action or a flagged checkpoint fix",
                "access": "Access, recorded by the service: the access policy in force from then on",
            },
        },
        "x-limits": {"max_payload_bytes": MAX_PAYLOAD_BYTES, "max_samples": MAX_SAMPLES,
                     "min_rate_hz": MIN_RATE_HZ, "max_rate_hz": MAX_RATE_HZ},
        "x-reject-reasons": list(REJECT_REASONS),
    }
