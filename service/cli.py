"""The ``firetrack`` command: one entry point for evaluation, tuning, benchmarks and the service.

Each sub-command lives in its own small module and is registered here.
"""
from __future__ import annotations

import typer

from service import bench_cli, eval_cli, tune_cli

app = typer.Typer(
    name="firetrack",
    help="Indoor localisation of firefighters: PDR per responder, fused with checkpoint, GNSS and UWB fixes.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(eval_cli.app, name="eval")
app.add_typer(tune_cli.app, name="tune")
app.add_typer(bench_cli.app, name="bench")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
