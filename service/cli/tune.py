"""``firetrack tune``: parameter searches beside the filters.

Two modes for ``tune ahrs``:

* without ``--grid``: the dissertation's sliding grid search from a start point (Justa
  2022 §6.2), scored on the given recordings;
* with ``--grid name=v1,v2,...`` (repeatable): every combination is scored on every
  recording; ``--cv`` adds leave-one-recording-out cross-validation (for each recording,
  the combination chosen on the others is scored on it). ``--balance dataset`` gives each
  data set (each IMU: BROAD's trials, Justa's Vicon recording) one vote in the choice
  instead of each recording one vote. This is how the shipped defaults of the decoupled
  filter were chosen.

A recording's score is its metric: BROAD trials the total RMSE over the movement samples
(filter started from its own estimate), other recordings the MAE (or RMSE) from the
reference start. Scores of a grid can be cached (``--cache``) and reused.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import typer

from pdr.ahrs import DEFAULT_FILTER, FILTERS, settings_with
from pdr.ahrs.tuning import criterion, grid_points, leave_one_out, sliding_grid_search
from pdr.evaluation.orientation import pooled, score_benchmark, score_orientation
from service.cli.recordings import load_all
from service.protocol.terminal import err, fail, out, parse_params, print_json, progress

app = typer.Typer(help="Tune algorithm settings on recordings with ground truth.", no_args_is_help=True)

NOT_TUNED = {"max_dt", "alpha"}


def _parse_span(span: str | None) -> slice:
    if not span:
        return slice(None)
    a, _, b = span.partition(":")
    return slice(int(a) if a else None, int(b) if b else None)


def _parse_grid(items: list[str], settings) -> dict[str, list[float]]:
    names = {f.name for f in dataclasses.fields(settings)}
    grid: dict[str, list[float]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not values.strip():
            raise ValueError(f"--grid expects name=v1,v2,..., got {item!r}")
        if key not in names:
            raise ValueError(f"unknown parameter {key!r} for {type(settings).__qualname__}; valid: {', '.join(sorted(names))}")
        try:
            grid[key] = [float(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"--grid {key}: values must be numbers, got {values!r}") from None
    return grid


def file_score(rec, filter_name: str, params: dict, objective: str) -> float:
    """One recording's score for a parameter set: its own metric (lower is better)."""
    if rec.kind == "broad":
        return score_benchmark(rec, filter_name, params).rmse_deg("total")
    s = score_orientation(rec, filter_name, params)
    return s.mae_deg if objective == "mae" else s.rmse_deg


@app.command("ahrs")
def tune_ahrs(
    files: list[Path] = typer.Argument(..., help="recordings with an orientation reference"),
    filter_name: str = typer.Option(DEFAULT_FILTER, "--filter", "-f"),
    param: list[str] = typer.Option(None, "--param", "-p", help="fixed or starting value name=value (default: shipped)"),
    grid: list[str] = typer.Option(None, "--grid", "-g", help="grid values name=v1,v2,... (repeatable): grid mode"),
    cv: bool = typer.Option(False, "--cv", help="grid mode: leave-one-recording-out cross-validation"),
    cache: Path = typer.Option(None, "--cache", help="grid mode: JSON file of scores to reuse and extend"),
    balance: str = typer.Option("recording", "--balance",
                                help="grid mode: one vote per 'recording', or per 'dataset' (the recording's kind, e.g. broad)"),
    objective: str = typer.Option("mae", help="non-BROAD recordings: mae or rmse"),
    train: str = typer.Option(None, help="sliding mode: score only samples A:B while tuning (e.g. 0:2799)"),
    as_json: bool = typer.Option(False, "--json"),
):
    """Sliding grid search, or a full grid with leave-one-recording-out cross-validation."""
    if filter_name not in FILTERS:
        fail(f"unknown filter {filter_name!r}; choose one of {', '.join(FILTERS)}")
        raise typer.Exit(2)
    if objective not in ("mae", "rmse"):
        fail("--objective must be mae or rmse")
        raise typer.Exit(2)
    try:
        fixed = parse_params(param)
        start_settings = settings_with(FILTERS[filter_name].Settings(), fixed)
        grid_values = _parse_grid(grid or [], start_settings)
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    if cv and not grid_values:
        fail("--cv needs a --grid")
        raise typer.Exit(2)
    if balance not in ("recording", "dataset"):
        fail(f"--balance must be recording or dataset, got {balance!r}")
        raise typer.Exit(2)
    recordings, _ = load_all(files)
    if not recordings:
        raise typer.Exit(2)
    if grid_values:
        report = _grid_mode(recordings, filter_name, fixed, grid_values, cv, cache, objective, balance)
        if as_json:
            print_json(report)
        else:
            _print_grid(report)
        return

    span = _parse_span(train)
    start = {f.name: float(getattr(start_settings, f.name)) for f in dataclasses.fields(start_settings)
             if f.name not in NOT_TUNED and isinstance(getattr(start_settings, f.name), float)}

    def score(p: dict[str, float], samples: slice = span) -> tuple[float, float]:
        return pooled([score_orientation(r, filter_name, p, samples=samples) for r in recordings])

    def obj(p):
        mae, rmse = score(p)
        return mae if objective == "mae" else rmse

    result = sliding_grid_search(obj, start, progress=lambda p, v: err.print(f"  {p} -> {v:.4f}", highlight=False))
    mae, rmse = score(result.params, slice(None))
    report = {"filter": filter_name, "params": result.params, "objective": objective, "train": train or "all",
              "train_value": result.value, "mae_deg": mae, "rmse_deg": rmse, "evaluations": result.evaluations}
    if as_json:
        print_json(report)
    else:
        out.print(f"[bold]{filter_name}[/] best {result.params} after {result.evaluations} evaluations")
        out.print(f"train ({train or 'all'}) {objective} {result.value:.3f}°; whole recordings MAE {mae:.3f}°, RMSE {rmse:.3f}°")


def _grid_mode(recordings, filter_name, fixed, grid_values, cv, cache, objective, balance="recording") -> dict:
    points = grid_points(grid_values)
    names = [Path(r.source).name for r in recordings]
    stored: dict = {}
    if cache is not None and cache.exists():
        stored = json.loads(cache.read_text())
    table = np.empty((len(points), len(recordings)))
    for i, point in enumerate(progress(points, "grid")):
        params = {**fixed, **point}
        for j, rec in enumerate(recordings):
            key = json.dumps([filter_name, objective, names[j], sorted(params.items())])
            if key not in stored:
                stored[key] = file_score(rec, filter_name, params, objective)
            table[i, j] = stored[key]
        if cache is not None and (i % 20 == 19 or i == len(points) - 1):
            cache.write_text(json.dumps(stored))
    groups = [r.kind for r in recordings] if balance == "dataset" else None
    means = criterion(table, range(len(recordings)), groups)
    best = int(np.argmin(means))
    kinds = sorted({r.kind for r in recordings})
    report = {
        "filter": filter_name, "fixed": fixed, "grid": grid_values, "recordings": names,
        "score": "BROAD: total RMSE over movement samples; others: " + objective.upper() + " from the reference start (deg)",
        "balance": balance,
        "criterion": "mean over recordings" if groups is None else "mean over data sets of the mean within each",
        "chosen": {"params": points[best], "mean_deg": float(means[best]),
                   "per_dataset_deg": {k: float(np.mean([table[best, j] for j, r in enumerate(recordings) if r.kind == k]))
                                       for k in kinds},
                   "per_recording_deg": dict(zip(names, table[best].tolist()))},
        "top": [{"params": points[i], "mean_deg": float(means[i])} for i in np.argsort(means)[:10]],
    }
    if cv:
        result = leave_one_out(table, groups)
        held = {k: float(np.mean([v for j, _, v in result.folds if recordings[j].kind == k])) for k in kinds}
        report["cross_validation"] = {
            "scheme": "leave one recording out: the grid point with the lowest criterion over the other recordings, "
                      "scored on the held-out one",
            "held_out_mean_by_dataset_deg": held,
            "held_out_mean_deg": result.held_out_mean,
            "folds": [{"held_out": names[j], "params": points[i], "held_out_deg": v} for j, i, v in result.folds],
        }
    return report


def _print_grid(report: dict) -> None:
    c = report["chosen"]
    out.print(f"[bold]{report['filter']}[/] chosen on all {len(report['recordings'])} recordings ({report['criterion']}): "
              f"{c['params']} criterion {c['mean_deg']:.3f}°")
    for k, v in c["per_dataset_deg"].items():
        out.print(f"  {k} mean: {v:.3f}°")
    for name, v in c["per_recording_deg"].items():
        out.print(f"  {name}: {v:.3f}°")
    if "cross_validation" in report:
        cvr = report["cross_validation"]
        out.print(f"leave-one-recording-out: held-out mean {cvr['held_out_mean_deg']:.3f}°; by data set "
                  + ", ".join(f"{k} {v:.3f}°" for k, v in cvr["held_out_mean_by_dataset_deg"].items()))
        for f in cvr["folds"]:
            out.print(f"  {f['held_out']}: {f['held_out_deg']:.3f}° with {f['params']}")
