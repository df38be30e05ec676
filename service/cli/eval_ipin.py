"""``firetrack eval ipin``: track IPIN 2023 logs from their first landmark and score the others."""
from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.table import Table

from pdr.evaluation.ipin import summary
from service.cli.recordings import load_all
from service.core.tracker import tracker_settings_for
from service.protocol.terminal import err, fail, out, print_json, progress
from service.review.ipin_run import IpinRun, run_ipin

KINDS = ("live", "smoothed", "pdr")


def eval_ipin(
    files: list[Path] = typer.Argument(..., help="IPIN 2023 GetSensorData logs (.txt or .txt.gz)"),
    fix_every: int = typer.Option(0, "--fix-every", "-k", help="hand landmarks 0, K, 2K, ... to the tracker as checkpoint fixes (0: only the first)"),
    no_gnss: bool = typer.Option(False, "--no-gnss", help="leave the logs' GNSS fixes out"),
    engine: str = typer.Option("fusion", "--engine", help="fusion (gtsam factor graph) or dr (dead reckoning alone)"),
    incident: Path = typer.Option(None, "--incident", help="incident config (origin, floors, floor plans); default: the IPIN museum demo"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    plot: Path = typer.Option(None, "--plot", help="write a PNG per file (track over the landmarks, on the floor plan) into this folder"),
):
    """Error at each scored landmark = horizontal distance + 15 m x |floor error|; p75 and median pooled over all files."""
    from service.protocol.incident import (
        IncidentConfigError,
        default_incident,
        load_incident,
    )

    if engine not in ("fusion", "dr"):
        fail(f"--engine must be fusion or dr, got {engine!r}")
        raise typer.Exit(2)
    try:
        cfg = load_incident(incident) if incident else default_incident()
    except IncidentConfigError as e:
        fail(str(e))
        raise typer.Exit(2)
    started = time.process_time()
    recordings, bad = load_all(files)
    settings = tracker_settings_for(cfg, engine)
    runs: list[IpinRun] = []
    for rec in progress(recordings, "tracking"):
        try:
            runs.append(run_ipin(rec, cfg, fix_every, not no_gnss, settings))
        except ValueError as e:
            fail(str(e))
            bad += 1
    if not runs:
        raise typer.Exit(2)
    report = _report(runs, fix_every, not no_gnss, engine)
    report["cpu_s"] = time.process_time() - started
    if plot is not None:
        from service.review.ipin_plot import plot_run

        plot.mkdir(parents=True, exist_ok=True)
        for r in progress(runs, "plotting"):
            err.print(f"wrote {plot_run(r, cfg, plot)}")
    if as_json:
        print_json(report)
    else:
        out.print(_table(report))
    if bad:
        raise typer.Exit(1)


def _report(runs: list[IpinRun], fix_every: int, gnss: bool, engine: str) -> dict:
    per_kind = {}
    for kind in KINDS:
        errs = [(r, r.errors(kind)) for r in runs]
        errs = [(r, e) for r, e in errs if e is not None]
        if not errs:
            per_kind[kind] = None
            continue
        per_kind[kind] = {
            **summary([e for _, e in errs]),
            "files": [{"file": r.source, **summary([e])} for r, e in errs],
        }
    live = per_kind["live"] or per_kind["pdr"]
    return {
        "files": live["files"],
        "p75_m": live["p75_m"],
        "median_m": live["median_m"],
        "floor_accuracy": live["floor_accuracy"],
        "n_eval": live["n_eval"],
        "fix_every": fix_every,
        "gnss": gnss,
        "engine": engine,
        **per_kind,
    }


def _fmt(x, spec=".2f") -> str:
    return "—" if x is None else format(x, spec)


def _table(report: dict) -> Table:
    kinds = [k for k in KINDS if report.get(k)]
    table = Table(title=f"IPIN landmarks, fix every {report['fix_every'] or '— (initial only)'}, "
                        f"GNSS {'on' if report['gnss'] else 'off'}, engine {report['engine']} (error m)")
    table.add_column("file")
    for k in kinds:
        table.add_column(f"{k} p75", justify="right")
        table.add_column(f"{k} median", justify="right")
    table.add_column("floor ok", justify="right")
    table.add_column("n", justify="right")
    for i, f in enumerate(report["files"]):
        row = [Path(f["file"]).name.replace("IPIN2023_T3_Training", "").split(".")[0]]
        for k in kinds:
            fk = report[k]["files"][i]
            row += [_fmt(fk["p75_m"]), _fmt(fk["median_m"])]
        table.add_row(*row, _fmt(f["floor_accuracy"], ".0%"), str(f["n_eval"]))
    row = ["all (pooled)"]
    for k in kinds:
        row += [f"[bold]{_fmt(report[k]['p75_m'])}[/]", _fmt(report[k]["median_m"])]
    table.add_row(*row, _fmt(report["floor_accuracy"], ".0%"), str(report["n_eval"]), end_section=True)
    table.caption = f"{report['cpu_s']:.1f} s CPU"
    return table



