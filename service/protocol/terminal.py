"""Terminal output shared by the commands: errors without tracebacks, tables, progress, JSON."""
from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

import numpy as np
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
)

T = TypeVar("T")

# results; piped into a file or a log they keep a table's columns whole (rich's default is 80)
out = Console(soft_wrap=True, width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True, soft_wrap=True)  # progress, warnings, errors


def leave_process(code: int = 0):
    """End this process with ``code`` once its work is done and its zenoh sessions are closed,
    without finalising the interpreter (issue 29: clean exits at any size).

    zenoh's runtime threads call into Python (subscriber callbacks) and Python threads call
    into zenoh with the GIL released (a put that blocks under congestion). CPython ends any
    such thread that wants the GIL back while the interpreter finalises with ``pthread_exit``,
    a forced unwind; Rust's ``catch_unwind`` around those frames catches and drops it, and
    glibc aborts the process ("FATAL: exception not rethrown", exit code -6). The more
    wearables a process holds, the likelier one is in flight at that moment: a load generator
    with 500 aborted in 2 of 3 runs on a quiet machine. So a command ends the way a forked
    child does: Python's ``atexit`` handlers run (logging, multiprocessing's children), the
    standard streams are flushed, and ``os._exit`` skips the finalisation the threads cannot
    survive. Whatever must reach a disk is closed by its owner before this (``with`` blocks).
    """
    import atexit
    import os

    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - a closed pipe: nothing more to say
                pass
        os._exit(code)


def fail(message: str) -> None:
    err.print(f"[bold red]error:[/] {message}", highlight=False)


def warn(message: str) -> None:
    err.print(f"[yellow]warning:[/] {message}", highlight=False)


def progress(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """A progress bar on stderr (hidden when stderr is not a terminal)."""
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        console=err, transient=True, disable=not sys.stderr.isatty(),
    ) as bar:
        task = bar.add_task(description, total=total if total is not None else getattr(items, "__len__", lambda: None)())
        for item in items:
            yield item
            bar.advance(task)


def _default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def print_json(obj) -> None:
    sys.stdout.write(json.dumps(obj, default=_default, indent=2) + "\n")
    sys.stdout.flush()


def parse_params(pairs: list[str] | None) -> dict[str, str]:
    """``["k=v", ...]`` -> ``{"k": "v"}``, with a clear error for a malformed pair."""
    params: dict[str, str] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ValueError(f"--param expects name=value, got {pair!r}")
        params[key.strip()] = value.strip()
    return params


class progress_bar:
    """``with progress_bar("replaying") as update: update(done, total)`` — a bar on stderr
    when it is a terminal, nothing otherwise (logs and CI stay clean)."""

    def __init__(self, description: str):
        self._bar = Progress(
            TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            console=err, transient=True, disable=not sys.stderr.isatty(),
        )
        self._description = description
        self._task = None

    def __enter__(self):
        self._bar.__enter__()
        self._task = self._bar.add_task(self._description, total=None)

        def update(done: int, total: int) -> None:
            self._bar.update(self._task, completed=done, total=total)

        return update

    def __exit__(self, *exc):
        return self._bar.__exit__(*exc)


# ------------------------------------------------------------------------------------------
# What every long-running command does the same way
# ------------------------------------------------------------------------------------------
SIGNAL_POLL_S = 0.25  # how long the main thread sleeps at most between looks at a signal


class SignalStop(threading.Event):
    """The stop event of a command. Its ``wait`` sleeps in slices of :data:`SIGNAL_POLL_S`.

    CPython runs a signal's Python handler in the main thread only, and it wakes a main
    thread that is blocked on a lock only when the signal itself interrupts that thread.
    The kernel delivers a process's SIGINT to any thread that does not block it, and
    zenoh's runtime threads (Rust) do not. When one of them takes it, an untimed
    ``Event.wait()`` in the main thread would never return, and Ctrl-C or systemd's stop
    would be lost. Timed slices let the main thread run the handler within a slice."""

    def wait(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = SIGNAL_POLL_S if deadline is None else min(SIGNAL_POLL_S, deadline - time.monotonic())
            if left <= 0:
                return self.is_set()
            if super().wait(left):
                return True


def stop_on_signals() -> SignalStop:
    """An event set by SIGINT or SIGTERM (Ctrl-C, systemd stop). A second Ctrl-C interrupts
    at once (KeyboardInterrupt, which the commands catch and end quietly). Its ``wait``
    returns within :data:`SIGNAL_POLL_S` of a signal, whichever thread the kernel gave it to."""
    stop = SignalStop()

    def handler(signum, frame):
        if stop.is_set():  # a second Ctrl-C: the user means it
            raise KeyboardInterrupt
        err.print(f"\n{signal.Signals(signum).name}: shutting down ...")
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    from service.protocol.early_interrupt import interrupted_early

    if interrupted_early():  # a Ctrl-C during the imports that something swallowed: it still counts
        handler(signal.SIGINT, None)
    return stop


def setup_logging(verbose: bool) -> None:
    """Log lines on stderr; INFO with ``--verbose``, else warnings and errors only. On a
    terminal they are coloured; into a file or journal (systemd) each record is one plain,
    unwrapped line with its time and level."""
    level = logging.INFO if verbose else logging.WARNING
    if sys.stderr.isatty():
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(console=err, show_path=False)
        fmt = "%(message)s"
    else:
        handler = logging.StreamHandler(sys.stderr)
        fmt = "%(asctime)s %(levelname)s %(name)s: %(message)s"
    handler.setFormatter(logging.Formatter(fmt))
    logging.basicConfig(level=level, handlers=[handler], force=True)


def incident_or_exit(config, incident_id: str | None = None):
    """The incident config at ``config`` (default: the IPIN museum demo), under ``incident_id``
    when given; a clear error and exit code 2 when it cannot be read."""
    import typer

    from service.protocol import incident as incidents
    from service.protocol.incident import (
        IncidentConfigError,
        default_incident,
        load_incident,
    )

    if not config and not incidents.DEFAULT_INCIDENT_PATH.is_file():
        fail("no incident config given, and this install has no demo config (deploy/incidents/ is not installed with "
             "the package, e.g. a wearable's `pip install firetrack`): give --config FILE, the incident's config "
             "from the command post")
        raise typer.Exit(2)
    try:
        cfg = load_incident(config) if config else default_incident()
    except IncidentConfigError as e:
        fail(str(e))
        raise typer.Exit(2)
    if incident_id and incident_id != cfg.id:
        cfg = cfg.model_copy(update={"id": incident_id})
    return cfg


def client_or_exit(connect: str | None, wait_s: float = 0.0, tls=None):
    """A zenoh client session to ``connect`` (default: the local router, over TLS with
    ``tls``; a router not up yet is waited for up to ``wait_s``), or one clear line and exit
    code 1."""
    import typer

    from service.protocol.session import open_client
    from service.protocol.tls import TlsConfigError

    try:
        return open_client(connect, wait_s, on_wait=warn, tls=tls)
    except (ConnectionError, TlsConfigError) as e:
        fail(str(e))
        raise typer.Exit(1)


def tls_or_exit(directory, *roles: str, what: str):
    """The identity in ``--tls DIR`` (None without the option) whose role may do ``what``; one
    clear line and exit code 2 when it cannot be used."""
    if directory is None:
        return None
    import typer

    from service.protocol.tls import TlsConfigError, TlsIdentity

    try:
        return TlsIdentity.load(directory).require_role(*roles, what=what)
    except TlsConfigError as e:
        fail(str(e))
        raise typer.Exit(2)


def insecure(what: str) -> None:
    """Say, every time, that this runs without TLS or access control."""
    warn(f"INSECURE: {what} runs without TLS and without access control: any program that reaches its endpoint "
         "can read every position and forge frames, fixes and poses. Fine on one laptop for a demo; at an "
         "incident use --tls (docs/security.md)")


def warn_plan_problems(cfg) -> None:
    """Say at start-up which floor plans cannot be shown (an image not found next to a config
    that was copied elsewhere, say); relative image paths are resolved against the config's
    own folder."""
    for plan in cfg.floor_plans:
        if plan.available and plan.georeferenced:
            continue
        instead = cfg.floor_plan(plan.floor, fallback=True)
        shown = (f"the console shows floor {instead.floor}'s plan instead" if instead is not None and instead.available
                 and instead.georeferenced else "the console draws a grid instead")
        warn(f"floor plan of floor {plan.floor}: {plan.problem or 'no usable georeference'} (image paths are "
             f"relative to the config's folder); {shown}")
