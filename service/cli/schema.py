"""``firetrack schema``: the JSON Schema of every wire message, for readers in other languages.

Registered in :mod:`service.cli` as ``app.command("schema")(schema_cli.schema_command)``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from service.protocol.terminal import err, fail
from service.protocol.wire import json_schema


def schema_command(
    out: Path | None = typer.Option(None, "--out", help="write the schema to this file instead of stdout"),
) -> None:
    """Print the wire schema: a definition per message kind (imu, fix, pose, status), the
    key-expression layout and how sample arrays are packed (one JSON document)."""
    text = json.dumps(json_schema(), indent=2) + "\n"
    if out is None:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
    except OSError as e:
        fail(f"cannot write {out}: {e.strerror or e}")
        raise typer.Exit(1) from None
    err.print(f"wrote {out}", highlight=False)
