"""Incident recordings on real files: round trip, filters, ordering, crash safety, write errors."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import msgpack
import numpy as np
import pytest

from service.review.recorder import (
    IncidentRecorder,
    RecordingWriteError,
    TruncatedRecordingWarning,
    read_recording,
    recording_summary,
)

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("imu", "fix", "pose", "status")


def _messages(n: int, incident: str = "demo", seed: int = 0, t0: float = 1.7e9):
    """n messages across 3 responders x 4 kinds with msgpack payloads of varied size."""
    rng = np.random.default_rng(seed)
    t = t0 + np.cumsum(rng.uniform(0.0, 0.02, n))
    out = []
    for i in range(n):
        responder, kind = f"ff{i % 3}", KINDS[(i // 3) % 4]
        payload = msgpack.packb({"i": i, "data": rng.normal(size=int(rng.integers(1, 30))).tolist()})
        publish = None if i % 5 == 0 else float(t[i] - 0.003)
        out.append((f"firetrack/{incident}/{responder}/{kind}", payload, float(t[i]), publish))
    return out


def _write(path, messages, **kw):
    with IncidentRecorder(path, "demo", **kw) as rec:
        for m in messages:
            rec.write(*m)
    return rec


def test_round_trip_identical_in_order(tmp_path):
    msgs = _messages(3000)
    rec = _write(tmp_path / "a.mcap", msgs, chunk_size=16 * 1024, flush_interval_s=0.5)
    assert rec.healthy and rec.error is None and rec.flushed_count == len(msgs)
    back = list(read_recording(tmp_path / "a.mcap"))
    assert [(m.key, m.payload) for m in back] == [(k, p) for k, p, _, _ in msgs]
    np.testing.assert_allclose([m.receive_time for m in back], [t for _, _, t, _ in msgs], atol=1e-6, rtol=0)
    for m, (key, _, _, pub) in zip(back, msgs):
        assert (m.publish_time is None) == (pub is None)
        if pub is not None:
            assert abs(m.publish_time - pub) < 1e-6
        _, incident, responder, kind = key.split("/")
        assert (m.incident, m.responder, m.kind) == (incident, responder, kind)

    summary = recording_summary(tmp_path / "a.mcap")
    assert summary["incident"] == "demo" and summary["messages"] == len(msgs)
    assert summary["truncated"] is False and summary["unreadable_bytes"] == 0
    assert summary["kinds"] == {k: sum(1 for m in msgs if m[0].endswith("/" + k)) for k in sorted(KINDS)}
    assert summary["responders"] == {r: sum(1 for m in msgs if f"/{r}/" in m[0]) for r in ("ff0", "ff1", "ff2")}
    assert summary["duration"] == pytest.approx(msgs[-1][2] - msgs[0][2], abs=1e-6)


def test_filters_and_start(tmp_path):
    msgs = _messages(600)
    _write(tmp_path / "a.mcap", msgs, chunk_size=4096)
    got = list(read_recording(tmp_path / "a.mcap", kinds=("imu", "fix"), responders=["ff1"], start=2.0))
    t0 = msgs[0][2]
    want = [m for m in msgs if m[0].split("/")[3] in ("imu", "fix") and m[0].split("/")[2] == "ff1" and m[2] - t0 >= 2.0 - 1e-9]
    assert want and [(m.key, m.payload) for m in got] == [(k, p) for k, p, _, _ in want]


def test_receive_clock_stepping_back_is_read_in_time_order(tmp_path):
    """Messages land in file order; a clock step back across chunks must still come out sorted."""
    msgs = _messages(400)
    step = [(k, p, t - (30.0 if i >= 200 else 0.0), None) for i, (k, p, t, _) in enumerate(msgs)]
    _write(tmp_path / "a.mcap", step, chunk_size=2048)
    back = list(read_recording(tmp_path / "a.mcap"))
    times = [m.receive_time_ns for m in back]
    assert times == sorted(times) and len(back) == len(step)
    assert {m.payload for m in back} == {p for _, p, _, _ in step}


def test_chunks_close_by_receive_time_and_by_timer(tmp_path):
    with IncidentRecorder(tmp_path / "a.mcap", "demo", chunk_size=1 << 20, flush_interval_s=1.0) as rec:
        rec.write("firetrack/demo/a/imu", b"\x01", 100.0)
        rec.write("firetrack/demo/a/imu", b"\x02", 100.5)
        assert rec.unflushed_count == 2
        rec.write("firetrack/demo/a/imu", b"\x03", 101.0)  # spans 1 s of receive time: chunk closes
        assert rec.unflushed_count == 0 and rec.flushed_count == 3
        rec.write("firetrack/demo/a/imu", b"\x04", 102.0)
        assert not rec.flush_if_due(102.9) and rec.unflushed_count == 1
        assert rec.flush_if_due(103.0) and rec.unflushed_count == 0
        # by size: the writer ends the chunk itself once it exceeds chunk_size
    with IncidentRecorder(tmp_path / "b.mcap", "demo", chunk_size=1000, flush_interval_s=60.0) as rec:
        for i in range(20):
            rec.write("firetrack/demo/a/imu", bytes(300), 200.0 + i * 1e-3)
            assert rec.unflushed_count * 331 <= 1000 + 331  # records of 31 bytes + payload


def test_bad_input_is_refused_with_the_key_named(tmp_path):
    with IncidentRecorder(tmp_path / "a.mcap", "demo") as rec:
        with pytest.raises(ValueError, match="firetrack/demo/ff1"):
            rec.write("firetrack/demo/ff1", b"x", 1.0)
        with pytest.raises(ValueError, match="incident 'other'"):
            rec.write("firetrack/other/ff1/imu", b"x", 1.0)
        with pytest.raises(ValueError, match="receive_time"):
            rec.write("firetrack/demo/ff1/imu", b"x", float("nan"))
        with pytest.raises(TypeError, match="bytes"):
            rec.write("firetrack/demo/ff1/imu", {"not": "bytes"}, 1.0)
        assert rec.healthy and rec.message_count == 0
    with pytest.raises(ValueError, match="incident"):
        IncidentRecorder(tmp_path / "b.mcap", "a/b")


# ------------------------------------------------------------------------------------------
# Crash safety
# ------------------------------------------------------------------------------------------
CHILD = """
import sys, time
from service.review.recorder import IncidentRecorder
interval = float(sys.argv[2])
with IncidentRecorder(sys.argv[1], "crash", chunk_size=1 << 20, flush_interval_s=interval) as rec:
    i = 0
    while True:
        t = time.time()
        rec.write(f"firetrack/crash/ff{i % 3}/imu", i.to_bytes(8, "little") + bytes(40), t)
        i += 1
        print(i, rec.flushed_count, repr(t), flush=True)
        time.sleep(0.0005)
"""


def test_sigkill_loses_at_most_the_unfinished_chunk(tmp_path):
    path, interval = tmp_path / "crash.mcap", 0.02
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(interval)], cwd=ROOT,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            line = child.stdout.readline()
            if not line:
                break
            lines.append(line)
            if len(lines) >= 400:
                break
        os.kill(child.pid, signal.SIGKILL)
        rest, errors = child.communicate(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == -signal.SIGKILL, errors
    lines += rest.splitlines(keepends=True)
    rows = [tuple(line.split()) for line in lines if line.endswith("\n")]
    assert len(rows) >= 400, errors
    written = [int(r[0]) for r in rows]
    flushed = [int(r[1]) for r in rows]
    times = [float(r[2]) for r in rows]
    n_printed, flushed_at_last_print = written[-1], flushed[-1]

    reader = read_recording(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        back = list(reader)
    m = len(back)
    # a prefix, byte for byte
    assert [b.payload for b in back] == [i.to_bytes(8, "little") + bytes(40) for i in range(m)]
    assert reader.truncated and reader.unreadable_bytes >= 0
    assert any(issubclass(w.category, TruncatedRecordingWarning) for w in caught)
    assert recording_summary(path)["truncated"] is True
    # everything the child had seen flushed is there; at most one unprinted message was written
    assert flushed_at_last_print <= m <= n_printed + 1
    # the bound: what was lost lay in one unfinished chunk, spanning < flush_interval of receive time
    if m < n_printed:
        assert times[n_printed - 1] - times[m] < interval
    print(f"\nSIGKILL: {n_printed} written (printed), {m} readable, lost {n_printed - m} "
          f"(bound: < {interval} s of receive time = {sum(1 for t in times if t > times[-1] - interval)} messages here); "
          f"{reader.unreadable_bytes} bytes unreadable")


def test_a_corrupt_chunk_is_skipped_named_and_the_rest_is_read(tmp_path):
    path = tmp_path / "a.mcap"
    msgs = _messages(2000)
    _write(path, msgs, chunk_size=4096)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    for i in range(64):  # inside some chunk's compressed data (a chunk is about 12 kB here)
        data[mid + i] ^= 0xFF
    path.write_bytes(bytes(data))
    reader = read_recording(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        back = list(reader)
    (offset, what), = reader.damage
    assert reader.truncated and "CRC" in what and offset <= mid and f"chunk at byte {offset}" in what
    assert 0 < reader.unreadable_bytes < len(data) // 4 and any("damaged" in str(w.message) for w in caught)
    payloads = [p for _, p, _, _ in msgs]
    got = [b.payload for b in back]
    # a prefix, one chunk's messages missing, then the rest to the end
    k = next(i for i, (a, b) in enumerate(zip(got, payloads)) if a != b)
    assert got[k:] == payloads[len(payloads) - (len(got) - k):] and 0 < len(payloads) - len(got) < 500


def test_empty_and_garbage_files(tmp_path):
    _write(tmp_path / "empty.mcap", [])
    assert list(read_recording(tmp_path / "empty.mcap")) == []
    assert recording_summary(tmp_path / "empty.mcap")["messages"] == 0
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    reader = read_recording(tmp_path / "junk.mcap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordingWarning)
        assert list(reader) == []
    assert reader.truncated and reader.unreadable_bytes == len(b"not an mcap file at all")
    with pytest.raises(FileNotFoundError, match="nothere"):
        read_recording(tmp_path / "nothere.mcap")


# ------------------------------------------------------------------------------------------
# Write errors
# ------------------------------------------------------------------------------------------
@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="/dev/full (always-full device) is Linux-only")
def test_full_disk_raises_a_clear_error():
    with pytest.raises(RecordingWriteError, match=r"/dev/full.*No space left on device \(ENOSPC\)"):
        IncidentRecorder("/dev/full", "demo", overwrite=True)


FULL_CHILD = """
import json, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit then fails with EFBIG instead of killing
resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))
from service.review.recorder import IncidentRecorder, RecordingWriteError
rec = IncidentRecorder(sys.argv[1], "demo", chunk_size=2048)
try:
    for i in range(100000):
        rec.write(f"firetrack/demo/ff{i % 2}/imu", i.to_bytes(8, "little") + bytes(100), 1000.0 + i * 1e-3)
    print(json.dumps({"error": None}))
except RecordingWriteError as e:
    first = dict(error=str(e), errno=e.errno, healthy=rec.healthy, rec_error=rec.error, flushed=rec.flushed_count, written=rec.message_count)
    try:
        rec.write("firetrack/demo/ff0/imu", b"x", 2000.0)
        again = None
    except RecordingWriteError as e2:
        again = str(e2)
    rec.close()
    print(json.dumps(dict(first, again=again)))
"""


def test_disk_filling_mid_recording(tmp_path):
    """A file-size limit (works as root too) fills the 'disk' after some chunks."""
    path = tmp_path / "full.mcap"
    done = subprocess.run([sys.executable, "-c", FULL_CHILD, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["error"] and "File too large (EFBIG)" in report["error"] and str(path) in report["error"]
    assert report["errno"] == 27 and report["healthy"] is False and report["rec_error"] == report["error"]
    assert report["again"] == report["error"]  # stays failed, never silently goes on
    reader = read_recording(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordingWarning)
        back = list(reader)
    # everything flushed is there; the chunk being written when the disk filled may be too if
    # only its index failed (so may the message whose write raised: it crossed the chunk size)
    assert 0 < report["flushed"] <= len(back) <= report["written"] + 1
    assert [b.payload[:8] for b in back] == [i.to_bytes(8, "little") for i in range(len(back))]


def test_unwritable_paths(tmp_path):
    (tmp_path / "a.mcap").write_bytes(b"precious")
    with pytest.raises(RecordingWriteError, match="already exists"):
        IncidentRecorder(tmp_path / "a.mcap", "demo")
    assert (tmp_path / "a.mcap").read_bytes() == b"precious"
    with pytest.raises(RecordingWriteError, match="No such file or directory"):
        IncidentRecorder(tmp_path / "missing" / "a.mcap", "demo")
    with pytest.raises(RecordingWriteError, match="Is a directory"):
        IncidentRecorder(tmp_path, "demo", overwrite=True)
    rec = IncidentRecorder(tmp_path / "b.mcap", "demo")
    rec.close()
    with pytest.raises(RecordingWriteError, match="closed"):
        rec.write("firetrack/demo/ff0/imu", b"x", 1.0)
    assert not rec.healthy and "closed" in rec.error


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores directory permissions")
def test_read_only_directory(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(RecordingWriteError, match="Permission denied"):
            IncidentRecorder(ro / "a.mcap", "demo")
    finally:
        ro.chmod(0o755)


def test_a_receive_time_stamped_as_recorded_is_read_back_to_the_bit(tmp_path):
    """The file keeps whole nanoseconds: a clock reading of today goes through ``round(t·1e9)``
    and ``/1e9``, and some come back one ulp off. The shell stamps inputs with
    :func:`as_recorded`, which the recording gives back exactly (live = reprocess)."""
    from service.review.recorder import as_recorded

    rng = np.random.default_rng(3)
    raw = sorted((time.time() + rng.uniform(-3e7, 3e7, 2000)).tolist())  # a recording reads back in time order
    stamped = [as_recorded(t) for t in raw]
    path = tmp_path / "t.mcap"
    with IncidentRecorder(path, "demo") as rec:
        for i, t in enumerate(stamped):
            rec.write("firetrack/demo/ff1/imu", msgpack.packb(i), t)
    back = [m.receive_time for m in read_recording(path)]
    assert back == stamped
    assert all(abs(a - b) <= 1e-6 for a, b in zip(raw, stamped))  # a nanosecond's rounding at most, in ulps
    assert sum(round(t * 1e9) / 1e9 != t for t in raw) > 0  # the raw readings would not all come back
