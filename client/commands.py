"""The client's commands: a wearable replaying a recording, simulated walkers, the demo."""
from __future__ import annotations

import math
import threading
from pathlib import Path

import typer

from service.cli.serve import running_service
from service.protocol.session import DEFAULT_ENDPOINT
from service.protocol.terminal import (
    client_or_exit,
    err,
    fail,
    incident_or_exit,
    insecure,
    out,
    setup_logging,
    stop_on_signals,
    tls_or_exit,
    warn,
)

DEMO_DOWN_AT_S = 45.0  # s into the demo when one simulated walker collapses (man-down 30 s later)
SIM_START_T = 1000.0  # s, the simulated walkers' device clock at their start (client.simulate)

TLS_HELP = "mutual TLS with this identity directory (firetrack certs issue): TLS only, plain TCP refused"


def wearable_command(
    responder: str = typer.Option(None, "--responder", help="responder id (letters, digits, _ . -); with --tls, "
                                                            "the certificate's name by default"),
    replay_file: Path = typer.Option(..., "--replay", help="recording to publish (IPIN, Oxford, PyShoe, ...)"),
    speed: float = typer.Option(1.0, "--speed", help="times real time (0: as fast as possible)"),
    connect: str = typer.Option(None, "--connect", help=f"router endpoint (default {DEFAULT_ENDPOINT}, "
                                                        "tls/127.0.0.1:7447 with --tls)"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's)"),
    config: Path = typer.Option(None, "--config", help="incident config, for the landmarks' local coordinates"),
    landmark_every: int = typer.Option(0, "--landmark-every", help="also send every K-th landmark as a checkpoint fix (the first is always sent)"),
    gnss: bool = typer.Option(True, "--gnss/--no-gnss", help="send the recording's GNSS fixes"),
    ble: bool = typer.Option(True, "--ble/--no-ble", help="send the recording's BLE beacon readings as ble fixes (one per 2 s scan)"),
    wait_router: float = typer.Option(30.0, "--wait-router", help="s to wait for a router that is not up yet"),
    flush: float = typer.Option(5.0, "--flush", help="s to wait at the end (or on Ctrl-C) for the service to "
                                                     "acknowledge the last frame"),
    tls: Path = typer.Option(None, "--tls", help=TLS_HELP + " (a wearable certificate: CN = the responder id)"),
):
    """Publish a real recording as a wearable would: IMU frames (10 per second), landmarks, GNSS and BLE scans as fixes.

    Frames are kept (the last 3000) and resent to a service that missed them (an outage, a
    restart); at the end the wearable waits for the service's acknowledgement and says what
    was not acknowledged."""
    from client.wearable import replay
    from pdr.io.errors import RecordingFormatError
    from service.protocol import wire
    from service.protocol.terminal import progress_bar

    identity = tls_or_exit(tls, "wearable", what="a wearable")
    if identity is not None:
        if responder is not None and responder != identity.name:
            fail(f"--responder {responder!r}, but the certificate in {identity.dir} is {identity.name!r}'s: the router "
                 f"lets it publish on {identity.name}'s keys only")
            raise typer.Exit(2)
        responder = identity.name
    if responder is None:
        fail("--responder is required (or --tls with the wearable's certificate)")
        raise typer.Exit(2)
    if not wire.is_valid_id(responder):
        fail(f"--responder {responder!r}: use 1-64 letters, digits, '_', '.' or '-'")
        raise typer.Exit(2)
    cfg = incident_or_exit(config, incident_id or (identity.incident if identity is not None else None))
    stop = stop_on_signals()  # before the warning: a Ctrl-C from here on is this command's stop
    if identity is None:
        insecure("this wearable")
    session = client_or_exit(connect, wait_router, tls=identity)
    connect = connect or ("tls/127.0.0.1:7447" if identity is not None else DEFAULT_ENDPOINT)
    key = wire.key(cfg.id, responder, "imu").rsplit("/", 1)[0] + "/{imu,fix}"

    def started(msgs):
        n_imu = sum(m.kind == "imu" for m in msgs)
        span = msgs[-1].t - msgs[0].t if msgs else 0.0
        err.print(f"{responder}: publishing {replay_file.name} ({n_imu} frames, {len(msgs) - n_imu} fixes, "
                  f"{span:.0f} s of recording at {speed:g}x) on {key} via {connect}", highlight=False)

    def matching(listening: bool):
        if listening:
            err.print(f"{responder}: a service is listening on incident {cfg.id!r}", highlight=False)
        else:
            warn(f"{responder}: no service is subscribed to incident {cfg.id!r} — frames go nowhere "
                 f"(is `firetrack serve` running, and for this --incident?)")

    try:
        with progress_bar(f"{responder} ← {replay_file.name}") as update:
            sent = replay(replay_file, responder, session, cfg, speed, landmark_every, gnss, stop, update,
                          on_matching=matching, on_start=started, flush_s=flush, ble=ble)
    except (RecordingFormatError, OSError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(1)
    finally:
        session.close()
    unheard = sent["unheard"]["imu"]
    d = sent["delivery"]
    out.print(f"{responder}: sent {sent['imu']} frames and {sent['fix']} fixes"
              + (f"; {unheard} frames went out while no service was subscribed" if unheard else ""))
    if d["unacknowledged"]:
        warn(f"{responder}: {d['unacknowledged']} frame(s) not acknowledged by the service when the wearable left "
             f"(newest acknowledged seq: {d['acked_seq']}); they are lost unless the service took them after")
    elif sent["imu"]:
        out.print(f"{responder}: every frame acknowledged by the service"
                  + (f" ({d['service_lost']} counted lost by it)" if d["service_lost"] else ""))
    if unheard and unheard == sent["imu"]:
        raise typer.Exit(1)  # nobody heard any of it: say so in the exit code too


def simulate_command(
    responders: int = typer.Option(5, "--responders", "-n", help="simulated walkers"),
    seconds: float = typer.Option(60.0, "--seconds", help="how long to walk, s"),
    rate: float = typer.Option(100.0, "--rate", help="IMU rate, Hz"),
    connect: str = typer.Option(None, "--connect", help=f"router endpoint (default {DEFAULT_ENDPOINT}, "
                                                        "tls/127.0.0.1:7447 with --tls)"),
    incident_id: str = typer.Option(None, "--incident", help="incident id (default: the config's)"),
    config: Path = typer.Option(None, "--config", help="incident config (the building the walkers roam)"),
    seed: int = typer.Option(0, "--seed", help="random seed of the walkers"),
    start_spread: float = typer.Option(5.0, "--start-spread", help="s over which the walkers start walking"),
    tls: Path = typer.Option(None, "--tls", help=TLS_HELP + " (a simulator certificate NAME: walkers NAME-000, ...)"),
):
    """Publish synthetic walkers in the incident's building; their true positions go on .../truth."""
    from client.simulate import SimulationPublisher, building_bounds

    identity = tls_or_exit(tls, "simulator", what="simulate")
    cfg = incident_or_exit(config, incident_id or (identity.incident if identity is not None else None))
    stop = stop_on_signals()  # before the warning: a Ctrl-C from here on is this command's stop
    if identity is None:
        insecure("firetrack simulate")
    session = client_or_exit(connect, tls=identity)
    floors = (min(f.number for f in cfg.floors), max(f.number for f in cfg.floors)) if cfg.floors else (0, 0)
    try:
        pub = SimulationPublisher(session, cfg.id, responders, rate, seed, bounds=building_bounds(cfg), floors=floors,
                                  start_spread_s=start_spread, prefix=identity.name if identity is not None else "sim")
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
    """The whole system on this machine: router, service, console, replayed IPIN walks and simulated walkers.

    No certificates: the demo is insecure by design (plain TCP, no access control, no login)
    and says so. An incident runs `firetrack serve --tls` (docs/security.md)."""
    from client.simulate import SimulationPublisher, building_bounds
    from client.wearable import replay
    from service.protocol.incident import default_incident

    setup_logging(False)
    stop = stop_on_signals()  # before the warning: a Ctrl-C from here on is this command's stop
    insecure("the demo")
    cfg = default_incident()
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "ipin2023"
    walks = sorted(data.glob("IPIN2023_T3_TrainingTrial*_repetition01.txt.gz"))[:3] if data.is_dir() else []
    with running_service(cfg, [listen], None, None, True, port) as (svc, where):
        session = client_or_exit(listen)
        threads = []
        for i, path in enumerate(walks):
            th = threading.Thread(target=replay, args=(path, f"ipin-{i + 1}", session, cfg, speed, 3, False, stop),
                                  daemon=True)
            th.start()
            threads.append(th)
        pub = SimulationPublisher(session, cfg.id, responders, 50.0, 1, bounds=building_bounds(cfg), floors=(0, 0))
        down = None
        if responders:  # so that every demo shows the man-down alarm: the last walker collapses
            down = pub.names[-1]
            pub.fleet.collapse(len(pub.names) - 1, at=SIM_START_T + DEMO_DOWN_AT_S)
        sim = threading.Thread(target=pub.run, args=(seconds if math.isfinite(seconds) else 24 * 3600.0, stop),
                               daemon=True)
        sim.start()
        out.print(f"[bold]firetrack demo[/]: incident {cfg.id} ({cfg.name}), router {where}")
        out.print(f"  {len(walks)} replayed IPIN walk(s) (ipin-1..), {responders} simulated walker(s) (sim-000..)")
        if down is not None:
            out.print(f"  {down} collapses {DEMO_DOWN_AT_S:.0f} s in: MAN DOWN shows about 35 s later")
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
