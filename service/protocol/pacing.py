"""Sending messages at their own pace: a recording's time line divided by a speed factor."""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def paced(items: Iterable[T], speed: float, stop: threading.Event | None = None,
          time_of: Callable[[T], float] = lambda m: m.t,
          clock: Callable[[], float] = time.monotonic) -> Iterator[T]:
    """Yield ``items`` at their own pace divided by ``speed``: item ``k`` leaves at
    ``start + (time_of(k) - time_of(0)) / speed`` of ``clock`` (0 or inf: all at once).
    Stops early, without yielding more, once ``stop`` is set."""
    if not speed >= 0:
        raise ValueError(f"speed must be >= 0 (0 or inf: as fast as possible), got {speed}")
    fast = speed == 0 or math.isinf(speed)
    start = t0 = None
    for m in items:
        if stop is not None and stop.is_set():
            return
        if not fast:
            if t0 is None:
                t0, start = time_of(m), clock()
            wait = start + (time_of(m) - t0) / speed - clock()
            if wait > 0:
                if stop is not None:
                    if stop.wait(wait):
                        return
                else:
                    time.sleep(wait)
        yield m
