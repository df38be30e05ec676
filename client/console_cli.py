"""``firetrack console``: the web console alone, as a zenoh client of a running service's router.

``firetrack serve`` already serves the console beside the service; this command is for a
second screen (another laptop in the command vehicle) or a console restarted on its own.
"""
from __future__ import annotations

import logging
from pathlib import Path

import typer

from service.protocol.terminal import (
    client_or_exit,
    err,
    fail,
    incident_or_exit,
    insecure,
    out,
    stop_on_signals,
    tls_or_exit,
    warn_plan_problems,
)


def console_command(
    connect: str = typer.Option(None, "--connect", help="the zenoh router of the incident (default: this machine's, "
                                                        "tcp/ or with --tls tls/127.0.0.1:7447)"),
    port: int = typer.Option(8080, "--port", help="web port of the console"),
    incident: str | None = typer.Option(None, "--incident", help="incident id (default: the config's, 'demo' for the demo)"),
    config: Path | None = typer.Option(None, "--config", help="incident config (JSON or TOML); default: the IPIN museum demo"),
    host: str = typer.Option("127.0.0.1", "--host", help="address to serve on (0.0.0.0: every interface of this machine)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log fixes, checkpoints and ignored messages"),
    tls: Path = typer.Option(None, "--tls", help="this console's identity (firetrack certs issue --role console): mutual "
                                                 "TLS to the router, HTTPS for the page, operator logins from the roster"),
    roster: Path = typer.Option(None, "--roster", help="the incident roster with the operators' credentials "
                                                       "(default: roster.json beside the --tls directory)"),
    origin: list[str] = typer.Option(None, "--origin", help="the address officers open, e.g. https://10.0.0.5:8080 "
                                                           "(Host and Origin are checked against it); repeat"),
    https: bool = typer.Option(None, "--https/--no-https", help="serve the page over HTTPS (default: beyond this machine)"),
    gateway_tls: Path = typer.Option(None, "--gateway-tls", help="the phone gateway's identity (firetrack certs issue "
                                                                 "--role gateway): phones at /wear publish through it"),
):
    """Serve the command console (live map, roster, alarms, operator fixes) from a zenoh router."""
    from client.console.server import ConsoleError, start_console

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s")
    identity = tls_or_exit(tls, "console", "operator", what="the console")
    roster = roster or (identity.roster_path() if identity is not None else None)
    if identity is not None and roster is None:
        fail(f"--tls {identity.dir}: the console needs the incident roster for its logins (roster.json beside the "
             "identity directory, or --roster FILE)")
        raise typer.Exit(2)
    cfg = incident_or_exit(config, incident)
    stop = stop_on_signals()  # before the warnings: a Ctrl-C from here on is this command's stop
    if identity is None:
        insecure("firetrack console")
    warn_plan_problems(cfg)
    session = client_or_exit(connect, tls=identity)
    gateway = None
    if gateway_tls is not None:
        gw_identity = tls_or_exit(gateway_tls, "gateway", what="the phone gateway")
        gateway = client_or_exit(connect, tls=gw_identity)
    try:
        try:
            handle = start_console(session, cfg, port=port, host=host, actor=identity.name if identity else "console",
                                   roster=roster, tls=identity, https=https, origins=origin or None)
        except ConsoleError as e:
            fail(str(e))
            raise typer.Exit(1)
        if gateway is not None:
            handle.server.phones.publish_through(gateway)
        out.print(f"[bold]firetrack console[/] for incident [bold]{cfg.id}[/] ({cfg.name}) from "
                  f"{connect or 'this machine'}" + (f" as {identity.name}" if identity else ""))
        out.print(f"open {handle.url}" + ("" if roster else "   (no logins: this machine only)"))
        try:
            stop.wait()
        finally:
            handle.close()
    finally:
        for s in (gateway, session):
            if s is not None:
                s.close()
    err.print("console stopped")
