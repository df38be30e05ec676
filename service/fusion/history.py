"""Every pose of a track as plain numbers: columns that grow by doubling (amortised O(1) append).

The factor graph keeps only the fixed-lag window; a pose that leaves it is frozen here at its
last smoothed value, so the whole incident can still be drawn and scored.
"""
from __future__ import annotations

import numpy as np

COLUMNS: dict[str, type] = {
    "t": np.float64,  # s, device clock
    "index": np.int64,  # StepEvent.index (0 for the start pose)
    "x": np.float64,  # m, ENU east (smoothed; NaN while the pose is still in the window)
    "y": np.float64,  # m, ENU north
    "heading": np.float64,  # rad, ENU yaw of travel
    "floor": np.int64,  # floor label (PDR floor plus checkpoint correction)
    "pdr_floor": np.int64,  # the PDR's own floor, kept so a late checkpoint can relabel
    "length": np.float64,  # m, the step that led to this pose (0 for the start)
    "duration": np.float64,  # s, since the previous pose (0 for the start)
}


class PoseHistory:
    def __init__(self, capacity: int = 1024):
        self._n = 0
        self._cols = {k: np.zeros(capacity, dtype=dt) for k, dt in COLUMNS.items()}

    def __len__(self) -> int:
        return self._n

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(COLUMNS)

    def append(self, **values) -> int:
        """Add one pose (every column named); returns its row."""
        if self._n == len(self._cols["t"]):
            for k, col in self._cols.items():
                grown = np.zeros(2 * len(col), dtype=col.dtype)
                grown[: self._n] = col[: self._n]
                self._cols[k] = grown
        row = self._n
        for k in COLUMNS:
            self._cols[k][row] = values[k]
        self._n += 1
        return row

    def copy(self) -> PoseHistory:
        """A copy holding just the filled rows (column copies, not a row at a time: a snapshot
        of an hour-long track costs a few memcpys, not thousands of appends)."""
        out = PoseHistory.__new__(PoseHistory)
        out._n = self._n
        out._cols = {k: col[: max(self._n, 1)].copy() for k, col in self._cols.items()}
        return out

    def col(self, name: str) -> np.ndarray:
        """A view of the filled part of column ``name`` (writable: the owner updates it)."""
        return self._cols[name][: self._n]

    def nearest(self, t: float) -> int:
        """Row whose time is nearest to ``t`` (ties to the earlier pose)."""
        ts = self.col("t")
        i = int(np.searchsorted(ts, t))
        if i == 0:
            return 0
        if i == self._n:
            return self._n - 1
        return i if ts[i] - t < t - ts[i - 1] else i - 1


def smoothed_columns(hist: PoseHistory, estimate, window_start: int, floor_marks: list) -> dict[str, np.ndarray]:
    """Every pose so far in hindsight: ``t, x, y, heading, floor, index``.

    Rows from ``window_start`` on come from the smoother's ``estimate`` (gtsam Values with a
    Pose2 at ``X(row)``); older ones were frozen in ``hist`` when they left the window. A floor
    change without a step (``floor_marks``: ``(t, row, floor)``, a lift) repeats the pose
    before it on the new floor.
    """
    from service.fusion.keys import (
        X,  # gtsam symbols: only where the smoother's estimate is read
    )

    out = {k: hist.col(k).copy() for k in ("t", "x", "y", "heading", "floor", "index")}
    for row in range(window_start, len(hist)):
        p = estimate.atPose2(X(row))
        out["x"][row], out["y"][row], out["heading"][row] = p.x(), p.y(), p.theta()
    if floor_marks:
        rows = np.array([m[1] for m in floor_marks])
        at = np.searchsorted(np.arange(len(hist)), rows, side="right")
        for k in ("x", "y", "heading", "index"):
            out[k] = np.insert(out[k], at, out[k][rows])
        out["t"] = np.insert(out["t"], at, [max(m[0], out["t"][r]) for m, r in zip(floor_marks, rows)])
        out["floor"] = np.insert(out["floor"], at, [m[2] for m in floor_marks])
    return out
