"""``firetrack eval ahrs``: orientation error of the filters against a reference."""
from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from pdr.evaluation.orientation import OrientationScore, pooled, score_orientation
from service.cli.recordings import load_all
from service.protocol.terminal import (
    err,
    fail,
    out,
    parse_params,
    print_json,
)


def eval_ahrs(
    files: list[Path] = typer.Argument(..., help="recordings with an orientation reference (e.g. Justa_dataset.mat)"),
    filter_names: list[str] = typer.Option(["fscf"], "--filter", "-f", help="fscf, scf, madgwick, complementary; repeat to compare"),
    param: list[str] = typer.Option(None, "--param", "-p", help="override a setting of the (first) filter: name=value"),
    no_mag: bool = typer.Option(False, "--no-mag", help="the IMU-only path (no magnetometer)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    plot: Path = typer.Option(None, "--plot", help="write a PNG of the error over time per file into this folder"),
):
    """Orientation error against a reference: MAE and RMSE of angle(q_ref ⊗ q_est*), degrees."""
    try:
        params = parse_params(param)
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    recordings, bad = load_all(files)
    results: dict[str, list[OrientationScore]] = {}
    for i, name in enumerate(filter_names):
        scores = []
        for rec in recordings:
            try:
                scores.append(score_orientation(rec, name, params if i == 0 else None, use_mag=not no_mag))
            except ValueError as e:
                fail(str(e))
                raise typer.Exit(2)
        results[name] = scores
    if not recordings:
        raise typer.Exit(2)
    reports = []
    for name, scores in results.items():
        mae, rmse = pooled(scores)
        reports.append({
            "filter": name,
            "files": [{"file": s.source, "mae_deg": s.mae_deg, "rmse_deg": s.rmse_deg} for s in scores],
            "mae_deg": mae,
            "rmse_deg": rmse,
        })
    if plot is not None:
        _plot_errors(results, plot)
    if as_json:
        print_json(reports[0] if len(reports) == 1 else {"filters": reports})
    else:
        table = Table(title="orientation error against the reference (deg)")
        for col, just in (("file", "left"), ("filter", "left"), ("MAE", "right"), ("RMSE", "right")):
            table.add_column(col, justify=just)
        for j, rec in enumerate(recordings):
            for r in reports:
                f = r["files"][j]
                table.add_row(Path(rec.source).name, r["filter"], f"{f['mae_deg']:.2f}", f"{f['rmse_deg']:.2f}")
        if len(recordings) > 1:
            for r in reports:
                table.add_row("all (pooled)", r["filter"], f"{r['mae_deg']:.2f}", f"{r['rmse_deg']:.2f}")
        out.print(table)
    if bad:
        raise typer.Exit(1)


def _plot_errors(results: dict[str, list[OrientationScore]], folder: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    n_files = len(next(iter(results.values())))
    for j in range(n_files):
        fig, ax = plt.subplots(figsize=(10, 4))
        for name, scores in results.items():
            s = scores[j]
            ax.plot(s.errors_deg, lw=0.7, label=f"{name} (MAE {s.mae_deg:.2f}°)")
        source = next(iter(results.values()))[j].source
        ax.set(xlabel="sample", ylabel="error (deg)", title=Path(source).name)
        ax.legend()
        ax.grid(alpha=0.3)
        target = folder / (Path(source).name.split(".")[0] + "_ahrs_error.png")
        fig.tight_layout()
        fig.savefig(target, dpi=110)
        plt.close(fig)
        err.print(f"wrote {target}")


# Commands defined in their own modules register themselves on ``app`` when imported.
