"""The incident core's state as bytes, and back, without letting the bytes run code.

A snapshot is a pickle (protocol 5) of the core's own objects: responders, frame gates, motion
models, estimators (whose gtsam graphs restart from their newest pose, see
:meth:`service.fusion.graph.TrackFusion.__getstate__`), numpy arrays and counters. Pickle can
name any importable callable, so :func:`loads` reads with an unpickler that only resolves
the classes of this project's pure layers (``pdr``, ``service.core``, ``service.fusion``,
``service.protocol``: no functions) and a fixed list of numpy and standard-library
reconstructors (:data:`ALLOWED_GLOBALS`), and refuses everything else with
:class:`SnapshotError`. A snapshot in a recording from elsewhere therefore cannot call
``os.system`` when it is reprocessed.

Framing: ``MAGIC`` + the pickle. A snapshot is only read by the same version of the code that
wrote it, or a compatible one; one that cannot be read is an error the caller handles (the
service then replays the recording from its start, :mod:`service.review.resume`).
"""
from __future__ import annotations

import io
import pickle

MAGIC = b"firetrack-core-snapshot/1\n"

# what a snapshot may name: classes (never functions) of this project's pure layers, and a few
# named reconstructors of numpy and the standard library
PROJECT_PREFIXES = ("pdr.", "service.core.", "service.fusion.", "service.protocol.")
ALLOWED_GLOBALS = frozenset({
    ("builtins", n) for n in ("set", "frozenset", "dict", "list", "tuple", "slice", "complex", "range", "bytearray",
                              "float", "int", "bool", "str", "bytes", "object")
} | {
    ("collections", "deque"), ("collections", "OrderedDict"), ("collections", "Counter"),
    ("collections", "defaultdict"), ("copyreg", "_reconstructor"), ("copyreg", "__newobj__"), ("_codecs", "encode"),
    ("numpy", "dtype"), ("numpy", "ndarray"), ("numpy", "float64"), ("numpy", "int64"), ("numpy", "bool_"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
})


class SnapshotError(ValueError):
    """Bytes that are not a snapshot this code can read (wrong framing, a forbidden name, damage)."""


class _Unpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in ALLOWED_GLOBALS or (module.startswith("numpy.dtypes") and name.endswith("DType")):
            return super().find_class(module, name)
        if module.startswith(PROJECT_PREFIXES) or module in ("pdr", "service"):
            obj = super().find_class(module, name)
            if isinstance(obj, type):
                return obj
            raise SnapshotError(f"a snapshot may name classes only, and {module}.{name} is not one")
        raise SnapshotError(f"a snapshot may not name {module}.{name} (only this project's classes, numpy arrays "
                            "and the standard containers)")


def dumps(state) -> bytes:
    return MAGIC + pickle.dumps(state, protocol=5)


def loads(blob: bytes):
    if not isinstance(blob, (bytes, bytearray, memoryview)) or bytes(blob[:len(MAGIC)]) != MAGIC:
        raise SnapshotError("not a firetrack core snapshot (its first bytes are not the snapshot header)")
    try:
        return _Unpickler(io.BytesIO(bytes(blob[len(MAGIC):]))).load()
    except SnapshotError:
        raise
    except Exception as e:  # damaged or written by an incompatible version
        raise SnapshotError(f"the snapshot cannot be read: {type(e).__name__}: {e}") from None
