"""A recording's arrays cut into wire frames (what a wearable sends, 10 a second)."""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from pdr.frames import frame_bounds
from service.protocol.schema import ImuBatch


def imu_batches_from_arrays(responder: str, device: str, t, acc, gyr, mag=None, pressure_t=None, pressure=None,
                            carry: str = "unknown", per_batch: int = 10, seq0: int = 0,
                            boot: str | None = None) -> Iterator[ImuBatch]:
    """Cut a recording into frames of ``per_batch`` samples, seq ``seq0, seq0+1, ...``.

    Pressure sample ``p`` goes with the batch ``k`` whose span contains it:
    ``end_{k-1} < p_t <= end_k`` (``end_k`` the time of batch k's last IMU sample); the first
    batch also takes every earlier one, the last batch every later one, so no sample is lost.
    """
    if per_batch < 1:
        raise ValueError(f"per_batch must be at least 1, got {per_batch}")
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    n = t.shape[0]
    if n == 0:
        raise ValueError("t is empty: there is nothing to cut into frames")
    arrays = {}
    for name, a in (("acc", acc), ("gyr", gyr), ("mag", mag)):
        if a is None:
            continue
        a = np.ascontiguousarray(a, dtype=np.float64)
        if a.shape != (n, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({n}, 3) to match t")
        arrays[name] = a
    if (pressure_t is None) != (pressure is None):
        raise ValueError("pressure_t and pressure come together")
    pt = p = None
    if pressure is not None:
        pt = np.ascontiguousarray(pressure_t, dtype=np.float64).reshape(-1)
        p = np.ascontiguousarray(pressure, dtype=np.float64).reshape(-1)
        if p.shape != pt.shape:
            raise ValueError(f"pressure has {p.shape[0]} values for {pt.shape[0]} times")
        if pt.size > 1 and not (np.diff(pt) > 0).all():
            i = int(np.argmax(~(np.diff(pt) > 0))) + 1
            raise ValueError(f"pressure_t must strictly increase: pressure_t[{i}] = {pt[i]!r} follows {pt[i - 1]!r}")
    starts, stops, p_lo, p_hi = frame_bounds(t, per_batch, pt)
    for k, (a, b) in enumerate(zip(starts, stops)):
        kw = {name: arr[a:b] for name, arr in arrays.items()}
        if pressure is not None:
            lo, hi = p_lo[k], p_hi[k]
            if hi > lo:
                kw["pressure_t"], kw["pressure"] = pt[lo:hi], p[lo:hi]
        yield ImuBatch(responder=responder, device=device, seq=seq0 + k, t=t[a:b], carry=carry, boot=boot, **kw)
