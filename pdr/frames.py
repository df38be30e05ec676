"""Cutting a recording into consecutive frames: the one rule both sides of the wire use.

A frame holds ``per_frame`` IMU samples (the last one fewer). Pressure runs on its own clock:
pressure sample ``p`` goes with the frame ``k`` whose span contains it,
``end_{k-1} < t_p <= end_k`` (``end_k`` the time of frame k's last IMU sample); the first frame
also takes every earlier pressure sample, the last frame every later one, so none is lost.
:func:`pdr.pipeline.frames_of` cuts :class:`ImuFrame` for the algorithms and
:func:`service.protocol.schema.imu_batches_from_arrays` cuts wire frames with the same bounds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def frame_bounds(t: np.ndarray, per_frame: int, pressure_t: np.ndarray | None = None):
    """``(starts, stops, p_lo, p_hi)``: frame ``k`` holds IMU samples ``starts[k]:stops[k]``
    and pressure samples ``p_lo[k]:p_hi[k]`` (both None without ``pressure_t``)."""
    if per_frame < 1:
        raise ValueError(f"per_frame must be at least 1, got {per_frame}")
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    n = t.shape[0]
    starts = np.arange(0, n, per_frame)
    stops = np.minimum(starts + per_frame, n)
    if pressure_t is None:
        return starts, stops, None, None
    pt = np.asarray(pressure_t, dtype=np.float64).reshape(-1)
    owner = np.minimum(np.searchsorted(t[stops - 1], pt, side="left"), max(starts.size - 1, 0))
    bounds = np.searchsorted(owner, np.arange(starts.size + 1), side="left")
    return starts, stops, bounds[:-1], bounds[1:]


@dataclass(frozen=True)
class ImuFrame:
    """Consecutive samples of one responder: what one wire frame (or a slice of a file) holds.

    ``t`` (N,) s device clock, ``acc`` (N, 3) m/s², ``gyr`` (N, 3) rad/s, ``mag`` (N, 3) µT or
    None; pressure on its own clock: ``pressure_t`` (M,) s and ``pressure`` (M,) hPa, or None.
    """

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None = None
    pressure_t: np.ndarray | None = None
    pressure: np.ndarray | None = None

    def __len__(self) -> int:
        return int(np.shape(self.t)[0])
