"""Snapshots of the core on the service's schedule: taken by the worker, written and fsynced by a
thread of their own (issue 20, restart recovery).

A mixin of :class:`service.shell.service.IncidentService`.
"""
from __future__ import annotations

import gc
import logging
import threading
import time

log = logging.getLogger("firetrack.service")


class SnapshotWriter:
    """The core's snapshots: taken by the worker, written by a thread of their own."""

    def _snapshot_if_due(self) -> None:
        """The core's snapshot every ``snapshot_every_s``: into the state file beside the recording,
        once the recording holds everything the core has seen, and to a standby that follows
        (``snapshot_feed``, :mod:`service.shell.standby`) while one does (a failure is logged
        once and the service goes on: the recording alone still lets ``serve`` resume)."""
        now = time.monotonic()
        if now - self._last_snapshot < self.settings.snapshot_every_s:
            return
        sf = self.state_file
        if self.recorder is None or self.recorder_error is not None or self.snapshot_error is not None:
            sf = None
        feed = self.snapshot_feed if self.snapshot_feed is not None and self.snapshot_feed.wanted() else None
        if sf is None and feed is None:
            return
        if self._snapshot_writer is not None and self._snapshot_writer.is_alive():
            self.snapshots_skipped += 1  # the disk is slower than the snapshots: the next one will do
            return
        # a crowd of responders to pickle afresh (ids just admitted) is pickled a batch per round,
        # and the snapshot taken when few are left (or once it is a whole period late)
        with self._core_lock:
            left = self.core.prepare_snapshot(self.settings.snapshot_batch)
        if left and now - self._last_snapshot < 2 * self.settings.snapshot_every_s:
            self.snapshots_deferred += 1
            return
        self._last_snapshot = now
        position = 0
        try:
            if sf is not None:
                with self._rec_lock:
                    self.recorder.flush()  # everything fed so far is in the file before the snapshot says so
                    position = self.recorder.message_count
            with self._core_lock:
                blob = self.core.snapshot()
        except Exception as e:
            self._snapshot_failed(sf, e)
            return
        # writing and fsyncing megabytes is the disk's time, not the worker's: a thread of its own
        # (the state file is replaced whole, so a crash meanwhile leaves the previous snapshot)
        self._snapshot_writer = threading.Thread(target=self._write_snapshot, args=(sf, feed, blob, position,
                                                                                    self.clock()),
                                                 daemon=True, name="snapshot-writer")
        self._snapshot_writer.start()

    def _write_snapshot(self, sf, feed, blob: bytes, position: int, now: float) -> None:
        if feed is not None:
            try:
                feed.put(blob)
            except Exception:  # a closing session; the standby keeps the previous one
                log.exception("publishing the snapshot to the standby")
        if sf is None:
            return
        try:
            sf.write(blob, position, now)
            self.snapshots += 1
        except Exception as e:
            self._snapshot_failed(sf, e)

    def _snapshot_failed(self, sf, e: Exception) -> None:
        self.snapshot_error = str(e)
        log.error("writing the snapshot %s failed; no more snapshots (a restart replays the recording): %s",
                  getattr(sf, "path", sf), e)


M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter (malloc.h)


def fix_mmap_threshold(nbytes: int | None) -> bool:
    """Blocks of ``nbytes`` and more are mapped on their own and unmapped when freed (glibc's
    ``mallopt(M_MMAP_THRESHOLD)``); True when set. glibc's default threshold rises to the size
    of the largest mapped block freed (up to 32 MB), after which the service's big short-lived
    buffers — a snapshot's bytes every few seconds, its state file's framing, large payloads —
    come from the heap, scatter free space through it, and stay resident: a flood that
    admitted hundreds of ids left ~80 MB of free heap resident after they expired (issue 20).
    A fixed threshold keeps the dynamic rise off. None, or no glibc: nothing is changed."""
    if nbytes is None:
        return False
    try:
        import ctypes

        return bool(ctypes.CDLL("libc.so.6").mallopt(M_MMAP_THRESHOLD, int(nbytes)))
    except (OSError, AttributeError):
        return False


def return_memory() -> None:
    """After responders left: collect their cycles and hand the freed heap back to the operating
    system (glibc keeps freed small blocks otherwise, and the process would look as big as at
    its peak). A no-op where there is no glibc."""
    gc.collect()
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
