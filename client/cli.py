"""The ``firetrack`` command: one entry point for the service, wearables, tools, evaluation and benchmarks.

Each sub-command lives in its own small module and is registered here. Modules that need
zenoh or gtsam import them inside the command, so ``firetrack --help`` stays fast.
"""
from __future__ import annotations

import typer

from client import console_cli
from service.cli import bench as bench_cli
from service.cli import eval as eval_cli
from service.cli import record as record_cli
from service.cli import review as review_cli
from service.cli import schema as schema_cli
from service.cli import serve as serve_cli
from service.cli import tune as tune_cli

app = typer.Typer(
    name="firetrack",
    help="Indoor localisation of firefighters: PDR per responder, fused with checkpoint, GNSS and UWB fixes.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.command("demo")(serve_cli.demo_command)
app.command("serve")(serve_cli.serve_command)
app.command("simulate")(serve_cli.simulate_command)
app.command("console")(console_cli.console_command)
app.command("wearable")(serve_cli.wearable_command)
app.command("record")(record_cli.record_command)
app.command("replay")(record_cli.replay_command)
app.command("reprocess")(review_cli.reprocess_command)
app.command("exercise")(review_cli.exercise_command)
app.command("schema")(schema_cli.schema_command)
app.add_typer(eval_cli.app, name="eval")
app.add_typer(tune_cli.app, name="tune")
app.add_typer(bench_cli.app, name="bench")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
