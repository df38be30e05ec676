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
