"""Rejects in the log: a few lines per source, then one summary per source and window.

Every rejected message is counted (``Status.rejected``, the core's accounting); the log only
has to let a person see what is wrong and who sends it. So per window of ``window_s`` of
receive time, each source gets its first ``lines_per_source`` rejects logged in full, and the
whole log at most ``lines_per_window`` such lines; when the window closes, every source that
had more gets one line with its counts by reason::

    <bad key>: 41,377 more messages rejected in the last 10 s (bad_key 41,377)
    ff3: 2,012 more messages rejected in the last 10 s (msgpack 1,004, schema 1,008)

A flood of any size therefore adds at most ``lines_per_window + sources`` lines per window,
and the sources are bounded (``max_sources``; beyond, their counts join ``<other sources>``).
Pure: time comes in with each call.
"""
from __future__ import annotations

import logging
import math

OTHER = "<other sources>"


class RejectLog:
    """``log.note(source, reason, detail, now)`` for every reject; see the module docstring."""

    def __init__(self, logger: logging.Logger, window_s: float = 10.0, lines_per_source: int = 3,
                 lines_per_window: int = 40, max_sources: int = 256):
        if not window_s > 0:
            raise ValueError(f"window_s must be positive, got {window_s!r}")
        self.log = logger
        self.window_s = float(window_s)
        self.lines_per_source = int(lines_per_source)
        self.lines_per_window = int(lines_per_window)
        self.max_sources = int(max_sources)
        self._start = -math.inf  # receive time the current window opened
        self._lines = 0  # full lines logged in this window
        self._logged: dict[str, int] = {}  # source -> full lines this window
        self._unlogged: dict[str, dict[str, int]] = {}  # source -> reason -> rejects not logged this window
        self.lines = 0  # lines written, ever (full and summary)

    def note(self, source: str, reason: str, detail: str, now: float, level: int = logging.WARNING,
             exc_info: bool = False) -> None:
        """One reject of ``source`` for ``reason`` at receive time ``now``; ``exc_info`` logs the
        exception being handled with it (when the line is logged in full)."""
        if now - self._start >= self.window_s or now < self._start:
            self.flush(now)
        n = self._logged.get(source, 0)
        if n < self.lines_per_source and self._lines < self.lines_per_window:
            self._logged[source] = n + 1
            self._lines += 1
            self.lines += 1
            self.log.log(level, "%s: rejected (%s): %s", source, reason, _short(detail), exc_info=exc_info)
            return
        if source not in self._unlogged and len(self._unlogged) >= self.max_sources:
            source = OTHER
        counts = self._unlogged.setdefault(source, {})
        counts[reason] = counts.get(reason, 0) + 1

    def flush(self, now: float) -> None:
        """Close the window: one summary line per source with rejects that were not logged."""
        for source, counts in self._unlogged.items():
            total = sum(counts.values())
            by = ", ".join(f"{r} {n:,}" for r, n in sorted(counts.items(), key=lambda kv: -kv[1]))
            span = now - self._start if math.isfinite(self._start) else self.window_s
            self.log.warning("%s: %s more message%s rejected in the last %.0f s (%s)", source, f"{total:,}",
                             "s" if total != 1 else "", max(span, 0.0), by)
            self.lines += 1
        self._unlogged.clear()
        self._logged.clear()
        self._lines = 0
        self._start = now


def _short(text: str, limit: int = 300) -> str:
    """A detail cut to ``limit`` characters: a 10 MB key or a 100 k-deep map must not reach the log whole."""
    text = str(text)
    return text if len(text) <= limit else text[:limit - 3] + "..."
