"""``firetrack serve``: the live service of one incident (router, service, recorder, console).

``--record x.mcap`` on a recording that exists (a restart after a crash, systemd's
``Restart=``) resumes: the incident's state is rebuilt from the newest snapshot beside it
(``x.mcap.state``) and the messages recorded after it, and the service writes the next
segment (``x.1.mcap``, ...); see :mod:`service.review.resume`. It never refuses to start
over what is there.

The console is the client layer's (``client/console``): the top of the house, where the
``firetrack`` command is assembled (``client/cli.py``), hands its starter to
:func:`set_console_starter`, so this module never imports the client.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import typer

from service.protocol.session import DEFAULT_ENDPOINT, default_endpoint
from service.protocol.terminal import (
    err,
    fail,
    incident_or_exit,
    insecure,
    out,
    setup_logging,
    stop_on_signals,
    tls_or_exit,
    warn,
    warn_plan_problems,
)

_console_starter: Callable | None = None  # (session, cfg, port, security) -> an object with close(); raises ValueError


def set_console_starter(starter: Callable) -> None:
    """Who serves the web console beside the service (set by ``client/cli.py``)."""
    global _console_starter
    _console_starter = starter


def serve_command(
    listen: list[str] = typer.Option(None, "--listen", help=f"endpoint(s) to listen on (default {DEFAULT_ENDPOINT}: an in-process router)"),
    connect: list[str] = typer.Option(None, "--connect", help="join a standalone zenoh router instead (e.g. tcp/10.0.0.2:7447)"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's, 'demo' for the demo)"),
    config: Path = typer.Option(None, "--config", help="incident config (JSON or TOML); default: the IPIN museum demo"),
    record: Path = typer.Option(None, "--record", help="record every message of the incident to this MCAP file "
                                                       "(if it exists: resume the incident from it and write the next segment)"),
    console: bool = typer.Option(True, "--console/--no-console", help="also serve the web console"),
    port: int = typer.Option(8080, "--port", help="web console port"),
    seconds: float = typer.Option(math.inf, "--seconds", help="stop after this long (default: until Ctrl-C)"),
    workers: int = typer.Option(1, "--workers", help="worker processes sharing the responders (one per core)"),
    shard: str = typer.Option(None, "--shard", help="i/N: serve only the responders whose id hashes to shard i of N "
                                                    "(N serve processes, one per shard, on one machine or several "
                                                    "joined by a router mesh; see deploy/README.md)"),
    standby: bool = typer.Option(False, "--standby", help="stand by for the service of this incident (or --shard part): "
                                                          "follow its snapshots, take over when it is gone; needs "
                                                          "--connect (a router of its own)"),
    catch_all: bool = typer.Option(False, "--catch-all", help="with --workers > 1: also hear sources that declare no "
                                                              "presence token (a replay, a third-party device); every "
                                                              "frame then reaches every worker"),
    max_responders: int = typer.Option(1024, "--max-responders", help="responders kept at once; new ids beyond are refused"),
    admit_burst: float = typer.Option(256, "--admit-burst", help="new responder ids admitted at once ..."),
    admit_per_s: float = typer.Option(2.0, "--admit-per-s", help="... and per second after that"),
    roster_only: bool = typer.Option(False, "--roster-only", help="admit the roster's responders only (the incident "
                                                                  "config's roster and, with --tls, the wearables of the "
                                                                  "incident roster); they are always admitted"),
    expire_after: float = typer.Option(1800.0, "--expire-after", help="s of silence after which a responder leaves "
                                                                        "(its track stays in the recording)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log every responder, fix and reject"),
    tls: Path = typer.Option(None, "--tls", help="mutual TLS with this service identity (firetrack certs issue "
                                                 "--role service): TLS only, access control from the roster"),
    roster: Path = typer.Option(None, "--roster", help="the incident roster (default: roster.json beside the --tls directory)"),
    foxglove: int = typer.Option(None, "--foxglove", help="also run a live Foxglove WebSocket server on this port (8765 is "
                                                          "Foxglove's usual; 0: any free port): connect Foxglove to "
                                                          "ws://HOST:PORT; needs the [foxglove] extra"),
    foxglove_host: str = typer.Option("127.0.0.1", "--foxglove-host", help="address the Foxglove server listens on"),
):
    """Run the service for one incident: one pipeline per responder, poses and status out."""
    setup_logging(verbose)
    _workers_or_exit(workers)
    part = shard_or_exit(shard, workers)
    identity = tls_or_exit(tls, "service", what="serve")
    security = security_or_exit(identity, roster, incident_id, router=not connect)
    cfg = incident_or_exit(config, incident_id or (security.roster.incident if security and security.roster else None))
    warn_plan_problems(cfg)
    settings = _service_settings(cfg, security, max_responders, admit_burst, admit_per_s, roster_only, expire_after)
    settings.catch_all = catch_all
    if standby and (not connect or workers > 1 or record is not None):
        fail("--standby needs --connect (the router must outlive the primary), one worker and no --record")
        raise typer.Exit(2)
    if workers > 1 and record is not None:
        fail("--record records one process's inputs; with --workers > 1 run `firetrack record` beside the service")
        raise typer.Exit(2)
    stop = stop_on_signals()  # before the warning: a Ctrl-C from here on is this command's stop
    if security is None:
        insecure("firetrack serve")
    if foxglove is not None and not 0 <= foxglove <= 65535:
        fail(f"--foxglove must be a port number (0-65535), got {foxglove}")
        raise typer.Exit(2)
    _exit_if_stuck(stop)
    with running_service(cfg, listen, connect, record, console, port, settings=settings, workers=workers,
                         security=security, stop=stop, shard=part, standby=standby,
                         foxglove=(foxglove_host, foxglove) if foxglove is not None else None) as (svc, where):
        out.print(f"[bold]firetrack[/] serving incident [bold]{cfg.id}[/] ({cfg.name}) on {where}"
                  + (f" as {identity.name}, mutual TLS" if identity else "")
                  + (f", shard {part[0]}/{part[1]}" if part else ""))
        if console:
            out.print(f"console: {svc.console_url or f'http://127.0.0.1:{port}/'}")
        if svc.foxglove_url:
            out.print(f"foxglove: {svc.foxglove_url} (Foxglove: Open connection, Foxglove WebSocket)")
        fenced = _serve_until(stop, seconds, svc.fence)
    if fenced:
        e, nonce = svc.fence.fenced_by
        out.print(f"stood down: the service of epoch {e} ({nonce}) serves this part of the incident now; "
                  f"{svc.fenced_dropped} message(s) not published")
        raise typer.Exit(3)
    out.print(f"stopped; {len(svc.responders)} responder(s), {svc.frames_processed} frames processed"
              + (f"; frames heard: {svc.heard['own']} of this shard's, {svc.heard['others']} of others'" if part else ""))


def _serve_until(stop, seconds: float, fence) -> bool:
    """Until a stop signal or ``seconds`` (False), or until a service of a higher epoch took
    this one's part over (True: the service has stopped publishing)."""
    deadline = time.monotonic() + seconds
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or stop.wait(min(0.2, left)):
            return False
        if fence is not None and fence.fenced.is_set():
            return True


def shard_or_exit(shard: str | None, workers: int) -> tuple[int, int] | None:
    """``--shard i/N`` as ``(i, N)`` with 0 <= i < N, or one line and exit code 2."""
    if shard is None:
        return None
    try:
        i, n = (int(x) for x in shard.split("/"))
    except ValueError:
        i = n = -1
    if not 0 <= i < n:
        fail(f"--shard must be i/N with 0 <= i < N (e.g. 0/2), got {shard!r}")
        raise typer.Exit(2)
    if workers > 1:
        fail("--shard is one process's part; it does not combine with --workers (run one process per shard)")
        raise typer.Exit(2)
    return i, n


STOP_GRACE_S = 15.0  # s after SIGTERM/SIGINT within which serve has ended, whatever it was doing


def _workers_or_exit(workers: int) -> None:
    """``--workers`` within 1 .. the cores this process may use (one worker per core: more only
    make processes fight for them), or one line and exit code 2."""
    from service.shell.workers import usable_cores

    cores = usable_cores()
    if not 1 <= workers <= cores:
        fail(f"--workers must be between 1 and {cores} (the cores this machine gives serve), got {workers}")
        raise typer.Exit(2)


def _exit_if_stuck(stop) -> None:
    """After a stop signal, the process ends within :data:`STOP_GRACE_S` even if shutting down
    hangs (a worker that will not stop, a router that will not close): exit code 1, and the
    worker processes die with it (:func:`service.shell.workers.die_with_parent`)."""
    import os
    import threading

    def watch() -> None:
        stop.wait(None)
        time.sleep(STOP_GRACE_S)
        err.print(f"still shutting down {STOP_GRACE_S:g} s after the signal: exiting now", highlight=False)
        os._exit(1)

    threading.Thread(target=watch, name="firetrack-stop-watchdog", daemon=True).start()


def _service_settings(cfg, security, max_responders, admit_burst, admit_per_s, roster_only, expire_after):
    """The service's settings from the command's isolation options (errors name the option). The
    intake's roster: the responders of the incident config's roster and, with ``--tls`` and an
    incident roster, its wearable identities."""
    import dataclasses

    from service.core.intake import IntakeSettings
    from service.shell.service import ServiceSettings

    ids = {m.id for m in cfg.roster}
    if security is not None and security.roster is not None:
        ids |= {name for name, ident in security.roster.identities.items() if ident.role == "wearable"}
    if roster_only and not ids:
        fail("--roster-only needs a roster: the incident config's (roster) or, with --tls, the incident roster's wearables")
        raise typer.Exit(2)
    try:
        intake = IntakeSettings(max_responders=max_responders, admit_burst=admit_burst, admit_per_s=admit_per_s,
                                roster=frozenset(ids) or None, roster_only=roster_only)
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    if not expire_after > 0:
        fail(f"--expire-after must be positive (s), got {expire_after}")
        raise typer.Exit(2)
    base = ServiceSettings()
    core = dataclasses.replace(base.core, intake=intake, expire_after_s=expire_after,
                               expire_unplaced_s=min(base.core.expire_unplaced_s, expire_after))
    return dataclasses.replace(base, core=core)


class Security:
    """What ``--tls`` sets up: the service's identity, the roster (None: no run-time policy)
    and where it was read."""

    def __init__(self, identity, roster=None, roster_path: Path | None = None):
        self.identity, self.roster, self.roster_path = identity, roster, roster_path

    def acl(self, incident: str) -> dict | None:
        from service.protocol.access import access_control

        return access_control(self.roster, incident) if self.roster is not None else None

    def access(self):
        from service.protocol.access import access_message

        return access_message(self.roster, str(self.roster_path)) if self.roster is not None else None


def security_or_exit(identity, roster_path: Path | None, incident: str | None, router: bool) -> Security | None:
    """The identity with its roster, or one clear line and exit code 2. A service that is the
    router needs the roster (its access control comes from it); joining a standalone router
    (whose config carries the rules) it is optional: without it the service enforces no
    revocations."""
    if identity is None:
        if roster_path is not None:
            fail("--roster is read with --tls only")
            raise typer.Exit(2)
        return None
    from service.protocol.access import RosterError, load_roster

    path = roster_path or identity.roster_path()
    if path is None:
        if router:
            fail(f"--tls {identity.dir}: the in-process router needs the incident roster for its access control "
                 "(roster.json beside the identity directory, or --roster FILE)")
            raise typer.Exit(2)
        warn("no incident roster: the router's access control applies, but the service enforces no revocations")
        return Security(identity)
    try:
        roster = load_roster(path)
    except RosterError as e:
        fail(str(e))
        raise typer.Exit(2)
    if incident and incident != roster.incident:
        fail(f"--incident {incident!r}, but the roster {path} is for incident {roster.incident!r}: the router's rules "
             "cover firetrack/{roster's incident}/** only")
        raise typer.Exit(2)
    return Security(identity, roster, Path(path))


class running_service:
    """Context manager: session (router or client), service, optional recorder and console."""

    def __init__(self, cfg, listen=None, connect=None, record: Path | None = None, console: bool = False,
                 port: int = 8080, settings=None, workers: int = 1, security: Security | None = None, stop=None,
                 foxglove: tuple[str, int] | None = None, shard: tuple[int, int] | None = None, standby: bool = False):
        self.cfg, self.listen, self.connect, self.workers = cfg, listen, connect, workers
        self.shard = shard or (0, workers)  # --shard i/N: this process is shard i; else worker 0 of --workers
        self.standby, self.fence = standby, None
        self.stop = stop  # a signal's stop: the worker start-up ends early
        self.foxglove = foxglove  # (host, port) of the live Foxglove server, or None
        self.record, self.console, self.port, self.settings = record, console, port, settings
        self.security = security
        self._closers: list = []

    def __enter__(self):
        from service.protocol.session import open_session
        from service.protocol.tls import TlsConfigError
        from service.shell.service import IncidentService

        sec = self.security
        tls = sec.identity if sec is not None else None
        try:
            session = open_session(self.listen, self.connect, tls=tls,
                                   acl=sec.acl(self.cfg.id) if sec is not None and not self.connect else None)
        except (ConnectionError, TlsConfigError) as e:
            fail(str(e))
            raise typer.Exit(1)
        self._closers.append(session.close)
        taken_over = self._claim(session) if self.workers == 1 else None  # may stand by first (standby.py)
        recorder = core = state_file = None
        self.resumed = None
        if self.record is not None:
            recorder, core, state_file = self._recording()
            self._closers.append(lambda: recorder.__exit__(None, None, None))
        svc = IncidentService(session, self.cfg, self.settings, recorder=recorder, shard=self.shard, core=core or taken_over,
                              state_file=state_file, access=sec.access() if sec is not None else None,
                              actor=tls.name if tls is not None else "service")
        if self.fence is not None:
            from service.shell.standby import SnapshotFeed

            svc.fence = self.fence
            svc.snapshot_feed = SnapshotFeed(session, self.cfg.id, self.shard, self.fence.tag)
            self._closers.append(svc.snapshot_feed.close)
        svc.start(cancel=self.stop)
        self._closers.append(svc.close)
        self._end_if_stopped()
        svc.console_url = None
        if sec is not None and sec.roster is not None:
            self._closers.append(_watch_roster(sec, svc, router=not self.connect).close)
        if self.workers > 1:
            from service.shell.workers import WorkerPool

            ep = (self.connect or self.listen or [default_endpoint(tls)])[0].replace("0.0.0.0", "127.0.0.1")
            pool = WorkerPool(ep, self.cfg, self.workers, tls_dir=str(tls.dir) if tls is not None else None,
                              roster=str(sec.roster_path) if sec is not None and sec.roster_path else None,
                              settings=self.settings, cancel=self.stop)
            self._closers.append(pool.close)
            if not pool.wait_ready(60) and not (self.stop is not None and self.stop.is_set()):
                err.print("[yellow]warning:[/] not every worker process started within 60 s")
            self._end_if_stopped()
        if self.console:
            if _console_starter is None:
                self.__exit__(None, None, None)
                fail("the web console is not installed here (pip install 'firetrack[console]'), or run with --no-console")
                raise typer.Exit(1)
            try:
                handle = _console_starter(session, self.cfg, self.port, sec)
            except ValueError as e:  # the console's own errors (port in use, ...) are ValueErrors
                self.__exit__(None, None, None)  # the service and session already opened
                fail(str(e))
                raise typer.Exit(1)
            self._closers.append(handle.close)
            svc.console_url = getattr(handle, "url", None)
        svc.foxglove_url = self._foxglove(session) if self.foxglove is not None else None
        where = ", ".join(self.connect) if self.connect else ", ".join(self.listen or [default_endpoint(tls)])
        self.service = svc
        return svc, where

    def _end_if_stopped(self) -> None:
        """A Ctrl-C (or systemd's stop) while starting: close what is open and end now, with
        exit code 0 as after serving. Without this the start went on for seconds (the warm-up),
        printed "serving" and only then stopped, or hit the stop watchdog (exit code 1)."""
        if self.stop is not None and self.stop.is_set():
            self.__exit__(None, None, None)
            out.print("stopped while starting")
            raise typer.Exit(0)

    def _claim(self, session):
        """Claim this part's next epoch; first, with ``--standby`` or while another service's
        claim is live, stand by until it is gone. Returns the core restored from the newest
        snapshot the primary published (None: start afresh, or resume from ``--record``)."""
        from service.shell.standby import Fence, SnapshotFollower

        fence = self.fence = Fence(session, self.cfg.id, self.shard)
        self._closers.append(fence.close)
        core = None
        live = fence.others()
        if self.standby or live:
            follower = None if self.record is not None else SnapshotFollower(session, self.cfg.id, self.shard)
            part = f" part {self.shard[0]}/{self.shard[1]}" if self.shard[1] > 1 else ""
            self._warm_up_now()  # not after the primary is gone: seconds of compiling before the first pose
            out.print(f"standing by for incident {self.cfg.id}{part}"
                      + (f" (served at epoch {max(live)[0]})" if live else "") + "; taking over when it is gone")
            if not fence.wait_vacant(self.stop):
                self.__exit__(None, None, None)
                out.print("stopped while standing by")
                raise typer.Exit(0)
            if follower is not None:
                follower.close()
                core = self._restore(follower)
        fence.claim()
        return core

    def _warm_up_now(self) -> None:
        import dataclasses

        from service.core.warmup import warm_up
        from service.shell.service import ServiceSettings

        settings = self.settings or ServiceSettings()
        if settings.warm_up:
            warm_up(self.cfg, settings.core, cancel=self.stop)
            self._end_if_stopped()
            self.settings = dataclasses.replace(settings, warm_up=False)

    def _restore(self, follower):
        from service.core.incident_core import IncidentCore
        from service.shell.service import ServiceSettings

        if follower.newest is None:
            warn("taking over with no snapshot of the primary: the incident starts afresh")
            return None
        try:
            core = IncidentCore.restore(follower.newest, self.cfg, (self.settings or ServiceSettings()).core)
        except Exception as e:  # a snapshot of another version, or damaged: start afresh, loudly
            warn(f"the primary's snapshot cannot be restored ({type(e).__name__}: {e}): the incident starts afresh")
            return None
        err.print(f"taking over from the snapshot of epoch {follower.newest_from} ({len(core.responders)} responder(s), "
                  f"{follower.received} snapshot(s) followed)", highlight=False)
        return core

    def _foxglove(self, session) -> str:
        """The live Foxglove server on the service's session; its ws:// address."""
        try:
            from service.shell.foxglove_live import FoxgloveLive
        except ImportError:
            self.__exit__(None, None, None)
            fail("--foxglove needs the foxglove extra: pip install 'firetrack\\[foxglove]'")
            raise typer.Exit(1)
        host, port = self.foxglove
        try:
            bridge = FoxgloveLive(session, self.cfg, port, host)
        except Exception as e:  # the port in use, a bad address: the server's own message
            self.__exit__(None, None, None)
            fail(f"--foxglove {port}: the Foxglove server did not start on {host}:{port}: {e}")
            raise typer.Exit(1)
        self._closers.append(bridge.close)
        return bridge.url

    def _recording(self):
        """The recorder (a new recording, or the next segment of one that exists), the core to
        go on with (None: a new one) and the state file for snapshots."""
        from service.review.recorder import IncidentRecorder, RecordingWriteError
        from service.review.resume import StateFile, resume, state_path
        from service.shell.service import ServiceSettings

        settings = (self.settings or ServiceSettings()).core
        resumed = resume(self.record, self.cfg, settings,
                         progress=lambda n: err.print(f"resuming: {n} recorded messages replayed ...", highlight=False))
        core = None
        segment, path, attachment = 0, self.record, None
        if resumed is not None:
            self.resumed = resumed
            for problem in resumed.problems:
                err.print(f"[yellow]warning:[/] {problem}", highlight=False)
            core, segment, path, attachment = resumed.core, resumed.segment, resumed.path, resumed.base.record()
            b = resumed.base
            err.print(f"resumed incident {self.cfg.id!r} from the {b.origin}"
                      + (f" (segment {b.segment}, message {b.position})" if b.origin != "start" else "")
                      + f" and {resumed.replayed} recorded messages after it in {resumed.seconds:.2f} s: "
                      f"{len(core.responders)} responder(s); recording on in {path}", highlight=False)
        try:
            recorder = IncidentRecorder(path, self.cfg.id, segment=segment, resume=attachment).__enter__()
        except RecordingWriteError as e:
            self.__exit__(None, None, None)
            fail(str(e))
            raise typer.Exit(1)
        return recorder, core, StateFile(state_path(self.record), self.cfg.id, segment)

    def __exit__(self, *exc):
        closers, self._closers = self._closers, []
        for close in reversed(closers):
            try:
                close()
            except Exception as e:  # shutting down: report, go on closing the rest
                err.print(f"[yellow]warning:[/] while shutting down: {e}")
        return False


def _watch_roster(sec: Security, svc, router: bool):
    """The roster re-read while the service runs: revocations reach the core at once; a name
    the in-process router did not have at its start is named (its rules need a restart)."""
    import logging

    from service.protocol.access import RosterWatcher, access_message

    log = logging.getLogger("firetrack.service")
    known = set(sec.roster.identities)

    def changed(roster) -> None:
        svc.update_access(access_message(roster, str(sec.roster_path)))
        new = sorted(set(roster.identities) - known)
        if new and router:
            log.warning("%s joined the roster after the router started: the router refuses them until it is "
                        "restarted with the new roster (reserve names ahead: firetrack certs reserve)", ", ".join(new))

    return RosterWatcher(sec.roster_path, changed, on_error=lambda m: log.error("roster: %s; the previous one stays", m))
