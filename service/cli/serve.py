"""``firetrack serve`` and ``firetrack wearable``: the live service and a replaying wearable."""
from __future__ import annotations

import logging
import math
import signal
import threading
from pathlib import Path

import typer

from service.protocol.terminal import err, fail, out
from service.protocol.session import DEFAULT_ENDPOINT


def _incident(config: Path | None, incident_id: str | None):
    from service.protocol.incident import IncidentConfigError, default_incident, load_incident

    try:
        cfg = load_incident(config) if config else default_incident()
    except IncidentConfigError as e:
        fail(str(e))
        raise typer.Exit(2)
    if incident_id and incident_id != cfg.id:
        cfg = cfg.model_copy(update={"id": incident_id})
    return cfg


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (Ctrl-C, systemd stop, docker stop)."""
    stop = threading.Event()

    def handler(signum, frame):
        if stop.is_set():  # a second Ctrl-C: the user means it
            raise KeyboardInterrupt
        err.print(f"\n{signal.Signals(signum).name}: shutting down ...")
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def _logging(verbose: bool) -> None:
    from rich.logging import RichHandler

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s",
                        handlers=[RichHandler(console=err, show_path=False)])


def serve_command(
    listen: list[str] = typer.Option(None, "--listen", help=f"endpoint(s) to listen on (default {DEFAULT_ENDPOINT}: an in-process router)"),
    connect: list[str] = typer.Option(None, "--connect", help="join a standalone zenoh router instead (e.g. tcp/10.0.0.2:7447)"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's, 'demo' for the demo)"),
    config: Path = typer.Option(None, "--config", help="incident config (JSON or TOML); default: the IPIN museum demo"),
    record: Path = typer.Option(None, "--record", help="record every message of the incident to this MCAP file"),
    console: bool = typer.Option(True, "--console/--no-console", help="also serve the web console"),
    port: int = typer.Option(8080, "--port", help="web console port"),
    seconds: float = typer.Option(math.inf, "--seconds", help="stop after this long (default: until Ctrl-C)"),
    workers: int = typer.Option(1, "--workers", help="worker processes sharing the responders (one per core)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log every responder, fix and reject"),
):
    """Run the service for one incident: one pipeline per responder, poses and status out."""
    _logging(verbose)
    cfg = _incident(config, incident_id)
    if workers < 1:
        fail(f"--workers must be at least 1, got {workers}")
        raise typer.Exit(2)
    if workers > 1 and record is not None:
        fail("--record records one process's inputs; with --workers > 1 run `firetrack record` beside the service")
        raise typer.Exit(2)
    stop = stop_on_signals()
    with running_service(cfg, listen, connect, record, console, port, workers=workers) as (svc, where):
        out.print(f"[bold]firetrack[/] serving incident [bold]{cfg.id}[/] ({cfg.name}) on {where}")
        if console:
            out.print(f"console: http://127.0.0.1:{port}/")
        stop.wait(None if math.isinf(seconds) else seconds)
    out.print(f"stopped; {len(svc.responders)} responder(s), {svc.frames_processed} frames processed")


class running_service:
    """Context manager: session (router or client), service, optional recorder and console."""

    def __init__(self, cfg, listen=None, connect=None, record: Path | None = None, console: bool = False,
                 port: int = 8080, settings=None, workers: int = 1):
        self.cfg, self.listen, self.connect, self.workers = cfg, listen, connect, workers
        self.record, self.console, self.port, self.settings = record, console, port, settings
        self._closers: list = []

    def __enter__(self):
        from service.shell.service import IncidentService
        from service.protocol.session import open_session

        try:
            session = open_session(self.listen, self.connect)
        except ConnectionError as e:
            fail(str(e))
            raise typer.Exit(1)
        self._closers.append(session.close)
        recorder = None
        if self.record is not None:
            from service.review.recorder import IncidentRecorder

            recorder = IncidentRecorder(self.record, self.cfg.id).__enter__()
            self._closers.append(lambda: recorder.__exit__(None, None, None))
        svc = IncidentService(session, self.cfg, self.settings, recorder=recorder, shard=(0, self.workers)).start()
        self._closers.append(svc.close)
        if self.workers > 1:
            from service.shell.workers import WorkerPool

            ep = (self.connect or self.listen or [DEFAULT_ENDPOINT])[0].replace("0.0.0.0", "127.0.0.1")
            pool = WorkerPool(ep, self.cfg, self.workers)
            self._closers.append(pool.close)
            if not pool.wait_ready(60):
                err.print("[yellow]warning:[/] not every worker process started within 60 s")
        if self.console:
            from client.console.server import ConsoleError, start_console

            try:
                handle = start_console(session, self.cfg, port=self.port)
            except ConsoleError as e:
                self.__exit__(None, None, None)  # the service and session already opened
                fail(str(e))
                raise typer.Exit(1)
            self._closers.append(handle.close)
        where = ", ".join(self.connect) if self.connect else ", ".join(self.listen or [DEFAULT_ENDPOINT])
        self.service = svc
        return svc, where

    def __exit__(self, *exc):
        for close in reversed(self._closers):
            try:
                close()
            except Exception as e:  # shutting down: report, go on closing the rest
                err.print(f"[yellow]warning:[/] while shutting down: {e}")
        return False


def _client_session(connect: str):
    """A zenoh client session to ``connect``, or a clear error and exit 1."""
    from service.protocol.session import open_client

    try:
        return open_client(connect)
    except ConnectionError as e:
        fail(str(e))
        raise typer.Exit(1)


def wearable_command(
    responder: str = typer.Option(..., "--responder", help="responder id (letters, digits, _ . -)"),
    replay_file: Path = typer.Option(..., "--replay", help="recording to publish (IPIN, Oxford, PyShoe, ...)"),
    speed: float = typer.Option(1.0, "--speed", help="times real time (0: as fast as possible)"),
    connect: str = typer.Option(DEFAULT_ENDPOINT, "--connect", help="router endpoint"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's)"),
    config: Path = typer.Option(None, "--config", help="incident config, for the landmarks' local coordinates"),
    landmark_every: int = typer.Option(0, "--landmark-every", help="also send every K-th landmark as a checkpoint fix (the first is always sent)"),
    gnss: bool = typer.Option(True, "--gnss/--no-gnss", help="send the recording's GNSS fixes"),
):
    """Publish a real recording as a wearable would: IMU frames (10 per second), landmarks and GNSS as fixes."""
    from client.wearable import replay
    from pdr.io.errors import RecordingFormatError
    from service.protocol import wire
    from service.protocol.terminal import progress_bar

    if not wire.is_valid_id(responder):
        fail(f"--responder {responder!r}: use 1-64 letters, digits, '_', '.' or '-'")
        raise typer.Exit(2)
    cfg = _incident(config, incident_id)
    stop = stop_on_signals()
    session = _client_session(connect)
    try:
        with progress_bar(f"{responder} ← {replay_file.name}") as update:
            sent = replay(replay_file, responder, session, cfg, speed, landmark_every, gnss, stop, update)
    except (RecordingFormatError, OSError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(1)
    finally:
        session.close()
    out.print(f"{responder}: sent {sent['imu']} frames and {sent['fix']} fixes")


def simulate_command(
    responders: int = typer.Option(5, "--responders", "-n", help="simulated walkers"),
    seconds: float = typer.Option(60.0, "--seconds", help="how long to walk, s"),
    rate: float = typer.Option(100.0, "--rate", help="IMU rate, Hz"),
    connect: str = typer.Option(DEFAULT_ENDPOINT, "--connect", help="router endpoint"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's)"),
    config: Path = typer.Option(None, "--config", help="incident config (the building the walkers roam)"),
    seed: int = typer.Option(0, "--seed", help="random seed of the walkers"),
    start_spread: float = typer.Option(5.0, "--start-spread", help="s over which the walkers start walking"),
):
    """Publish synthetic walkers in the incident's building; their true positions go on .../truth."""
    from client.simulate import SimulationPublisher, building_bounds

    cfg = _incident(config, incident_id)
    stop = stop_on_signals()
    session = _client_session(connect)
    floors = (min(f.number for f in cfg.floors), max(f.number for f in cfg.floors)) if cfg.floors else (0, 0)
    try:
        pub = SimulationPublisher(session, cfg.id, responders, rate, seed, bounds=building_bounds(cfg), floors=floors,
                                  start_spread_s=start_spread)
        try:
            frames = pub.run(seconds, stop)
        finally:
            pub.close()
    finally:
        session.close()
    out.print(f"simulated {responders} responder(s): {frames} frames")


def demo_command(
    seconds: float = typer.Option(math.inf, "--seconds", help="stop after this long (default: until Ctrl-C)"),
    responders: int = typer.Option(4, "--responders", "-n", help="simulated walkers besides the replayed ones"),
    speed: float = typer.Option(1.0, "--speed", help="replay speed of the recorded walks"),
    port: int = typer.Option(8080, "--port", help="web console port"),
    listen: str = typer.Option(DEFAULT_ENDPOINT, "--listen", help="router endpoint"),
):
    """The whole system on this machine: router, service, console, replayed IPIN walks and simulated walkers."""
    from client.simulate import SimulationPublisher, building_bounds
    from client.wearable import replay
    from service.protocol.incident import default_incident

    _logging(False)
    cfg = default_incident()
    stop = stop_on_signals()
    data = Path(__file__).resolve().parents[3] / "shared" / "data" / "ipin2023"
    walks = sorted(data.glob("IPIN2023_T3_TrainingTrial*_repetition01.txt.gz"))[:3] if data.is_dir() else []
    with running_service(cfg, [listen], None, None, True, port) as (svc, where):
        session = _client_session(listen)
        threads = []
        for i, path in enumerate(walks):
            th = threading.Thread(target=replay, args=(path, f"ipin-{i + 1}", session, cfg, speed, 3, False, stop),
                                  daemon=True)
            th.start()
            threads.append(th)
        pub = SimulationPublisher(session, cfg.id, responders, 50.0, 1, bounds=building_bounds(cfg), floors=(0, 0))
        sim = threading.Thread(target=pub.run, args=(seconds if math.isfinite(seconds) else 24 * 3600.0, stop),
                               daemon=True)
        sim.start()
        out.print(f"[bold]firetrack demo[/]: incident {cfg.id} ({cfg.name}), router {where}")
        out.print(f"  {len(walks)} replayed IPIN walk(s) (ipin-1..), {responders} simulated walker(s) (sim-000..)")
        out.print(f"  open the console: http://127.0.0.1:{port}/   (Ctrl-C to stop)")
        stop.wait(None if math.isinf(seconds) else seconds)
        stop.set()
        sim.join(5)
        for th in threads:
            th.join(5)
        pub.close()
        summary = {rid: (r.tracker.steps, r.poses) for rid, r in sorted(svc.responders.items())}
        session.close()
    out.print(f"demo over: {len(summary)} responders")
    for rid, (steps, poses) in summary.items():
        out.print(f"  {rid}: {steps} steps, {poses} poses published")
