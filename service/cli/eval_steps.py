"""``firetrack eval steps``: detected against true step counts (registered on the eval app)."""
from __future__ import annotations

import warnings
from pathlib import Path

import typer
from rich.table import Table

from pdr.io import load
from pdr.io.errors import RecordingFormatError, RecordingWarning
from pdr.steps import DEFAULT_DETECTOR, DETECTORS, make_detector
from pdr.steps.scoring import StepCount, count_steps, mean_abs_error_pct
from service.protocol.terminal import (
    fail,
    out,
    parse_params,
    print_json,
    progress,
    warn,
)


def eval_steps(
    files: list[Path] = typer.Argument(
        ..., help="Oxford walk directories (or their accelerometer.csv.gz), Oxford validation .csv.gz, IPIN logs"
    ),
    detector: str = typer.Option(DEFAULT_DETECTOR, "--detector", "-d", help=f"one of {', '.join(DETECTORS)}"),
    param: list[str] = typer.Option(None, "--param", "-p", help="override a detector setting: name=value"),
    zero_phase: bool = typer.Option(False, "--zero-phase", help="filter forward-backward (offline analysis only)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
):
    """True and detected steps per file; error = 100·(detected − true)/true, mean of |error| over files."""
    try:
        params = parse_params(param)
        make_detector(detector, params)
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    warnings.simplefilter("ignore", RecordingWarning)  # repairs are printed once below
    counts: list[tuple[Path, StepCount]] = []
    bad = 0
    for path in progress(files, "counting steps"):
        try:
            rec = load(path)
            for w in rec.warnings:
                warn(f"{path}: {w}")
            counts.append((path, count_steps(rec, detector, params, zero_phase=zero_phase)))
        except (RecordingFormatError, OSError, ValueError) as e:
            fail(str(e))
            bad += 1
    if not counts:
        raise typer.Exit(2)
    for path, c in counts:
        if c.true_steps is None:
            warn(f"{path}: no true step count; left out of the mean")
    mean = mean_abs_error_pct([c for _, c in counts])
    if as_json:
        print_json({
            "files": [
                {"file": str(p), "true_steps": c.true_steps, "detected_steps": c.detected_steps, "error_pct": c.error_pct}
                for p, c in counts
            ],
            "mean_abs_error_pct": mean,
        })
    else:
        out.print(_table(counts, detector, mean))
    if bad:
        raise typer.Exit(1)


def _table(counts: list[tuple[Path, StepCount]], detector: str, mean: float | None) -> Table:
    table = Table(title=f"step count, detector {detector} ({counts[0][1].signal})")
    for col, just in (("file", "left"), ("carry", "left"), ("true", "right"), ("detected", "right"), ("error %", "right")):
        table.add_column(col, justify=just)
    for k, (path, c) in enumerate(counts):
        name = path.name if path.name not in ("accelerometer.csv.gz", "accelerometer.csv") else path.parent.name
        table.add_row(
            name,
            c.carry or "",
            "—" if c.true_steps is None else str(c.true_steps),
            str(c.detected_steps),
            "—" if c.error_pct is None else f"{c.error_pct:+.1f}",
            end_section=k == len(counts) - 1,
        )
    scored = [c for _, c in counts if c.error_pct is not None]
    carries = sorted({c.carry for c in scored if c.carry})
    if len(carries) > 1:
        for carry in carries:
            group = [c for c in scored if c.carry == carry]
            table.add_row(f"mean |error| of {len(group)}", carry, "", "", f"{mean_abs_error_pct(group):.2f}")
    if mean is not None:
        table.add_row(f"mean |error| of {len(scored)}", "all", "", "", f"{mean:.2f}")
    return table
