"""The ``firetrack`` command, assembled at the top of the house.

Every verb lives in a small module of its own layer: the service's in ``service/cli/``
(serve, eval, bench, record, replay, reprocess, ...), the client's here (wearable, simulate,
demo, console, the load bench). This is the one place that joins them, and the one place
that may: the console is handed to ``serve`` here, so ``service/`` never imports the client.

The install can be partial: ``pip install firetrack[wearable]`` has no gtsam, numba or
aiohttp. A verb whose module needs a package that is not installed still shows in
``--help``; run, it says which extra to install, instead of the whole command failing.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable

import typer

from service.protocol.terminal import fail

# optional third-party packages -> the extra that installs them
EXTRA_OF = {"gtsam": "service", "numba": "service", "mcap": "service", "zstandard": "service", "aiohttp": "console",
            "PIL": "console", "matplotlib": "eval", "vqf": "eval", "cryptography": "service"}

app = typer.Typer(
    name="firetrack",
    help="Indoor localisation of firefighters: PDR per responder, fused with checkpoint, GNSS and UWB fixes.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def _load(module: str, attr: str):
    """``module.attr``, or None with the missing optional package's name when it cannot be imported."""
    try:
        return getattr(importlib.import_module(module), attr), None
    except ModuleNotFoundError as e:
        top = (e.name or "").split(".")[0]
        if top not in EXTRA_OF:
            raise  # a bug, not a partial install
        return None, top


def _missing(name: str, package: str) -> Callable:
    def command(ctx: typer.Context) -> None:
        from rich.markup import escape

        fail(escape(f"'firetrack {name}' needs {package}, which is not installed: "
                    f"pip install 'firetrack[{EXTRA_OF[package]}]'"))
        raise typer.Exit(3)
    command.__doc__ = f"(not installed: pip install 'firetrack[{EXTRA_OF[package]}]')"
    return command


def _command(name: str, module: str, attr: str) -> None:
    fn, missing = _load(module, attr)
    settings = dict(context_settings={"allow_extra_args": True, "ignore_unknown_options": True}) if missing else {}
    app.command(name, **settings)(fn if fn is not None else _missing(name, missing))


def _group(name: str, module: str) -> None:
    sub, missing = _load(module, "app")
    if sub is not None:
        app.add_typer(sub, name=name)
    else:
        app.command(name, context_settings={"allow_extra_args": True, "ignore_unknown_options": True})(
            _missing(name, missing))


def _console_starter(session, cfg, port: int, security=None):
    """The console beside ``serve``: on this machine only (127.0.0.1), its operator actions
    published as the service's own identity; with ``--tls`` and a roster, operators log in."""
    from client.console.server import ConsoleError, start_console

    try:
        if security is None:
            return start_console(session, cfg, port=port)
        return start_console(session, cfg, port=port, actor=security.identity.name,
                             roster=security.roster_path, tls=security.identity)
    except ConsoleError as e:
        raise ValueError(str(e)) from None


_command("demo", "client.commands", "demo_command")
_command("serve", "service.cli.serve", "serve_command")
_command("simulate", "client.commands", "simulate_command")
_command("console", "client.console_cli", "console_command")
_command("wearable", "client.commands", "wearable_command")
_command("record", "service.cli.record", "record_command")
_command("replay", "service.cli.record", "replay_command")
_command("reprocess", "service.cli.review", "reprocess_command")
_command("exercise", "service.cli.review", "exercise_command")
_command("schema", "service.cli.schema", "schema_command")
_group("certs", "service.cli.certs")
_group("eval", "service.cli.eval")
_group("tune", "service.cli.tune")
_group("bench", "service.cli.bench")

_serve, _ = _load("service.cli.serve", "set_console_starter")
if _serve is not None and importlib.util.find_spec("aiohttp") is not None:
    _serve(_console_starter)
_bench, _ = _load("service.cli.bench", "app")
_load_bench, _ = _load("client.load_bench", "bench_service_command")
if _bench is not None and _load_bench is not None:
    _bench.callback(invoke_without_command=True)(_load_bench)
_fault_bench, _ = _load("client.fault_bench", "bench_faults_command")
if _bench is not None and _fault_bench is not None:
    _bench.command("faults")(_fault_bench)
_login_bench, _ = _load("client.console.login_bench", "bench_logins_command")
if _bench is not None and _login_bench is not None:
    _bench.command("logins")(_login_bench)


def main() -> None:
    try:
        app()
    except KeyboardInterrupt:  # a second Ctrl-C while shutting down: stop quietly
        raise SystemExit(130) from None


if __name__ == "__main__":  # the script (client/entry.py) imports this module; it is not run as a program
    raise SystemExit("run `firetrack` (or `python -m client.entry`): it ends cleanly after Ctrl-C and under "
                     "zenoh's threads (client/entry.py)")
