"""When the next frame is due: background work (a snapshot) started in a gap between frames.

A wearable publishes its frames periodically (a batch every 20-200 ms). A worker busy with
a snapshot for a few milliseconds delays any frame that arrives meanwhile by up to that long;
started right after a round, when no responder's next frame is due for longer than the
snapshot takes, it delays none (issue 20: the snapshot's stall set the bystanders' latency
p99 under a flood).

The forecast per stream is the median of its last intervals, so one gap or one burst does not
move it: next arrival = last arrival + median interval. A stream whose interval is shorter
than :data:`MIN_PERIOD_S` (a flood on a key, a wearable that publishes every sample) or that
is late by half a period (stopped, or in an outage) has no forecast. The work is delayed by
at most the caller's bound, so a fleet whose frames leave no gap still gets its snapshots.
"""
from __future__ import annotations

import math
from collections import deque

MIN_PERIOD_S = 0.015  # s: faster streams are not forecast (a flood, a sample-by-sample publisher)
MAX_PERIOD_S = 2.0  # s: slower ones neither (no steady cadence to keep clear of)
INTERVALS = 8  # intervals whose median is a stream's period
FORGET_S = 10.0  # s of silence after which a stream is forgotten


class ArrivalForecast:
    """Per stream (a responder's frame key): its last arrival and recent intervals. Bounded:
    at most ``max_streams`` (the least recently heard go first) and none silent for
    :data:`FORGET_S`."""

    def __init__(self, max_streams: int = 1024):
        self.max_streams = max_streams
        self._streams: dict[str, tuple[float, deque]] = {}

    def __len__(self) -> int:
        return len(self._streams)

    def saw(self, key: str, t: float) -> None:
        """A frame of ``key`` arrived at ``t`` (s, the caller's clock)."""
        s = self._streams.pop(key, None)  # re-inserted: the dict stays in order of last arrival
        if s is None:
            s = (t, deque(maxlen=INTERVALS))
            if len(self._streams) >= self.max_streams:
                del self._streams[next(iter(self._streams))]
        else:
            last, iv = s
            if t > last:
                iv.append(t - last)
            s = (max(t, last), iv)
        self._streams[key] = s

    def period(self, key: str) -> float | None:
        """``key``'s period (s): the median of its last intervals, None before three."""
        s = self._streams.get(key)
        return None if s is None else _median(s[1])

    def quiet_for(self, now: float) -> float:
        """Seconds from ``now`` until the earliest forecast arrival (0 if one is due or
        overdue, ``inf`` when no stream has a forecast). Forgets streams silent for
        :data:`FORGET_S`."""
        quiet = math.inf
        stale = []
        for key, (last, iv) in self._streams.items():
            if now - last > FORGET_S:
                stale.append(key)
                continue
            period = _median(iv)
            if period is None or not MIN_PERIOD_S <= period <= MAX_PERIOD_S:
                continue
            due = last + period
            if due < now - 0.5 * period:  # late by half a period: stopped or cut off, no cadence now
                continue
            quiet = min(quiet, max(0.0, due - now))
        for key in stale:
            del self._streams[key]
        return quiet


def _median(iv: deque) -> float | None:
    if len(iv) < 3:
        return None
    s = sorted(iv)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])
