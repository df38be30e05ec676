"""Scoring a track against the IPIN 2023 landmarks (surveyed points the walker stood on).

The IPIN competition's metric, as the issue fixes it: at each scored landmark ``j`` the
error is the horizontal distance between the estimate and the surveyed point plus 15 m per
floor of error,

    e_j = ‖p̂(t_j) − p_j‖ + 15 · |f̂(t_j) − f_j|,

and a set of trials is summarised by the 75th percentile of all its errors pooled (p75),
the median and the share of landmarks on the right floor. ``p̂(t_j)`` is the estimate of the
last step at or before ``t_j`` (what the tracker knew of the walker at that moment).
With ``--fix-every K`` the landmarks 0, K, 2K, … are handed to the tracker as checkpoint
fixes and left out of the score; with K = 0 only landmark 0 (the initial position) is.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLOOR_PENALTY_M = 15.0


def fix_indices(n_landmarks: int, every: int) -> np.ndarray:
    """Indices of the landmarks given to the tracker: 0, K, 2K, … (only 0 when K = 0)."""
    if every < 0:
        raise ValueError(f"--fix-every must be 0 or positive, got {every}")
    if n_landmarks == 0:
        return np.empty(0, dtype=int)
    return np.arange(0, n_landmarks, every) if every > 0 else np.array([0])


@dataclass(frozen=True)
class LandmarkErrors:
    """Per scored landmark of one file."""

    index: np.ndarray  # landmark numbers
    t: np.ndarray
    horizontal_m: np.ndarray
    floor_error: np.ndarray  # integer floors
    error_m: np.ndarray  # horizontal + 15 m·|floor error|

    def __len__(self) -> int:
        return int(self.index.size)


def score_track(lm_t, lm_x, lm_y, lm_floor, track_t, track_x, track_y, track_floor, scored) -> LandmarkErrors:
    """Errors of the track at the landmarks ``scored`` (indices). The track is a step function:
    the estimate at ``t_j`` is the last track point at or before it (the first point if none)."""
    scored = np.asarray(scored, dtype=int)
    i = np.clip(np.searchsorted(np.asarray(track_t), np.asarray(lm_t)[scored], side="right") - 1, 0, None)
    tx, ty, tf = np.asarray(track_x)[i], np.asarray(track_y)[i], np.asarray(track_floor)[i]
    horiz = np.hypot(tx - np.asarray(lm_x)[scored], ty - np.asarray(lm_y)[scored])
    ferr = np.asarray(tf, int) - np.asarray(lm_floor, int)[scored]
    return LandmarkErrors(scored, np.asarray(lm_t)[scored], horiz, ferr, horiz + FLOOR_PENALTY_M * np.abs(ferr))


def summary(errors: list[LandmarkErrors]) -> dict:
    """p75, median and floor accuracy pooled over all scored landmarks of all files."""
    e = np.concatenate([x.error_m for x in errors]) if errors else np.empty(0)
    f = np.concatenate([x.floor_error for x in errors]) if errors else np.empty(0)
    if e.size == 0:
        return {"p75_m": None, "median_m": None, "floor_accuracy": None, "n_eval": 0}
    return {
        "p75_m": float(np.percentile(e, 75)),
        "median_m": float(np.median(e)),
        "floor_accuracy": float(np.mean(f == 0)),
        "n_eval": int(e.size),
    }
