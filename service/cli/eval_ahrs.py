"""``firetrack eval ahrs``: orientation error of the filters against a reference, with each data set's metric."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from pdr.ahrs import DEFAULT_FILTER, FILTERS
from pdr.evaluation.baselines import BASELINES, BaselineUnavailable, run_baseline
from pdr.evaluation.orientation import (
    BenchmarkScore,
    OrientationScore,
    benchmark_score,
    benchmark_summary,
    orientation_score,
    pooled,
    score_benchmark,
    score_orientation,
)
from pdr.io import load_broad_groups
from pdr.io.errors import RecordingFormatError
from service.cli.recordings import load_all
from service.protocol.terminal import (
    err,
    fail,
    out,
    parse_params,
    print_json,
    warn,
)


def eval_ahrs(
    files: list[Path] = typer.Argument(..., help="recordings with an orientation reference (Justa_dataset.mat, BROAD trials)"),
    filter_names: list[str] = typer.Option([DEFAULT_FILTER], "--filter", "-f",
                                           help=f"{', '.join(FILTERS)}; repeat to compare"),
    param: list[str] = typer.Option(None, "--param", "-p", help="override a setting of the (first) filter: name=value"),
    baseline: list[str] = typer.Option(None, "--baseline", "-b",
                                       help=f"also run a peer with its own defaults: {', '.join(BASELINES)}"),
    groups_file: Path = typer.Option(None, "--groups", help="BROAD trials.json (default: the one beside the first BROAD file)"),
    no_mag: bool = typer.Option(False, "--no-mag", help="the IMU-only path (no magnetometer)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    plot: Path = typer.Option(None, "--plot", help="write PNGs of the error over time into this folder"),
):
    """Orientation error against a reference, with the metric each data set defines.

    Justa-style recordings (Vicon AHRS set): the filter starts from the reference; MAE and
    RMSE of angle(q_ref ⊗ q_est*) over all samples. BROAD trials: the filter starts from its
    own estimate; RMSE of the total, heading and inclination error over the movement
    samples, the mean over trials and by group (trials.json). Degrees.
    """
    try:
        params = parse_params(param)
        for b in baseline or []:
            if b not in BASELINES:
                raise ValueError(f"unknown baseline {b!r}; choose one of {', '.join(BASELINES)}")
        for name in filter_names:
            if name.lower() not in FILTERS:
                raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTERS)}")
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    recordings, bad = load_all(files)
    if not recordings:
        raise typer.Exit(2)
    broad = [r for r in recordings if r.kind == "broad"]
    vicon = [r for r in recordings if r.kind != "broad"]
    groups = _broad_groups(groups_file, broad)
    runs = [(name, "filter") for name in filter_names] + [(b, "baseline") for b in baseline or []]
    reports, curves = [], {}
    for i, (name, role) in enumerate(runs):
        p = params if i == 0 else None
        try:
            report, curve = _evaluate(name, role, p, vicon, broad, groups, use_mag=not no_mag)
        except BaselineUnavailable as e:
            fail(str(e))
            raise typer.Exit(2)
        except ValueError as e:
            fail(str(e))
            raise typer.Exit(2)
        reports.append(report)
        curves[name] = curve
    if plot is not None:
        _plot_errors({k: v["vicon"] for k, v in curves.items()}, plot)
        if broad:
            _plot_broad({k: v["broad"] for k, v in curves.items()}, plot)
    if as_json:
        if len(reports) == 1:
            print_json(reports[0])
        else:
            doc = {"filters": reports}
            if broad:
                doc["comparison"] = _comparison(reports)
            print_json(doc)
    else:
        _print_tables(reports, vicon, broad)
    if bad:
        raise typer.Exit(1)


def _broad_groups(groups_file: Path | None, broad) -> dict[str, list[str]]:
    if not broad:
        return {}
    path = groups_file or Path(broad[0].source).parent / "trials.json"
    if not path.exists():
        warn(f"{path}: not found; BROAD group means are left out (give --groups)")
        return {}
    try:
        return load_broad_groups(path)
    except RecordingFormatError as e:
        warn(f"{e}; BROAD group means are left out")
        return {}


def _evaluate(name, role, params, vicon, broad, groups, use_mag):
    """One filter or baseline over every recording: its report and its error curves."""
    report: dict = {"filter": name}
    if role == "baseline":
        report["baseline"] = True
    curves: dict = {"vicon": [], "broad": []}
    if vicon:
        scores = []
        for rec in vicon:
            if role == "baseline":
                q = run_baseline(name, rec, use_mag)
                scores.append(orientation_score(rec, q, name))
            else:
                scores.append(score_orientation(rec, name, params, use_mag=use_mag))
        mae, rmse = pooled(scores)
        report.update({"files": [{"file": s.source, "mae_deg": s.mae_deg, "rmse_deg": s.rmse_deg} for s in scores],
                       "mae_deg": mae, "rmse_deg": rmse})
        curves["vicon"] = scores
    if broad:
        scores = []
        for rec in broad:
            if role == "baseline":
                scores.append(benchmark_score(rec, run_baseline(name, rec, use_mag), name))
            else:
                scores.append(score_benchmark(rec, name, params, use_mag=use_mag))
        report["broad"] = {"metric": "RMSE over movement samples, filter started from its own estimate",
                           "trials": [s.as_dict() for s in scores], **benchmark_summary(scores, groups)}
        curves["broad"] = scores
    return report, curves


def _comparison(reports: list[dict]) -> dict:
    """Mean total RMSE of every filter and baseline, overall and in each top-level group."""
    cmp = {"mean_total_rmse_deg": {r["filter"]: r["broad"]["mean_total_rmse_deg"] for r in reports if "broad" in r}}
    for g in ("undisturbed", "disturbed"):
        vals = {r["filter"]: r["broad"]["groups"][g]["mean_total_rmse_deg"]
                for r in reports if "broad" in r and g in r["broad"]["groups"]}
        if vals:
            cmp[f"{g}_mean_total_rmse_deg"] = vals
    return cmp


def _print_tables(reports, vicon, broad) -> None:
    if vicon:
        table = Table(title="orientation error against the reference, filter started from it (deg)")
        for col, just in (("file", "left"), ("filter", "left"), ("MAE", "right"), ("RMSE", "right")):
            table.add_column(col, justify=just)
        for j, rec in enumerate(vicon):
            for r in reports:
                f = r["files"][j]
                table.add_row(Path(rec.source).name, r["filter"], f"{f['mae_deg']:.2f}", f"{f['rmse_deg']:.2f}")
        if len(vicon) > 1:
            for r in reports:
                table.add_row("all (pooled)", r["filter"], f"{r['mae_deg']:.2f}", f"{r['rmse_deg']:.2f}")
        out.print(table)
    if broad:
        table = Table(title="BROAD: RMSE over movement samples, filter started from its own estimate (deg)")
        for col, just in (("trial", "left"), ("filter", "left"), ("total", "right"), ("heading", "right"),
                          ("inclination", "right")):
            table.add_column(col, justify=just)

        def row(label, r, d):
            table.add_row(label, r["filter"], *(f"{d[f'{k}']:.2f}" for k in
                                                   ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")))

        for j in range(len(broad)):
            for r in reports:
                row(r["broad"]["trials"][j]["trial"], r, r["broad"]["trials"][j])
        for r in reports:
            b = r["broad"]
            row(f"mean of {len(broad)}", r, {k.replace("mean_", ""): v for k, v in b.items() if k.startswith("mean_")})
        for g in next(iter(reports))["broad"]["groups"]:
            for r in reports:
                d = r["broad"]["groups"][g]
                row(f"{g} ({d['trials']})", r, {k.replace("mean_", ""): v for k, v in d.items() if k.startswith("mean_")})
        out.print(table)


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


def _plot_broad(results: dict[str, list[BenchmarkScore]], folder: Path) -> None:
    """One figure, one panel per trial: total error over time of each filter; movement shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    first = next(iter(results.values()))
    fig, axes = plt.subplots(len(first), 1, figsize=(12, 2.2 * len(first)), squeeze=False)
    for j, ax in enumerate(axes[:, 0]):
        s0 = first[j]
        top = 0.0
        for name, scores in results.items():
            s = scores[j]
            ax.plot(s.t, s.errors_deg[:, 0], lw=0.6, label=f"{name} ({s.rmse_deg():.2f}°)")
            top = max(top, float(np.nanmax(s.errors_deg[s.movement, 0])) if s.movement.any() else 0.0)
        ax.fill_between(s0.t, 0, 1, where=s0.movement, transform=ax.get_xaxis_transform(), color="0.9", zorder=0)
        ax.set_ylim(0, max(1.0, 1.05 * top))
        ax.set_title(s0.trial, fontsize=9)
        ax.set_ylabel("total (deg)")
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s); shaded: movement samples (scored)")
    target = folder / "broad_total_error.png"
    fig.tight_layout()
    fig.savefig(target, dpi=80)
    plt.close(fig)
    err.print(f"wrote {target}")
