"""Reading delimited text logs (plain or gzip) quickly, with exact blame when they are bad.

The fast path hands a whole block of lines to :func:`numpy.loadtxt` (compiled); only when
that fails is the block walked line by line, to name the first bad line and field.
"""
from __future__ import annotations

import io
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from pdr.io._common import Notes, file_must_exist
from pdr.io.errors import RecordingFormatError

GZIP_MAGIC = b"\x1f\x8b"
_SALVAGE_CHUNK = 4096  # bytes fed at a time when recovering the good start of a damaged gzip


def read_text(path: str | Path, notes: Notes) -> str:
    """The file's text, gunzipped when it starts with the gzip magic bytes.

    A gzip stream that stops early (download cut short) or is damaged part-way yields what
    could be decompressed, with a warning; the caller then meets at most one partial last
    line. Newlines are normalised to ``\\n``; undecodable bytes become U+FFFD.
    """
    p = file_must_exist(path)
    if not p.is_file():
        raise RecordingFormatError(p, "not a regular file")
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise RecordingFormatError(p, f"cannot read file: {exc}") from None
    if raw[:2] == GZIP_MAGIC:
        raw = _gunzip(raw, p, notes)
    if not raw.strip():
        raise RecordingFormatError(p, "empty file")
    text = raw.decode("utf-8", errors="replace")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def inflate_member(data: bytes) -> tuple[bytes, bool, bytes, str | None]:
    """(output, member complete, bytes after it, zlib error) for one gzip member."""
    d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
    try:
        out = d.decompress(data) + d.flush()
        return out, d.eof, d.unused_data, None
    except zlib.error as exc:
        error = str(exc)
    # Damaged stream: decompress again in small pieces and keep everything before the damage.
    d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
    parts = []
    for i in range(0, len(data), _SALVAGE_CHUNK):
        try:
            parts.append(d.decompress(data[i : i + _SALVAGE_CHUNK]))
        except zlib.error:
            break
    return b"".join(parts), False, b"", error


def _gunzip(raw: bytes, path: Path, notes: Notes) -> bytes:
    out: list[bytes] = []
    data = raw
    while True:
        chunk, complete, rest, error = inflate_member(data)
        out.append(chunk)
        if not complete:
            got = sum(map(len, out))
            why = f"gzip data damaged ({error})" if error else "gzip stream ends early (file truncated?)"
            if got == 0:
                raise RecordingFormatError(path, f"{why}; nothing could be decompressed")
            notes.warn(f"{why}; kept the {got} bytes decompressed before that")
            break
        if not rest.strip(b"\0"):
            break
        if rest[:2] != GZIP_MAGIC:
            notes.warn(f"{len(rest)} bytes of non-gzip data after the compressed stream ignored")
            break
        data = rest  # concatenated gzip members form one file
    return b"".join(out)


def drop_partial_last_line(
    lines: list[str],
    text: str,
    n_fields: Callable[[str], int | None],
    usecols: Callable[[str], Sequence[int] | None],
    delimiter: str,
    notes: Notes,
) -> None:
    """Blank out the last data line in place when it was cut short.

    A line is taken as cut short when it has fewer fields than its kind needs, or when
    the file does not end with a newline and the line does not parse. ``n_fields(line)``
    gives the expected field count (``None`` for lines the caller ignores anyway) and
    ``usecols(line)`` the numeric columns. Blanking keeps every other line number right.
    """
    j = len(lines) - 1
    while j >= 0 and not lines[j].strip():
        j -= 1
    if j < 0:
        return
    line = lines[j]
    unterminated = not text.endswith("\n")
    expected = n_fields(line)
    if expected is None:
        if unterminated and not _known_prefix(line, delimiter):
            lines[j] = ""
            notes.warn(f"line {j + 1} is incomplete (file ends mid-line); skipped")
        return
    parts = line.split(delimiter)
    cut = len(parts) < expected
    if not cut and unterminated:
        cut = _first_bad_field(parts, usecols(line) or ()) is not None
    if cut:
        lines[j] = ""
        notes.warn(
            f"line {j + 1} looks truncated ({len(parts)} of {expected} fields"
            f"{', no final newline' if unterminated else ''}); skipped"
        )


def _known_prefix(line: str, delimiter: str) -> bool:
    head, sep, _ = line.partition(delimiter)
    return bool(sep) and len(head) == 4 and head.isalnum() and head.isupper()


def _first_bad_field(parts: Sequence[str], usecols: Sequence[int]) -> tuple[int, str] | None:
    for c in usecols:
        if c >= len(parts):
            return c, f"missing field {c + 1}"
        try:
            float(parts[c])
        except ValueError:
            return c, f"field {c + 1} is not a number: {parts[c]!r}"
    return None


def parse_rows(
    rows: list[str],
    usecols: Sequence[int],
    path: str | Path,
    what: str,
    line_of: Callable[[int], int | None],
    delimiter: str,
) -> np.ndarray:
    """Numbers from the columns ``usecols`` of every row, shape (len(rows), len(usecols)).

    Rows may carry extra fields. A row that is short, non-numeric or holds NaN/inf in a
    used column raises :class:`RecordingFormatError` naming ``what`` and the file line
    ``line_of(k)`` of row ``k``.
    """
    usecols = tuple(usecols)
    if not rows:
        return np.empty((0, len(usecols)))
    try:
        arr = np.loadtxt(
            io.StringIO("\n".join(rows)),
            delimiter=delimiter,
            usecols=usecols,
            ndmin=2,
            dtype=np.float64,
            comments=None,
        )
    except ValueError as exc:
        k, problem = _find_bad_row(rows, usecols, delimiter)
        if k is None:
            raise RecordingFormatError(path, f"{what}: cannot read numbers ({exc})") from None
        raise RecordingFormatError(path, f"{what}: {problem}", line=line_of(k)) from None
    if arr.shape[0] != len(rows):  # loadtxt skips blank rows; callers should not pass any
        raise RecordingFormatError(path, f"{what}: {len(rows) - arr.shape[0]} blank row(s) in data")
    finite = np.isfinite(arr)
    if not finite.all():
        k, c = np.argwhere(~finite)[0]
        raise RecordingFormatError(
            path, f"{what}: field {usecols[c] + 1} is {arr[k, c]} (not a finite number)", line=line_of(int(k))
        )
    return arr


def _find_bad_row(rows: list[str], usecols: tuple[int, ...], delimiter: str) -> tuple[int | None, str]:
    need = max(usecols) + 1
    for k, row in enumerate(rows):
        parts = row.split(delimiter)
        if len(parts) < need:
            return k, f"expected at least {need} fields, found {len(parts)}"
        bad = _first_bad_field(parts, usecols)
        if bad is not None:
            return k, bad[1]
    return None, ""
