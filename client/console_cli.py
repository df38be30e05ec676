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
    out,
    stop_on_signals,
    warn_plan_problems,
)


def console_command(
    connect: str = typer.Option("tcp/127.0.0.1:7447", "--connect", help="the zenoh router of the incident"),
    port: int = typer.Option(8080, "--port", help="web port of the console"),
    incident: str | None = typer.Option(None, "--incident", help="incident id (default: the config's, 'demo' for the demo)"),
    config: Path | None = typer.Option(None, "--config", help="incident config (JSON or TOML); default: the IPIN museum demo"),
    host: str = typer.Option("127.0.0.1", "--host", help="address to serve on (0.0.0.0: every interface of this machine)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log fixes, checkpoints and ignored messages"),
):
    """Serve the command console (live map, roster, alarms, operator fixes) from a zenoh router."""
    from client.console.server import ConsoleError, start_console

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s")
    cfg = incident_or_exit(config, incident)
    warn_plan_problems(cfg)
    stop = stop_on_signals()
    session = client_or_exit(connect)
    try:
        try:
            handle = start_console(session, cfg, port=port, host=host)
        except ConsoleError as e:
            fail(str(e))
            raise typer.Exit(1)
        shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
        out.print(f"[bold]firetrack console[/] for incident [bold]{cfg.id}[/] ({cfg.name}) from {connect}")
        out.print(f"open http://{shown}:{handle.port}/")
        try:
            stop.wait()
        finally:
            handle.close()
    finally:
        session.close()
    err.print("console stopped")
