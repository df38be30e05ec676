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

**Incremental.** Each responder is a pickle of its own (:func:`dump_responder`), kept by the
core until the responder changes, so a snapshot costs the responders that changed since the
last one, not every responder the incident holds (a flood that brought hundreds of ids that
then fell silent must not stall the worker for a tenth of a second every few seconds, issue
20). What responders share is named in their pickles, not held (:class:`SharedRefs`): the
core's fleet of handheld pipelines (:class:`pdr.fleet.PdrFleet`), its rows (a floor
tracker's arrays are views of them), its members, and the settings every tracker shares; the whole-core
pickle holds these once and the responders' pickles as bytes. Restoring resolves the names
against the restored objects, so the views are views of the restored fleet again.

Framing: ``MAGIC`` + the pickle. A snapshot is only read by the same version of the code that
wrote it, or a compatible one; one that cannot be read is an error the caller handles (the
service then replays the recording from its start, :mod:`service.review.resume`).
"""
from __future__ import annotations

import copyreg
import dataclasses
import io
import pickle

import numpy as np

MAGIC = b"firetrack-core-snapshot/4\n"  # 4: one PDR engine (pdr.fleet_rows)

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
    def __init__(self, file, resolve=None):
        super().__init__(file)
        self._resolve = resolve

    def find_class(self, module: str, name: str):
        if (module, name) == (__name__, "Ref"):  # a name of something the snapshot shares: resolved here
            if self._resolve is None:
                raise SnapshotError("a reference where the snapshot may hold none")
            return self._resolve
        if (module, name) in ALLOWED_GLOBALS or (module.startswith("numpy.dtypes") and name.endswith("DType")):
            return super().find_class(module, name)
        if module.startswith(PROJECT_PREFIXES) or module in ("pdr", "service"):
            obj = super().find_class(module, name)
            if isinstance(obj, type):
                return obj
            raise SnapshotError(f"a snapshot may name classes only, and {module}.{name} is not one")
        raise SnapshotError(f"a snapshot may not name {module}.{name} (only this project's classes, numpy arrays "
                            "and the standard containers)")



class Ref:
    """In a responder's pickle, what stands for an object it shares (:class:`SharedRefs`):
    reading calls the reader's resolver with ``Ref``'s arguments instead of this class."""

    def __new__(cls, *name):  # pragma: no cover - never called: the unpickler resolves it
        raise SnapshotError("a snapshot reference read without its snapshot")


class _Pickler(pickle.Pickler):
    def __init__(self, file, name=None, reducers=None):
        super().__init__(file, protocol=5)
        if name is not None:  # called for instances (not numbers, strings, containers): far fewer calls than persistent_id
            def reducer_override(obj):
                ref = name(obj)
                return NotImplemented if ref is None else (Ref, ref)
            self.reducer_override = reducer_override
        if reducers:
            self.dispatch_table = {**copyreg.dispatch_table, **reducers}


def dumps(state, reducers=None) -> bytes:
    """``MAGIC`` + the pickle of ``state``; ``reducers`` (type -> reduce function) pickle the
    objects of those types their own way."""
    f = io.BytesIO()
    f.write(MAGIC)
    _Pickler(f, reducers=reducers).dump(state)
    return f.getvalue()


def loads(blob: bytes, resolve=None):
    """What :func:`dumps` pickled; ``resolve(name)`` gives the object a name stands for."""
    if not isinstance(blob, (bytes, bytearray, memoryview)) or bytes(blob[:len(MAGIC)]) != MAGIC:
        raise SnapshotError("not a firetrack core snapshot (its first bytes are not the snapshot header)")
    return _unpickle(memoryview(blob)[len(MAGIC):], resolve)


def _pickle(obj, name) -> bytes:
    f = io.BytesIO()
    _Pickler(f, name).dump(obj)
    return f.getvalue()


def _unpickle(data, resolve=None):
    try:
        return _Unpickler(io.BytesIO(data), resolve).load()
    except SnapshotError:
        raise
    except Exception as e:  # damaged or written by an incompatible version
        raise SnapshotError(f"the snapshot cannot be read: {type(e).__name__}: {e}") from None


# ------------------------------------------------------------------ one responder at a time
class SharedRefs:
    """The objects a responder's pickle names instead of holding: the core's fleet (``fleet``),
    a row of one of its arrays (``row``: a pipeline's state is a view of the fleet's rows) and
    the settings every tracker shares (``shared``: the given roots and every dataclass inside
    them, in a fixed order)."""

    def __init__(self, fleet, roots):
        self.fleet = fleet
        self.shared = _dataclass_tree(roots)
        self._ids = {id(o): ("shared", k) for k, o in enumerate(self.shared)}
        self._rows: dict[int, str] = {}
        rows = vars(fleet.rows) if fleet is not None else {}  # pdr.fleet_rows.FleetRows
        self._arrays = frozenset(k for k, v in rows.items() if isinstance(v, np.ndarray))
        if fleet is not None:
            self._ids[id(fleet)] = ("fleet",)
            self._rows = {id(v): k for k, v in rows.items() if isinstance(v, np.ndarray) and v.ndim >= 2}

    def name(self, obj):
        """For the responders' pickles: the name of a shared object, a fleet row or None."""
        ref = self._ids.get(id(obj))
        if ref is not None:
            return ref
        if type(obj) is np.ndarray and obj.base is not None and id(obj.base) in self._rows:
            return self._row(obj)
        return None

    def _row(self, a: np.ndarray):
        base = a.base
        stride = base.strides[0]
        offset = a.__array_interface__["data"][0] - base.__array_interface__["data"][0]
        if stride <= 0 or offset % stride or a.shape != base.shape[1:] or a.strides != base.strides[1:]:
            return None  # not a whole row: pickled as it is
        return ("row", self._rows[id(base)], offset // stride)

    def resolve(self, *pid):
        """For reading a responder's pickle: the object a name stands for."""
        try:
            kind = pid[0]
            if kind == "shared":
                return self.shared[pid[1]]
            if self.fleet is not None and kind == "fleet":
                return self.fleet
            if self.fleet is not None and kind == "row":
                name, slot = pid[1], pid[2]
                if name not in self._arrays:  # only the fleet's arrays may be named
                    raise KeyError(name)
                return getattr(self.fleet.rows, name)[int(slot)]
        except (TypeError, IndexError, KeyError, ValueError):
            pass
        raise SnapshotError(f"a snapshot names {str(pid)[:80]}, which it does not hold")


def _dataclass_tree(roots) -> list:
    """``roots`` (not None) and every dataclass instance inside them, breadth first, once each."""
    out, seen, todo = [], set(), [(o, True) for o in roots]
    while todo:
        o, root = todo.pop(0)
        if o is None or id(o) in seen or isinstance(o, type) or not (root or dataclasses.is_dataclass(o)):
            continue
        seen.add(id(o))
        out.append(o)
        if dataclasses.is_dataclass(o):
            todo += [(getattr(o, f.name, None), False) for f in dataclasses.fields(o)]
    return out


def dump_responder(state: dict, refs: SharedRefs) -> bytes:
    """One responder's state (a dict of its fields) as a pickle that names what it shares."""
    return _pickle(state, refs.name)


def load_responder(blob: bytes, refs: SharedRefs) -> dict:
    return _unpickle(blob, refs.resolve)
