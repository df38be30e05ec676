"""Reading a recording back: messages in the order they were written, a torn file up to its
last complete chunk, and a summary (keys, counts, duration) without decoding the payloads.

A recording may be segments (``x.mcap``, ``x.1.mcap``, ...; :func:`segment_paths`, see
:mod:`service.review.recorder`): :func:`read_recording` of the first reads them all, one
after the other; ``segments=False`` reads one file.
"""
from __future__ import annotations

import dataclasses
import heapq
import os
import struct
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path

import zstandard
from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import MCAP0_MAGIC

from service.protocol.keys import parse_key


def ns_of_seconds(t: float) -> int:
    """Unix seconds as the file keeps them (``log_time``, ``publish_time``): whole nanoseconds."""
    return round(float(t) * 1e9)


def seconds_of_ns(ns: int) -> float:
    """... and back, as every reader of a recording gets them."""
    return ns / 1e9

RECORDING_FORMAT = "firetrack-recording/1"
RECORDING_METADATA = "firetrack.recording"
RESUME_ATTACHMENT = "firetrack.resume"


def segment_paths(path) -> list[Path]:
    """The files of a recording in order: ``path`` itself, then ``stem.1.suffix``,
    ``stem.2.suffix``, ... as long as they exist (an empty list when ``path`` does not)."""
    path = Path(path)
    out = []
    k = 0
    while True:
        p = _segment(path, k)
        if not p.is_file():
            return out
        out.append(p)
        k += 1


def next_segment_path(path) -> tuple[int, Path]:
    """The number and file of the segment a new run of the service writes."""
    k = len(segment_paths(path))
    return k, _segment(Path(path), k)


def _segment(path: Path, k: int) -> Path:
    return path if k == 0 else path.with_name(f"{path.stem}.{k}{path.suffix}")


class TruncatedRecordingWarning(UserWarning):
    """The recording ends before its footer (the writer was killed); only its complete chunks were read."""


# ------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, slots=True)
class RecordedMessage:
    key: str
    incident: str
    responder: str
    kind: str
    payload: bytes
    receive_time: float  # Unix s (the file keeps ns: ``receive_time_ns``)
    publish_time: float | None  # Unix s, None when the sample had no timestamp
    receive_time_ns: int


class RecordingReader:
    """An iterator over a recording's messages in receive-time order; see :func:`read_recording`.

    After iteration ``truncated`` tells whether the file ended before its footer (or held a
    corrupt chunk), ``unreadable_bytes`` how many bytes could not be read (corrupt chunks, and
    from a cut to the end), ``stop_reason`` the first problem and ``damage`` every one, as
    ``(byte offset, what)``. A chunk whose CRC or compression is broken is skipped and reading
    goes on with the next one; a cut, or broken framing, ends the reading there.
    """

    def __init__(self, path, kinds=None, responders=None, start=None, ordered: bool = True):
        self.path = Path(path)
        self.ordered = ordered  # False: in the order written (file order), without the receive-time merge
        self.resume: bytes | None = None  # the segment's resume attachment, once read
        self.kinds = None if kinds is None else frozenset(kinds)
        self.responders = None if responders is None else frozenset(responders)
        self.start = start
        self.truncated = False
        self.unreadable_bytes = 0
        self.stop_reason: str | None = None
        self.damage: list[tuple[int, str]] = []  # (byte offset, what is wrong there), in file order
        self.incident: str | None = None
        if not self.path.is_file():
            raise FileNotFoundError(f"recording {self.path} does not exist or is not a file")

        self._gen: Iterator[RecordedMessage] | None = None

    def __iter__(self) -> RecordingReader:
        return self

    def __next__(self) -> RecordedMessage:
        if self._gen is None:  # nothing is read until the first message is asked for
            self._gen = self._messages()
        return next(self._gen)

    def _messages(self) -> Iterator[RecordedMessage]:
        # Pass 1 reads only the records' framing (no decompression): the start time of every
        # chunk. The merge in pass 2 may emit a message once no chunk still to come can hold
        # an earlier one, i.e. when its time is <= the smallest start time of the chunks after
        # the current one. A file written in arrival order makes this a one-chunk look-ahead
        # with bounded memory; a receive clock that stepped back is still put in order.
        starts = [rec.message_start_time for rec, _ in _walk(self.path, self) if isinstance(rec, Chunk)]
        later_min = [0] * len(starts)
        running = 2**64
        for i in range(len(starts) - 1, -1, -1):
            later_min[i] = running
            running = min(running, starts[i])
        start_ns = None if self.start is None else (running if starts else 0) + round(float(self.start) * 1e9)

        channels: dict[int, tuple[str, tuple[str, str, str]]] = {}
        heap: list[tuple[int, int, RecordedMessage]] = []
        order = 0
        chunk_i = 0
        before = 0  # file offset where the current record starts
        for rec, after in _walk(self.path, None):
            if isinstance(rec, Channel):
                channels[rec.id] = (rec.topic, parse_key(rec.topic))
            elif isinstance(rec, Metadata) and rec.name == RECORDING_METADATA:
                self.incident = rec.metadata.get("incident")
            elif isinstance(rec, Attachment) and rec.name == RESUME_ATTACHMENT:
                self.resume = rec.data
            elif isinstance(rec, Chunk):
                if chunk_i >= len(starts):
                    break  # pass 1 found this chunk cut off
                try:
                    items = breakup_chunk(rec, validate_crc=True)
                except _READ_ERRORS as e:  # a corrupt chunk: its messages are lost, the next chunk is read
                    self._damaged(before, after - before, f"chunk at byte {before} ({after - before} bytes): "
                                                          f"{_describe(e)}")
                    items = []
                for item in items:
                    if isinstance(item, Channel):
                        channels[item.id] = (item.topic, parse_key(item.topic))
                    elif isinstance(item, Message):
                        msg = self._message(item, channels, start_ns)
                        if msg is not None:
                            heapq.heappush(heap, ((item.log_time if self.ordered else 0), order, msg))
                            order += 1
                threshold = later_min[chunk_i] if self.ordered else 2**64
                chunk_i += 1
                while heap and heap[0][0] <= threshold:
                    yield heapq.heappop(heap)[2]
            before = after
        while heap:
            yield heapq.heappop(heap)[2]
        if self.truncated:
            warnings.warn(TruncatedRecordingWarning(
                f"recording {self.path} is damaged ({'; '.join(w for _, w in self.damage[:3])}"
                f"{f'; {len(self.damage) - 3} more' if len(self.damage) > 3 else ''}): read what could be read; "
                f"{self.unreadable_bytes} bytes are unreadable"), stacklevel=2)

    def _message(self, item: Message, channels, start_ns) -> RecordedMessage | None:
        try:
            key, (incident, responder, kind) = channels[item.channel_id]
        except KeyError:
            raise McapError(f"recording {self.path}: a message on channel {item.channel_id}, "
                            "which the file never declares") from None
        if (self.kinds is not None and kind not in self.kinds) or \
           (self.responders is not None and responder not in self.responders) or \
           (start_ns is not None and item.log_time < start_ns):
            return None
        return RecordedMessage(
            key=key, incident=incident, responder=responder, kind=kind, payload=item.data,
            receive_time=seconds_of_ns(item.log_time),
            publish_time=None if item.publish_time == item.log_time else seconds_of_ns(item.publish_time),
            receive_time_ns=item.log_time,
        )

    def _stopped(self, offset: int, reason: str) -> None:
        """Reading ends at ``offset``: the rest of the file is unreadable."""
        self._damaged(offset, self.path.stat().st_size - offset, reason)

    def _damaged(self, offset: int, nbytes: int, reason: str) -> None:
        self.truncated = True
        self.unreadable_bytes += nbytes
        self.stop_reason = self.stop_reason or reason
        self.damage.append((offset, reason))


# What a cut-off or damaged file raises inside the mcap reader: a short read (struct.error,
# EndOfFile), a bad length or magic (McapError), a CRC mismatch (ValueError), a broken
# compressed block (zstandard.ZstdError; lz4 raises RuntimeError).
_READ_ERRORS = (McapError, struct.error, EOFError, ValueError, OSError, RuntimeError, zstandard.ZstdError)


def _describe(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}" if str(e) else type(e).__name__


def _walk(path: Path, report: RecordingReader | None) -> Iterator[tuple[object, int]]:
    """Top-level MCAP records, each with the file offset just after it; stops cleanly at a cut.

    Chunks are not decompressed here. When ``report`` is given and the file ends before its
    footer, its ``truncated``, ``unreadable_bytes`` and ``stop_reason`` say where and why.
    """
    good = 0
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        # no record can be longer than the file: a garbage length stops the walk instead of
        # making the reader try to allocate it
        reader = StreamReader(f, emit_chunks=True, validate_crcs=False, record_size_limit=max(size, 64))
        try:
            for record in reader.records:
                good = f.tell()
                yield record, good
        except _READ_ERRORS as e:
            if report is not None:
                # the file ends inside a record (a short read, or a length longer than what is left)
                cut = isinstance(e, (EndOfFile, RecordLengthLimitExceeded, struct.error, EOFError))
                if good == size:  # between two records: the writer stopped before its footer
                    report._stopped(good, f"cut off at byte {good} of {size}: no footer (the writer was stopped)")
                else:
                    report._stopped(good, f"{'cut off' if cut else 'corrupt'} at byte {good} of {size}: {_describe(e)}")


def read_recording(path, kinds: Iterable[str] | None = None, responders: Iterable[str] | None = None,
                   start: float | None = None, segments: bool = True) -> Iterator[RecordedMessage]:
    """Messages of a recording in receive-time order, optionally only some kinds/responders and
    only from ``start`` seconds after the recording's first message.

    Works on a file cut off by a crash: it reads up to the last complete chunk and then stops,
    issuing a :class:`TruncatedRecordingWarning`; the returned reader's ``truncated`` and
    ``unreadable_bytes`` say so too (after iteration). With ``segments`` (the default) a
    recording of several segments is read one segment after the other (each in receive-time
    order; a cut-off segment warns and the next one follows).
    """
    segs = segment_paths(path) if segments else []
    if len(segs) <= 1:
        return RecordingReader(path, kinds, responders, start)
    return SegmentedReader(segs, kinds, responders, start)


class SegmentedReader:
    """The messages of every segment in turn (see :func:`read_recording`); ``truncated`` and
    ``unreadable_bytes`` add up the segments', ``incident`` is the first's."""

    def __init__(self, paths, kinds=None, responders=None, start=None):
        self.paths = list(paths)
        self.readers = [RecordingReader(p, kinds, responders, None) for p in self.paths]
        self.start = start
        self._gen = None

    @property
    def truncated(self) -> bool:
        return any(r.truncated for r in self.readers)

    @property
    def unreadable_bytes(self) -> int:
        return sum(r.unreadable_bytes for r in self.readers)

    @property
    def incident(self) -> str | None:
        return next((r.incident for r in self.readers if r.incident), None)

    def __iter__(self):
        return self

    def __next__(self) -> RecordedMessage:
        if self._gen is None:
            self._gen = self._messages()
        return next(self._gen)

    def _messages(self):
        first = None
        for r in self.readers:
            for m in r:
                if self.start is not None:
                    first = m.receive_time if first is None else first
                    if m.receive_time < first + self.start:
                        continue
                yield m


def recording_summary(path) -> dict:
    """What is in a recording: incident, responders, counts per kind and key, time span.

    A complete file answers from its MCAP summary (statistics + channels) without reading the
    messages; a cut-off one is scanned.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recording {path} does not exist or is not a file")
    segs = segment_paths(path)
    if len(segs) > 1:  # a recording of segments: their summaries added up
        parts = [_file_summary(p) for p in segs]
        per_key: Counter[str] = Counter()
        for part in parts:
            per_key.update(part["keys"])
        starts = [p["start_time"] for p in parts if p["start_time"] is not None]
        ends = [p["end_time"] for p in parts if p["end_time"] is not None]
        out = _summary_dict(path, parts[0]["incident"], dict(per_key), round(min(starts) * 1e9) if starts else None,
                            round(max(ends) * 1e9) if ends else None, truncated=any(p["truncated"] for p in parts),
                            unreadable=sum(p["unreadable_bytes"] for p in parts))
        out["segments"] = [str(p) for p in segs]
        return out
    return _file_summary(path)


def _file_summary(path: Path) -> dict:
    summary = meta = None
    try:
        with open(path, "rb") as f:
            if os.fstat(f.fileno()).st_size > 2 * len(MCAP0_MAGIC):
                f.seek(-len(MCAP0_MAGIC), os.SEEK_END)
                if f.read() == MCAP0_MAGIC:  # a footer can only be read where the file ends properly
                    f.seek(0)
                    summary = make_reader(f).get_summary()
                    meta = next((m for m in make_reader(f).iter_metadata() if m.name == RECORDING_METADATA), None)
    except _READ_ERRORS:
        summary = None  # not readable from its end: scan it below
    if summary is not None and summary.statistics is not None:
        stats = summary.statistics
        per_key = {summary.channels[cid].topic: n for cid, n in stats.channel_message_counts.items()}
        first, last = (stats.message_start_time, stats.message_end_time) if stats.message_count else (None, None)
        return _summary_dict(path, meta.metadata.get("incident") if meta else None, per_key, first, last,
                             truncated=False, unreadable=0)
    reader = read_recording(path, segments=False)
    per_key: Counter[str] = Counter()
    first = last = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordingWarning)  # reported in the dict
        for m in reader:
            per_key[m.key] += 1
            first = m.receive_time_ns if first is None else min(first, m.receive_time_ns)
            last = m.receive_time_ns if last is None else max(last, m.receive_time_ns)
    return _summary_dict(path, reader.incident, dict(per_key), first, last,
                         truncated=reader.truncated, unreadable=reader.unreadable_bytes)


def _summary_dict(path, incident, per_key: dict[str, int], first_ns, last_ns, truncated, unreadable) -> dict:
    kinds: Counter[str] = Counter()
    responders: Counter[str] = Counter()
    for key, n in per_key.items():
        inc, responder, kind = parse_key(key)
        incident = incident or inc
        kinds[kind] += n
        responders[responder] += n
    return {
        "path": str(path),
        "incident": incident,
        "messages": sum(per_key.values()),
        "responders": dict(sorted(responders.items())),
        "kinds": dict(sorted(kinds.items())),
        "keys": dict(sorted(per_key.items())),
        "start_time": None if first_ns is None else first_ns / 1e9,
        "end_time": None if last_ns is None else last_ns / 1e9,
        "duration": 0.0 if first_ns is None else (last_ns - first_ns) / 1e9,
        "truncated": truncated,
        "unreadable_bytes": unreadable,
    }


