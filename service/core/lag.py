"""How late frames reach the core: a responder's lag, and how far behind the service is.

Per frame ``k`` the core knows its newest sample's device time ``t_k`` and the service time
``r_k`` the shell took it at. ``d_k = r_k − t_k`` is the frame's delay plus the offset between
the two clocks, which is unknown but constant (a clock drifts by at most about 100 ppm:
0.03 s in 5 minutes). The least delayed frame seen recently, the *base* ``b = min d_j``, carries
the offset and the smallest delay (the base-delay idea of LEDBAT, RFC 6817 section 2.4.1: the
minimum over the current and the previous window of ``window_s``, two buckets, so it follows a
drifting clock and forgets an old one). At service time ``now``, the newest sample taken is

    lag(now) = now − t_newest − b  ≥ 0

seconds old beyond what the quickest frame took: the time frames spend queued (network,
router, the worker's channel) and the rounds of a worker that is behind. No clock needs to be
synchronised. Between two frames of a live wearable (0.1 s) it grows by up to 0.1 s; the core
lets it grow at most ``GROWTH_S`` past the newest input of any responder at a tick that follows
no input, so silence (nobody sending) is not mistaken for a service behind; at a tick right
after a round that took input, the round's own work counts in full (a worker behind takes all
that waits, then works through it).

One responder's lag is its own news (a bad radio link, frames resent after a gap). When the
service cannot keep up, every responder's lag grows together: :func:`behind_s`, the median
over the responders heard lately, is the service's lag. Status carries each responder's; the
console shows the service's.
"""
from __future__ import annotations

import math
from collections.abc import Iterable

BASE_WINDOW_S = 300.0  # s of service time per bucket of the base delay's minimum
GROWTH_S = 0.5  # s a lag may grow past the newest input taken (frames every 0.1 s; below the console's 1 s)


class FrameLag:
    """``note(received, t_last)`` per frame in order; ``at(now)`` the age of the newest sample."""

    __slots__ = ("window_s", "_bucket_start", "_min_now", "_min_before", "_t_newest")

    def __init__(self, window_s: float = BASE_WINDOW_S):
        self.window_s = window_s
        self.reset()

    def reset(self) -> None:
        """A new device clock (another stream): the base starts again."""
        self._bucket_start = -math.inf
        self._min_now = math.inf
        self._min_before = math.inf
        self._t_newest = math.nan

    def note(self, received: float, t_last: float, base: bool = True) -> None:
        """The frame whose newest sample is at ``t_last`` (device s) was taken at ``received``
        (service s); ``base=False``: it does not count towards the base (a stream's first frame,
        sent before the wearable settled: a simulator that paused its clock after it, say)."""
        d = received - t_last
        if not math.isfinite(d):
            return
        self._t_newest = t_last
        if not base:
            return
        if received - self._bucket_start >= self.window_s or received < self._bucket_start:
            self._bucket_start, self._min_before, self._min_now = received, self._min_now, math.inf
        self._min_now = min(self._min_now, d)

    def at(self, now: float) -> float:
        """s: how much older the newest sample is at service time ``now`` than the quickest
        frame's delay says it would be (0 before any frame)."""
        lag = now - self._t_newest - min(self._min_now, self._min_before)
        return max(lag, 0.0) if math.isfinite(lag) else 0.0


def behind_s(lags: Iterable[float]) -> float:
    """The service's lag: the median of its responders' lags (0 with none). One responder's
    late frames do not move it; a worker that cannot keep up moves everyone's."""
    xs = sorted(x for x in lags if math.isfinite(x))
    if not xs:
        return 0.0
    m = len(xs) // 2
    return xs[m] if len(xs) % 2 else 0.5 * (xs[m - 1] + xs[m])


class ServiceLag:
    """The core's side of the lags: when it last took input (``took``, per message) and whether
    the last tick came right after a round with input (``ticked``). ``of`` is one responder's lag
    at a time, :meth:`behind_s` the service's. Owned by the core; its Statuses read it."""

    __slots__ = ("idle_after_s", "last_take", "fed", "tick_busy")

    def __init__(self, idle_after_s: float):
        self.idle_after_s = idle_after_s  # s: a responder not heard within this of the newest input is idle
        self.last_take = -math.inf  # service time of the newest message taken (who was heard lately)
        self.fed = False  # input since the last tick
        self.tick_busy = False  # the last tick followed a round with input: that round's work counts

    def took(self, now: float) -> None:
        """A message taken at service time ``now``."""
        self.last_take, self.fed = now, True

    def ticked(self) -> None:
        """A tick: whether input came since the one before decides how far lags may grow now."""
        self.tick_busy, self.fed = self.fed, False

    def of(self, frames: FrameLag, last_input: float, now: float) -> float:
        """The lag at ``now`` of a responder whose frames are ``frames`` and whose newest input was
        at ``last_input``: after a tick that follows no input, at most ``GROWTH_S`` past the newest
        input of anyone (a quiet incident is not a service behind; a round's work is); at its own
        last input unless heard within ``idle_after_s`` of the newest input (of the input, not of
        the clock: a worker behind takes all input late)."""
        lately = last_input > self.last_take - self.idle_after_s
        at = now if self.tick_busy else min(now, self.last_take + GROWTH_S)
        return frames.at(at if lately else last_input)

    def behind_s(self, responders: Iterable, now: float) -> float:
        """How far behind the core is at ``now``: the median lag of ``responders`` (each with
        ``lag`` and ``last_input``)."""
        return behind_s(self.of(r.lag, r.last_input, now) for r in responders)
