"""Incident recordings: every message of an incident, as it was on the wire, in an MCAP file.

A recording stores the raw msgpack payload of each zenoh sample with its key expression
``firetrack/{incident}/{responder}/{kind}``; nothing is decoded on the way in, so a replay
republishes exactly what the service once received (and a wire-schema change cannot break
an old recording: it is decoded by whoever reads it).

File layout (MCAP, https://mcap.dev/spec):

- one channel per key expression: ``topic`` = the key, ``message_encoding`` = ``"msgpack"``,
  no schema (``schema_id`` 0). msgpack is self-describing, which is what MCAP asks of a
  schema-less channel; the channel's metadata carries ``incident``, ``responder``, ``kind``.
- ``log_time`` = receive time (ns since the Unix epoch); ``publish_time`` = the sample's own
  timestamp when it had one (zenoh routers stamp samples), else equal to ``log_time`` as the
  spec asks, which the reader turns back into ``None``.
- a ``firetrack.recording`` metadata record with the incident and the writer's settings.
- messages in zstd-compressed chunks with CRCs, then the usual summary (statistics,
  chunk and message indexes) written by :meth:`IncidentRecorder.close`.

Crash safety. Messages wait in memory in the chunk being built; a chunk goes to the operating
system (``os.write``, no user-space buffer) as soon as it is finished. A chunk is finished

- by the ``mcap`` writer once its uncompressed records exceed ``chunk_size`` bytes, or
- by :meth:`IncidentRecorder.write` as soon as the pending messages span ``flush_interval_s``
  of receive time, and by :meth:`IncidentRecorder.flush_if_due` (called on a timer by the
  live recorder) once the oldest pending message is ``flush_interval_s`` old. ``mcap``'s
  ``Writer.flush()`` (mcap >= 1.6) ends a chunk early, so the library needs no patching.

So a process killed at any instant (SIGKILL, OOM, crash) loses at most the messages of the one
unfinished chunk: fewer than ``flush_interval_s`` of receive time, and at most ``chunk_size``
bytes of records plus the single message that crossed it. :func:`read_recording` reads such a
cut-off file up to its last complete chunk (tests/test_recorder.py kills a writer with
SIGKILL and checks both the exact prefix and the bound). A power cut can also lose what the
kernel had not written out yet, unless ``fsync=True``: each finished chunk is then
``fsync``-ed, which cost ~7 ms per chunk on the development VM's ext4 against ~0.1 ms without
(so at the default one chunk per second, under 1 % of a core's time either way).

Segments. A recording may be several files: ``x.mcap``, then ``x.1.mcap``, ``x.2.mcap``, ...
(:func:`segment_paths`), one per run of the service: a service restarted on the same recording
path (after a crash, or by systemd) writes the next segment instead of refusing to start or
touching what is there. Each segment is a complete MCAP file on its own; its metadata names
its number, and a segment written by a resumed service starts with a ``firetrack.resume``
attachment saying what the service resumed from (:mod:`service.review.resume`), so
``reprocess`` of the whole recording takes the same path as the live service did.

Measured on the development VM (one core, 246-byte msgpack IMU payloads, zstd): ~200 000
messages/s written, ~190 000/s read back, 117 bytes/message on disk.
"""
from __future__ import annotations

import errno
import os
from collections import Counter
from pathlib import Path

from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, Writer

from service.protocol.keys import KEY_ROOT, check_id, parse_key  # noqa: F401  (the one set of key rules)
from service.review.recording_reader import (  # noqa: F401  (read back where it is written)
    RECORDING_FORMAT,
    RECORDING_METADATA,
    RESUME_ATTACHMENT,
    RecordedMessage,
    RecordingReader,
    TruncatedRecordingWarning,
    next_segment_path,
    ns_of_seconds,
    read_recording,
    recording_summary,
    seconds_of_ns,
    segment_paths,
)

INPUT_KINDS = ("imu", "fix", "command", "ack", "op")  # what wearables, anchors, operators and consoles publish: a replay feeds it back


class RecordingWriteError(OSError):
    """The recording could not be written (disk full, file closed, no permission, ...).

    ``str()`` is the whole message (path, what was being written, the reason, how many
    messages are safe); ``errno`` is the operating system's code when there is one.
    """

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.errno = code


# ------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------
class _UnbufferedFile:
    """The output the ``mcap`` writer sees: every ``write`` goes straight to the kernel.

    The writer only writes whole records (header, a finished chunk, its message index), so
    there is no user-space buffer whose loss a crash could add to the unfinished chunk; and a
    full disk surfaces at the write that hit it, not at some later flush.
    """

    def __init__(self, fd: int, fsync: bool):
        self.fd = fd
        self.position = 0
        self._fsync = fsync
        self._synced = 0

    def write(self, data) -> int:
        view = memoryview(data)
        while view:  # os.write may write less than asked
            n = os.write(self.fd, view)
            if n == 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            view = view[n:]
            self.position += n
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        if self._fsync and self._synced != self.position:
            os.fsync(self.fd)
            self._synced = self.position

    def close(self) -> None:
        os.close(self.fd)


class IncidentRecorder:
    """Writes one incident's messages into an MCAP file (see the module docstring).

    ``with IncidentRecorder(path, "demo") as rec: rec.write(key, payload, receive_time)``.

    Loss bound on a crash: at most the messages of the last unfinished chunk, i.e. fewer than
    ``flush_interval_s`` of receive time and at most ``chunk_size`` bytes of uncompressed
    records (+ the one message that crossed it). With :meth:`flush_if_due` called every
    ``P`` seconds the lost messages are also at most ``flush_interval_s + P`` old.

    Any write failure raises :class:`RecordingWriteError` and leaves ``healthy`` False with the
    reason in ``error``; later writes raise it again. The file then ends at its last complete
    chunk, which :func:`read_recording` reads: at least the ``flushed_count`` messages, and
    possibly the chunk that was being written (even the message whose ``write`` raised) when
    only what followed it failed.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        incident: str,
        chunk_size: int = 1024 * 1024,
        flush_interval_s: float = 1.0,
        *,
        fsync: bool = False,
        compression: str = "zstd",
        overwrite: bool = False,
        segment: int = 0,
        resume: bytes | None = None,
    ):
        self.path = Path(path)
        self.incident = check_id("incident", incident)
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be > 0 bytes, got {chunk_size}")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s, got {flush_interval_s}")
        codecs = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in codecs:
            raise ValueError(f"compression must be one of {sorted(codecs)}, got {compression!r}")
        self.chunk_size = int(chunk_size)
        self.flush_interval_s = float(flush_interval_s)
        self.healthy = True
        self.error: str | None = None
        self.message_count = 0  # accepted by write()
        self.flushed_count = 0  # in finished chunks, i.e. safe from a crash of this process
        self.counts: Counter[str] = Counter()  # per key
        self._channels: dict[str, int] = {}
        self._pending_since: float | None = None  # receive time of the oldest unflushed message
        self._closed = False

        flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL) | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except OSError as e:
            exists = "it already exists (pass overwrite=True to replace it)" if isinstance(e, FileExistsError) else None
            raise self._failed("opening it", e, exists) from e
        self._file = _UnbufferedFile(fd, fsync)
        self._writer = Writer(self._file, chunk_size=self.chunk_size, compression=codecs[compression], enable_crcs=True)
        try:
            with self._guard("writing its header"):
                self._writer.start(profile="", library=f"firetrack {RECORDING_FORMAT}")
                self._writer.add_metadata(RECORDING_METADATA, {
                    "format": RECORDING_FORMAT,
                    "incident": self.incident,
                    "chunk_size": str(self.chunk_size),
                    "flush_interval_s": repr(self.flush_interval_s),
                    "compression": compression,
                    "segment": str(int(segment)),
                })
                if resume is not None:  # what this segment's service resumed from (service.review.resume)
                    self._writer.add_attachment(0, 0, RESUME_ATTACHMENT, "application/msgpack", bytes(resume))
                self._file.flush()
        except RecordingWriteError:
            self.close()  # no file descriptor left behind by a recorder that never started
            raise

    # -- the public calls ------------------------------------------------------------------
    def write(self, key: str, payload: bytes, receive_time: float, publish_time: float | None = None) -> None:
        """Record one sample: its key expression, raw payload and receive time (Unix s)."""
        channel = self._channels.get(key)
        if channel is None:  # a key seen before was checked then
            incident, responder, kind = parse_key(key)
            if incident != self.incident:
                raise ValueError(f"key {key!r} belongs to incident {incident!r}, this recording is of {self.incident!r}")
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise TypeError(f"payload of {key!r} must be bytes, got {type(payload).__name__}")
        log_ns = _to_ns(receive_time, "receive_time", key)
        pub_ns = log_ns if publish_time is None else _to_ns(publish_time, "publish_time", key)
        self._check_usable()
        before = self._file.position
        with _WriteGuard(self, "writing a message of ", key):
            if channel is None:
                channel = self._writer.register_channel(
                    key, MessageEncoding.MessagePack, 0,
                    {"incident": incident, "responder": responder, "kind": kind})
                self._channels[key] = channel
                if self._file.position != before:  # the channel record itself filled the chunk
                    self._chunk_done()
                    before = self._file.position
            # sequence: the message's number on its key (MCAP's field is 32 bits)
            self._writer.add_message(channel, log_ns, bytes(payload), pub_ns, self.counts[key] & 0xFFFFFFFF)
        self.message_count += 1
        self.counts[key] += 1
        if self._file.position != before:  # the writer finished a chunk by size, this message in it
            self._chunk_done()
        elif self._pending_since is None:
            self._pending_since = receive_time
        elif receive_time - self._pending_since >= self.flush_interval_s:
            self.flush()
        elif receive_time < self._pending_since:
            # the receive clock stepped back: count from the new reading, so the chunk still
            # closes flush_interval_s later instead of when the clock catches up
            self._pending_since = receive_time

    def flush_if_due(self, now: float) -> bool:
        """Finish the pending chunk if its oldest message was received ``flush_interval_s`` ago."""
        if self._pending_since is not None and now - self._pending_since >= self.flush_interval_s:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        """Finish the pending chunk now and hand it to the kernel (and the disk, if ``fsync``)."""
        self._check_usable()
        with self._guard("finishing a chunk"):
            self._writer.flush()
        self._chunk_done()

    def close(self) -> None:
        """Finish the last chunk, write the summary and footer, close the file."""
        if self._closed:
            return
        self._closed = True
        if not self.healthy:  # the failure was raised already; the file ends at its last good chunk
            try:
                self._file.close()
            except OSError:
                pass  # closing a file that already failed: the first error is the one reported
            return
        try:
            with self._guard("writing its summary"):
                self._writer.finish()
                self._file.flush()
            self._chunk_done()
        finally:
            try:
                self._file.close()
            except OSError as e:
                if self.healthy:
                    raise self._failed("closing it", e) from e

    @property
    def unflushed_count(self) -> int:
        """Messages a crash right now would lose."""
        return self.message_count - self.flushed_count

    def __enter__(self) -> IncidentRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------
    def _chunk_done(self) -> None:
        self._file.flush()  # fsync if asked; a no-op otherwise (the bytes are already in the kernel)
        self.flushed_count = self.message_count
        self._pending_since = None

    def _check_usable(self) -> None:
        if self._closed:
            raise self._failed("writing to it", None, "the recording is closed")
        if not self.healthy:
            raise RecordingWriteError(self.error, None)

    def _guard(self, what: str):
        return _WriteGuard(self, what, "")

    def _failed(self, what: str, exc: BaseException | None, reason: str | None = None) -> RecordingWriteError:
        if reason is None:
            if isinstance(exc, OSError) and exc.errno is not None:
                reason = f"{exc.strerror or os.strerror(exc.errno)} ({errno.errorcode.get(exc.errno, exc.errno)})"
            else:
                reason = str(exc) if exc is not None else "unknown error"
        message = f"cannot write recording {self.path} while {what}: {reason}"
        if self.message_count:
            message += f"; {self.flushed_count} of its {self.message_count} messages are safely in the file"
        self.healthy = False
        self.error = message
        return RecordingWriteError(message, exc.errno if isinstance(exc, OSError) else None)


class _WriteGuard:
    """Turns an OS-level failure inside the ``mcap`` writer into :class:`RecordingWriteError`."""

    def __init__(self, recorder: IncidentRecorder, what: str, key: str):
        self.recorder, self.what, self.key = recorder, what, key  # joined only on failure

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        # ValueError is what Python raises for an operation on a closed file
        if exc is not None and isinstance(exc, (OSError, ValueError)) and not isinstance(exc, RecordingWriteError):
            raise self.recorder._failed(self.what + self.key, exc) from exc
        return False


def as_recorded(t: float) -> float:
    """``t`` (Unix s) as a recording gives it back. The file keeps whole nanoseconds
    (``log_time``) and the reader divides by 10⁹; for about 7 % of today's clock readings
    ``round(t · 10⁹) / 10⁹`` is not ``t`` but its neighbour, one ulp (238 ns) away. The shell
    stamps every input with this, so the core live sees the receive times ``reprocess`` will
    (the promise live = reprocess, bit for bit). One application reaches a value that round-trips
    (checked on 10⁶ readings); the loop is the guarantee."""
    for _ in range(4):
        r = seconds_of_ns(ns_of_seconds(t))
        if r == t:
            break
        t = r
    return t


def _to_ns(t: float, what: str, key: str) -> int:
    try:
        ns = ns_of_seconds(t)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{what} of {key!r} must be a finite number of Unix seconds, got {t!r}") from None
    if not 0 <= ns < 2**64:
        raise ValueError(f"{what} of {key!r} must be >= 0 Unix seconds, got {t!r}")
    return ns


__all__ = [
    "INPUT_KINDS", "as_recorded", "IncidentRecorder", "RecordedMessage", "RecordingReader", "RecordingWriteError",
    "TruncatedRecordingWarning", "next_segment_path", "parse_key", "read_recording", "recording_summary", "segment_paths",
]
