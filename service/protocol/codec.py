"""Encoding and decoding of wire messages, the track reply, and the JSON Schema for other languages."""
from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
from pydantic import ValidationError

from service.protocol import actions, fixes  # noqa: F401  (register the fix sources and the action kinds before any decode)
from service.protocol.keys import ID_PATTERN, KEY_ROOT
from service.protocol.schema import (
    MAX_PAYLOAD_BYTES,
    MAX_RATE_HZ,
    MAX_SAMPLES,
    MESSAGE_TYPES,
    MIN_RATE_HZ,
    REJECT_REASONS,
    SCHEMA_VERSION,
    WireError,
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
    if expect is not None and not issubclass(cls, expect) and not issubclass(expect, cls):
        raise WireError("kind", f"expected {getattr(expect, 'KIND', expect)!s}, got {kind}")
    try:
        return cls.model_validate(data, strict=True, context={"wire": True})
    except ValidationError as e:
        raise _wire_error(e, kind) from None


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
