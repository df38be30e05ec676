"""``firetrack tune``: the deterministic parameter search beside the filters."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from pdr.ahrs import FILTERS, settings_with
from pdr.ahrs.tuning import sliding_grid_search
from pdr.evaluation.orientation import pooled, score_orientation
from service.cli.recordings import load_all
from service.protocol.terminal import err, fail, out, parse_params, print_json

app = typer.Typer(help="Tune algorithm settings on recordings with ground truth.", no_args_is_help=True)

NOT_TUNED = {"max_dt", "alpha"}


def _parse_span(span: str | None) -> slice:
    if not span:
        return slice(None)
    a, _, b = span.partition(":")
    return slice(int(a) if a else None, int(b) if b else None)


@app.command("ahrs")
def tune_ahrs(
    files: list[Path] = typer.Argument(..., help="recordings with an orientation reference"),
    filter_name: str = typer.Option("fscf", "--filter", "-f"),
    param: list[str] = typer.Option(None, "--param", "-p", help="starting value name=value (default: shipped)"),
    objective: str = typer.Option("mae", help="mae or rmse"),
    train: str = typer.Option(None, help="score only samples A:B while tuning (e.g. 0:2799); the report shows all"),
    as_json: bool = typer.Option(False, "--json"),
):
    """Sliding grid search (Justa 2022 §6.2): 8 relative + 2 absolute steps per gain, until no step improves."""
    if filter_name not in FILTERS:
        fail(f"unknown filter {filter_name!r}; choose one of {', '.join(FILTERS)}")
        raise typer.Exit(2)
    if objective not in ("mae", "rmse"):
        fail("--objective must be mae or rmse")
        raise typer.Exit(2)
    try:
        start_settings = settings_with(FILTERS[filter_name].Settings(), parse_params(param))
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    recordings, _ = load_all(files)
    if not recordings:
        raise typer.Exit(2)
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
