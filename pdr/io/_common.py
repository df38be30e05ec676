"""Pieces every loader needs: a warning log, time ordering and length reconciliation."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from pdr.io.errors import RecordingFormatError, RecordingWarning

# Arrays in one file that should be sample-aligned may differ by at most this much before
# the difference counts as a broken file rather than a logger that stopped one channel a
# moment early. Both limits must hold: a 20000-sample file may lose 10 samples, a
# 500-sample file only 5.
MAX_TRIM_SAMPLES = 10
MAX_TRIM_FRACTION = 0.01


class Notes:
    """Warnings about one file: kept for ``Recording.warnings`` and raised as
    :class:`RecordingWarning` so that interactive users see them at once."""

    def __init__(self, path: str | Path):
        self.path = str(path)
        self.messages: list[str] = []

    def warn(self, message: str) -> None:
        self.messages.append(message)
        warnings.warn(f"{self.path}: {message}", RecordingWarning, stacklevel=3)


def time_order(t: np.ndarray, what: str, notes: Notes) -> np.ndarray | None:
    """Indices that make ``t`` strictly increasing, or ``None`` when it already is.

    Out-of-order samples are sorted stably (a sensor FIFO flushed late keeps its own
    order); a repeated timestamp keeps its first sample, since a series needs strictly
    increasing time for interpolation and differences. Both repairs are reported.
    """
    d = np.diff(t)
    if d.size == 0 or bool(np.all(d > 0)):
        return None
    n_back = int(np.count_nonzero(d < 0))
    order = np.argsort(t, kind="stable")
    keep = np.ones(order.size, dtype=bool)
    keep[1:] = np.diff(t[order]) > 0
    n_dup = int(np.count_nonzero(~keep))
    parts = []
    if n_back:
        parts.append(f"{n_back} step(s) back in time, sorted")
    if n_dup:
        parts.append(f"{n_dup} repeated timestamp(s), later sample(s) dropped")
    notes.warn(f"{what}: " + "; ".join(parts))
    return order[keep]


def common_length(lengths: dict[str, int], path: str | Path, notes: Notes) -> int:
    """Length to which sample-aligned arrays are trimmed; an error when they differ grossly.

    See :data:`MAX_TRIM_SAMPLES` and :data:`MAX_TRIM_FRACTION` for what "grossly" means.
    """
    longest = max(lengths.values())
    shortest_name = min(lengths, key=lengths.__getitem__)
    shortest = lengths[shortest_name]
    if shortest == longest:
        return longest
    listing = ", ".join(f"{k} {n}" for k, n in lengths.items())
    gap = longest - shortest
    if gap > MAX_TRIM_SAMPLES or gap > MAX_TRIM_FRACTION * longest:
        raise RecordingFormatError(
            path,
            f"sample-aligned fields differ in length by {gap} samples ({listing}); "
            f"at most {MAX_TRIM_SAMPLES} samples and {MAX_TRIM_FRACTION:.0%} are trimmed",
            field=shortest_name,
        )
    notes.warn(f"fields differ slightly in length ({listing}); trimmed to {shortest} samples")
    return shortest


def file_must_exist(path: str | Path) -> Path:
    p = Path(path)
    if not p.exists():
        raise RecordingFormatError(p, "file not found")
    return p
