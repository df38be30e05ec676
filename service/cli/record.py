"""``firetrack record`` and ``firetrack replay``: an incident's zenoh traffic to and from MCAP.

``record`` joins a router as a zenoh client, subscribes to ``firetrack/{incident}/**`` and
writes every sample's raw payload with its key and receive time (:mod:`service.review.recorder`).
``replay`` publishes a recording's inputs (``imu`` and ``fix`` unless told otherwise) back to
a router with the recorded timing, so the service downstream sees what it saw live: a
recording, a live stream and a replay go through the same code path.

The zenoh callback runs on zenoh's own threads; it only stamps the receive time and queues the
sample. One thread owns the file (the MCAP writer is not thread-safe) and also closes a chunk
``flush_interval_s`` after its first message when traffic stops, keeping the crash-loss bound
of :class:`service.review.recorder.IncidentRecorder` in wall-clock time too (plus whatever sits in the
queue, normally nothing: the writer keeps up with ~100 000 samples/s through a router).

A replay publishes with encoding ``application/msgpack`` (the channel's message encoding): the
zenoh encoding of each original sample is not stored.
"""
from __future__ import annotations

import queue
import signal
import threading
import time
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import typer
import zenoh

from service.protocol.keys import check_id
from service.protocol.pacing import paced
from service.protocol.session import DEFAULT_ENDPOINT, open_client
from service.protocol.terminal import err, fail, progress, warn
from service.protocol.terminal import out as console
from service.review.recorder import (
    INPUT_KINDS,
    KEY_ROOT,
    IncidentRecorder,
    RecordingWriteError,
    read_recording,
    recording_summary,
)

DEFAULT_CONNECT = DEFAULT_ENDPOINT
POLL_S = 0.05  # how often the writer thread wakes without traffic: stop requests, timed chunk flushes
DRAIN_BATCH = 2000  # samples written between those checks under load (~10 ms of writing)
MSGPACK = "application/msgpack"


class _StopOnSignals:
    """SIGINT/SIGTERM set ``event`` (main thread only: elsewhere signals are not ours to take)."""

    def __init__(self, event: threading.Event):
        self.event = event
        self.saved: dict[int, object] = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.saved[sig] = signal.signal(sig, lambda *_: self.event.set())
        return self

    def __exit__(self, *exc):
        for sig, handler in self.saved.items():
            signal.signal(sig, handler)


# ------------------------------------------------------------------------------------------
# record
# ------------------------------------------------------------------------------------------
def record(
    connect: str,
    incident: str,
    out: Path,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
    *,
    ready: threading.Event | None = None,
    max_messages: int | None = None,
    flush_interval_s: float = 1.0,
    chunk_size: int = 1024 * 1024,
    fsync: bool = False,
    overwrite: bool = False,
    quiet: bool = False,
    tls=None,
) -> dict:
    """Record every sample under ``firetrack/{incident}/**`` until ``duration`` s have passed,
    ``max_messages`` are recorded, ``stop_event`` is set or SIGINT/SIGTERM arrives; returns
    (and prints) a summary.

    ``ready`` is set once the subscription is declared. A sample whose key is not
    ``firetrack/{incident}/{responder}/{kind}`` is not recorded; it is counted in the summary's
    ``rejected`` and warned about once per key. A write failure raises
    :class:`RecordingWriteError` after the session is closed.
    """
    check_id("incident", incident)
    stop = stop_event or threading.Event()
    samples: queue.SimpleQueue = queue.SimpleQueue()

    def on_sample(sample: zenoh.Sample) -> None:
        received = time.time()  # stamped here, on arrival, not when the writer gets to it
        stamp = sample.timestamp
        samples.put((str(sample.key_expr), sample.payload.to_bytes(), received,
                     stamp.get_time_as_ntp64().as_secs_f64() if stamp is not None else None))

    rejected: Counter[str] = Counter()
    started = time.monotonic()
    session = open_client(connect, tls=tls)
    try:
        with IncidentRecorder(out, incident, chunk_size, flush_interval_s, fsync=fsync, overwrite=overwrite) as rec, \
                _StopOnSignals(stop):
            subscriber = session.declare_subscriber(f"{KEY_ROOT}/{incident}/**", on_sample)
            if ready is not None:
                ready.set()
            if not quiet:
                err.print(f"recording incident {incident!r} from {connect} into {out} (Ctrl-C stops)")
            deadline = None if duration is None else started + duration
            try:
                while not stop.is_set() and (deadline is None or time.monotonic() < deadline) \
                        and (max_messages is None or rec.message_count < max_messages):
                    _drain(samples, rec, rejected, POLL_S, DRAIN_BATCH)
                    rec.flush_if_due(time.time())
            finally:
                subscriber.undeclare()
            _drain(samples, rec, rejected, 0.0)  # what arrived before the undeclare
    finally:
        session.close()
    summary = recording_summary(out)
    summary["rejected"] = dict(rejected)
    summary["wall_seconds"] = time.monotonic() - started
    if not quiet:
        _print_summary(summary)
    return summary


def _drain(samples: queue.SimpleQueue, rec: IncidentRecorder, rejected: Counter, wait: float,
           limit: int | None = None) -> None:
    """Write the queued samples (at most ``limit``, so a flood cannot starve the stop checks and
    the chunk timer); wait up to ``wait`` s for the first one."""
    try:
        item = samples.get(timeout=wait) if wait > 0 else samples.get_nowait()
    except queue.Empty:
        return
    written = 0
    while True:
        key, payload, received, published = item
        try:
            rec.write(key, payload, received, published)
        except ValueError as e:  # a key outside the firetrack/{incident}/{responder}/{kind} scheme
            if not rejected[key]:
                warn(f"not recorded: {e}")
            rejected[key] += 1
        written += 1
        if limit is not None and written >= limit:
            return
        try:
            item = samples.get_nowait()
        except queue.Empty:
            return


def _print_summary(summary: dict) -> None:
    console.print(f"[bold]{summary['path']}[/]: {summary['messages']} messages over {summary['duration']:.1f} s "
              f"of incident {summary['incident']!r}", highlight=False)
    for name in ("responders", "kinds"):
        if summary[name]:
            console.print(f"  {name}: " + ", ".join(f"{k} {n}" for k, n in summary[name].items()), highlight=False)
    if summary.get("rejected"):
        console.print(f"  not recorded (bad keys): {sum(summary['rejected'].values())}", highlight=False)


# ------------------------------------------------------------------------------------------
# replay
# ------------------------------------------------------------------------------------------
def replay(
    path: Path,
    connect: str = DEFAULT_CONNECT,
    speed: float = 1.0,
    start: float | None = None,
    responders: Iterable[str] | None = None,
    kinds: Iterable[str] | None = INPUT_KINDS,
    stop_event: threading.Event | None = None,
    *,
    incident: str | None = None,
    wait_for_subscribers_s: float = 2.0,
    quiet: bool = False,
    force: bool = False,
    tls=None,
) -> dict:
    """Publish a recording's messages to a router with the recorded timing divided by ``speed``.

    ``speed`` 0 or inf publishes as fast as the network takes them. ``start`` skips the first
    ``start`` seconds of the recording; ``responders``/``kinds`` select (``kinds=None``: all;
    the default replays only the inputs ``imu`` and ``fix``, so the service recomputes pose and
    status). ``incident`` republishes under another incident name. Publishers are reliable
    with blocking congestion control: a slow network slows the replay instead of dropping.
    Before the first message it waits up to ``wait_for_subscribers_s`` for every key to have a
    subscriber (a warning names those that have none). Returns counts per key and timing.
    """
    if not (speed >= 0):
        raise ValueError(f"speed must be >= 0 (0 or inf: as fast as possible), got {speed}")
    if incident is not None:
        check_id("incident", incident)
    kinds = None if kinds is None else tuple(kinds)
    responders = None if responders is None else tuple(responders)
    summary = recording_summary(path)
    keys = [k for k in summary["keys"] if _selected(k, responders, kinds)]
    if not keys:
        raise ValueError(f"recording {path} has no messages of kinds {kinds or 'any'} and responders "
                         f"{responders or 'any'}; it has kinds {sorted(summary['kinds'])} and responders "
                         f"{sorted(summary['responders'])}")
    total = None if start is not None else sum(summary["keys"][k] for k in keys)
    stop = stop_event or threading.Event()
    counts: Counter[str] = Counter()
    session = open_client(connect, tls=tls)
    try:
        if not force and any(k.endswith("/imu") for k in keys):  # frames: the service keeps their seqs
            target = incident or summary["incident"] or keys[0].split("/")[1]
            tracked = _already_tracked(session, target, {r for r in summary["responders"]
                                                         if responders is None or r in responders}, stop)
            if tracked:
                names = ", ".join(f"{r} ({n} frames)" for r, n in sorted(tracked.items()))
                raise ValueError(
                    f"the service already tracks {names} in incident {target!r}: the same frames again would be "
                    f"rejected as duplicates. Replay under a new incident id (--as-incident {target}-replay), "
                    f"or restart the service; --force replays anyway")
        publishers = {k: session.declare_publisher(
            _retarget(k, incident), encoding=MSGPACK, congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE) for k in keys}
        unmatched = _wait_for_subscribers(publishers, wait_for_subscribers_s, stop)
        if unmatched and not quiet:
            warn(f"no subscriber yet for {', '.join(_retarget(k, incident) for k in unmatched)}; publishing anyway")
        reader = read_recording(path, kinds=kinds, responders=responders, start=start)
        began = time.monotonic()
        with _StopOnSignals(stop):
            messages = reader if quiet else progress(reader, f"replaying {Path(path).name}", total=total)
            for msg in paced(messages, speed, stop, time_of=lambda m: m.receive_time):
                publishers[msg.key].put(msg.payload)
                counts[msg.key] += 1
        elapsed = time.monotonic() - began
        unheard = sorted(_retarget(k, incident) for k, p in publishers.items()
                         if counts[k] and not p.matching_status.matching)
    finally:
        session.close()
    result = {
        "path": str(path), "messages": sum(counts.values()), "keys": dict(sorted(counts.items())),
        "unheard_keys": unheard,
        "seconds": elapsed, "speed": speed, "stopped": stop.is_set(),
        "truncated": reader.truncated, "unreadable_bytes": reader.unreadable_bytes,
    }
    if not quiet:
        console.print(f"replayed {result['messages']} messages from {path} in {elapsed:.1f} s", highlight=False)
        if unheard:
            target = incident or summary["incident"] or keys[0].split("/")[1]
            warn(f"nobody was subscribed to {', '.join(unheard)} at the end: those messages went nowhere "
                 f"(is `firetrack serve` running, and for incident {target!r}?)")
    return result


def _selected(key: str, responders, kinds) -> bool:
    _, _, responder, kind = key.split("/")
    return (kinds is None or kind in kinds) and (responders is None or responder in responders)


def _retarget(key: str, incident: str | None) -> str:
    if incident is None:
        return key
    root, _, responder, kind = key.split("/")
    return f"{root}/{incident}/{responder}/{kind}"


STATUS_LISTEN_S = 1.5  # s a replay listens for the service's Status before it publishes (Status comes at 1 Hz)


def _already_tracked(session, incident: str, responders: set[str], stop: threading.Event) -> dict[str, int]:
    """Responders of the recording that a live service already tracks in ``incident``, with the
    frames it has of them (from its once-a-second Status)."""
    from service.protocol import wire

    seen: dict[str, int] = {}

    def on_status(sample) -> None:
        try:
            st = wire.decode(sample.payload.to_bytes(), expect=wire.Status)
        except wire.WireError:
            return
        if st.responder in responders and st.frames > 0:
            seen[st.responder] = st.frames

    sub = session.declare_subscriber(wire.key_all(incident, "status"), on_status)
    try:
        stop.wait(STATUS_LISTEN_S)
    finally:
        sub.undeclare()
    return dict(seen)


def _wait_for_subscribers(publishers: dict, timeout: float, stop: threading.Event) -> list[str]:
    deadline = time.monotonic() + timeout
    while True:
        unmatched = [k for k, p in publishers.items() if not p.matching_status.matching]
        if not unmatched or time.monotonic() >= deadline or stop.wait(0.02):
            return unmatched


# ------------------------------------------------------------------------------------------
# typer commands (registered by client/cli.py)
# ------------------------------------------------------------------------------------------
TLS_HELP = ("mutual TLS with this identity directory (a service certificate: the router lets it read and publish every "
            "key of the incident); TLS only")


def record_command(
    connect: str = typer.Option(None, "--connect", help=f"zenoh router endpoint (default {DEFAULT_CONNECT}, "
                                                        "tls/127.0.0.1:7447 with --tls)"),
    incident: str = typer.Option(..., "--incident", help="incident name: records firetrack/{incident}/**"),
    out_file: Path = typer.Option(..., "--out", help="MCAP file to write (refuses to overwrite unless --overwrite)"),
    seconds: float = typer.Option(None, "--seconds", help="stop after this many seconds (default: until Ctrl-C)"),
    flush_interval: float = typer.Option(1.0, "--flush-interval", help="a crash loses at most this many seconds of messages"),
    fsync: bool = typer.Option(False, "--fsync", help="fsync each chunk (survives a power cut too)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file"),
    tls: Path = typer.Option(None, "--tls", help=TLS_HELP),
):
    """Record every message of an incident into an MCAP file, as it was on the wire."""
    from service.protocol.terminal import insecure, tls_or_exit

    identity = tls_or_exit(tls, "service", what="record")
    if identity is None:
        insecure("firetrack record")
    try:
        record(connect, incident, out_file, seconds, flush_interval_s=flush_interval, fsync=fsync, overwrite=overwrite,
               tls=identity)
    except (RecordingWriteError, ConnectionError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(1)


def replay_command(
    file: Path = typer.Argument(..., help="an MCAP recording made by firetrack record"),
    speed: float = typer.Option(1.0, "--speed", help="time factor; 0 = as fast as possible"),
    from_s: float = typer.Option(None, "--from", help="skip this many seconds from the recording's start"),
    responder: list[str] = typer.Option(None, "--responder", help="only this responder; repeat for more"),
    kind: list[str] = typer.Option(None, "--kind", help="kinds to publish (default: imu, fix); repeat for more"),
    connect: str = typer.Option(None, "--connect", help=f"zenoh router endpoint (default {DEFAULT_CONNECT}, "
                                                        "tls/127.0.0.1:7447 with --tls)"),
    as_incident: str = typer.Option(None, "--as-incident", help="publish under this incident name instead"),
    force: bool = typer.Option(False, "--force", help="replay even when the service already tracks these responders"),
    tls: Path = typer.Option(None, "--tls", help=TLS_HELP),
):
    """Publish a recording's inputs (imu, fix, operator actions) back to a router with their recorded timing."""
    from service.protocol.terminal import insecure, tls_or_exit

    identity = tls_or_exit(tls, "service", what="replay (it publishes as every recorded responder)")
    if identity is None:
        insecure("firetrack replay")
    try:
        result = replay(file, connect, speed, from_s, responder or None, tuple(kind) if kind else INPUT_KINDS,
                        incident=as_incident, force=force, tls=identity)
    except (ConnectionError, ValueError, OSError) as e:
        fail(str(e))
        raise typer.Exit(1)
    if result["unheard_keys"]:  # said above; a script sees it in the exit code, as with `wearable`
        raise typer.Exit(1)
