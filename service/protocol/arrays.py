"""Sample arrays on the wire: msgpack ``bin`` of little-endian float64, read-only numpy in Python."""
from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BeforeValidator,
    Field,
    PlainSerializer,
    ValidationInfo,
    WithJsonSchema,
)
from pydantic_core import PydanticCustomError

from service.protocol.keys import ID_PATTERN


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
