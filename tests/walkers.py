"""Simulated walkers as wire frames, for tests of the core and the service (no recordings needed)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdr.simulation import SimulatedWalker, WalkerSettings
from service.protocol import wire

RATE_HZ = 100.0
PER_FRAME = 10  # samples per wire frame: 10 frames/s, like a wearable


@dataclass
class Walk:
    """A walker's frames and its truth: ``frames[k]`` covers ``t[k*PER_FRAME:(k+1)*PER_FRAME]``."""

    frames: list
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    steps: np.ndarray

    def truth_at(self, t: float) -> tuple[float, float]:
        i = min(int(np.searchsorted(self.t, t)), len(self.t) - 1)
        return float(self.x[i]), float(self.y[i])


def walk(responder: str = "ff1", seconds: float = 60.0, seed: int = 0, device: str = "phone-1", boot: str | None = "b1",
         t0: float = 1000.0, seq0: int = 0, collapse_at: float | None = None, bounds=(-30.0, 30.0, -20.0, 20.0)) -> Walk:
    """``seconds`` of one simulated walker (a random route in ``bounds``) as 10 frames/s."""
    w = SimulatedWalker(responder, None, WalkerSettings(rate_hz=RATE_HZ), seed, start_t=t0, bounds=bounds,
                        floors=(0, 0), collapse_at=collapse_at, attitude=False)
    b = w.next_batch(int(round(seconds * RATE_HZ)))
    frames = list(wire.imu_batches_from_arrays(responder, device, b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure,
                                               carry="handheld", per_batch=PER_FRAME, seq0=seq0, boot=boot))
    return Walk(frames, b.t, b.x, b.y, b.step_count)


def restamped(frames, *, dt: float = 0.0, seq0: int | None = None, boot: str | None = None, device: str | None = None):
    """The same frames on another clock (``dt`` added to every time), counter, boot or device."""
    out = []
    for k, f in enumerate(frames):
        upd = {}
        if dt:
            upd["t"] = f.t + dt
            if f.pressure_t is not None:
                upd["pressure_t"] = f.pressure_t + dt
        if seq0 is not None:
            upd["seq"] = seq0 + k
        if boot is not None:
            upd["boot"] = boot
        if device is not None:
            upd["device"] = device
        out.append(wire.ImuBatch(**{**{n: getattr(f, n) for n in wire.ImuBatch.model_fields}, **upd}))
    return out
