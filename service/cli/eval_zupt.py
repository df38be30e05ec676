"""``firetrack eval zupt``: the boot-mounted INS against Vicon and ground control points, next to PyShoe.

Registered on the eval app (``service/cli/eval.py``). Scores come from
:mod:`pdr.evaluation.zupt`: ATE after an SE(2) fit and final error as % of the distance on
Vicon files; mean/final error at the ground control points on hallway files; the same for
the file's published PyShoe track, with its own fit. ``--cv`` reruns the grid the shipped
defaults were chosen on and prints the cross-validated (held-out) figures.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import re
import time
from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from pdr.evaluation.zupt import FileScore, cross_validate, score_recording, summary
from pdr.settings import settings_with
from pdr.zupt.settings import DETECTORS, ZuptSettings
from service.cli.recordings import load_all
from service.protocol.terminal import err, fail, out, parse_params, print_json, progress

# The settings chosen from data, and the grid they were chosen on (see docs/zupt.md).
CV_GRID = {
    "detector.shoe_threshold": (5e3, 1e4, 2e4),
    "detector.adaptive_exponent": (3.0, 4.0, 5.0),
    "detector.adaptive_max_threshold": (2e5, 3e5, 5e5),
    "detector.adaptive_floor_factor": (0.0, 3.0),
    "ins.acc_noise_density": tuple(a / math.sqrt(200.0) for a in (0.02, 0.05, 0.1)),
    "ins.gyro_noise_density": tuple(math.radians(g) / math.sqrt(200.0) for g in (0.5, 1.0, 2.0)),
    "ins.init_gyro_bias_sigma": (1e-4, 3e-4, 1e-3),
}


def zupt_settings(detector: str | None, params: dict[str, str]) -> ZuptSettings:
    """Defaults, with the detector and ``section.name=value`` overrides (sections: detector, ins,
    stride, gait)."""
    s = ZuptSettings()
    if detector is not None:
        s = dataclasses.replace(s, detector=dataclasses.replace(s.detector, detector=detector))
    by_section: dict[str, dict[str, str]] = {}
    for key, value in params.items():
        section, dot, name = key.partition(".")
        if not dot or section not in ("detector", "ins", "stride", "gait"):
            raise ValueError(f"--param {key!r}: write section.name=value, section one of detector, ins, stride, gait")
        by_section.setdefault(section, {})[name] = value
    for section, values in by_section.items():
        s = dataclasses.replace(s, **{section: settings_with(getattr(s, section), values)})
    return s


def eval_zupt(
    files: list[Path] = typer.Argument(..., help="PyShoe .mat recordings (Vicon and hallway files)"),
    detector: str = typer.Option(None, "--detector", "-d", help=f"zero-velocity detector: {', '.join(DETECTORS)}"),
    param: list[str] = typer.Option(None, "--param", "-p", help="override a setting: section.name=value, "
                                    "e.g. detector.shoe_threshold=2e4 or ins.zupt_sigma=0.02"),
    per_frame: int = typer.Option(0, "--per-frame", help="feed the model in frames of this many samples (0: at once)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    plot: Path = typer.Option(None, "--plot", help="write one PNG per file (track, truth, PyShoe) into this folder"),
    cv: bool = typer.Option(False, "--cv", help="also cross-validate the data-chosen settings over the Vicon files "
                            "(a grid of 1458 settings: about ten minutes)"),
):
    """Boot INS track vs. truth and vs. PyShoe: ATE (m) after an SE(2) fit, final error (% of distance),
    errors at ground control points (m)."""
    try:
        settings = zupt_settings(detector, parse_params(param))
    except ValueError as e:
        fail(str(e))
        raise typer.Exit(2)
    if per_frame < 0:
        fail("--per-frame must be >= 0")
        raise typer.Exit(2)
    recordings, bad = load_all(files)
    recordings = [r for r in recordings if _pyshoe(r)]
    if not recordings:
        fail("no PyShoe recording to score")
        raise typer.Exit(2)
    scores: list[FileScore] = []
    for rec in progress(recordings, "running the INS"):
        try:
            scores.append(score_recording(rec, settings, per_frame or None))
        except ValueError as e:
            fail(str(e))
            bad += 1
    report = {"settings": dataclasses.asdict(settings), "files": [s.as_dict() for s in scores],
              "summary": summary(scores)}
    if cv:
        report["cross_validation"] = cross_validation(recordings, settings)
    if plot is not None:
        _plot(scores, plot)
    if as_json:
        print_json(report)
    else:
        _table(scores, report)
    if bad:
        raise typer.Exit(1)


def _pyshoe(rec) -> bool:
    if rec.kind != "pyshoe":
        fail(f"{rec.source}: not a PyShoe recording ({rec.kind}); skipped")
        return False
    return True


def _session(source: str) -> str:
    """Recording session (day) of a file, for leave-one-session-out: the date in its name."""
    m = re.search(r"(\d{4}-\d{2}-\d{2})", Path(source).name)
    return m.group(1) if m else Path(source).name


def cross_validation(recordings, base: ZuptSettings) -> dict:
    """ATE on the Vicon files for every point of :data:`CV_GRID`; held-out figures of choosing by
    the mean over the other files (leave one file out; leave one recording session out)."""
    vicon = [r for r in recordings if r.position_ref is not None]
    if len(vicon) < 2:
        return {"error": "cross-validation needs at least two Vicon files"}
    names = list(CV_GRID)
    combos = list(itertools.product(*CV_GRID.values()))
    errors = np.empty((len(combos), len(vicon)))
    t0 = time.time()
    for i, combo in enumerate(progress(combos, "cross-validation grid")):
        s = base
        for key, value in zip(names, combo):
            section, _, name = key.partition(".")
            s = dataclasses.replace(s, **{section: dataclasses.replace(getattr(s, section), **{name: value})})
        for j, rec in enumerate(vicon):
            errors[i, j] = score_recording(rec, s).ours.ate_rmse_m
    loo = cross_validate(errors)
    sessions = np.array([_session(r.source) for r in vicon])
    loso = cross_validate(errors, sessions) if np.unique(sessions).size > 1 else None
    best = int(np.argmin(errors.mean(axis=1)))
    err.print(f"cross-validation: {len(combos)} settings x {len(vicon)} files in {time.time() - t0:.0f} s")
    return {
        "grid": {k: list(v) for k, v in CV_GRID.items()},
        "files": [r.source for r in vicon],
        "in_sample_best": {"settings": dict(zip(names, combos[best])), "mean_ate_rmse_m": float(errors[best].mean())},
        "leave_one_file_out": {"mean_ate_rmse_m": loo["mean"], "median_ate_rmse_m": loo["median"],
                               "held_out_ate_rmse_m": loo["held_out"]},
        "leave_one_session_out": None if loso is None else {
            "mean_ate_rmse_m": loso["mean"], "median_ate_rmse_m": loso["median"],
            "sessions": sorted(set(sessions.tolist())), "held_out_ate_rmse_m": loso["held_out"]},
    }


def _table(scores: list[FileScore], report: dict) -> None:
    vicon = [s for s in scores if s.kind == "vicon"]
    hall = [s for s in scores if s.kind == "gcp"]
    if vicon:
        t = Table(title="Vicon files: ATE after SE(2) fit (m), final error (% of distance)")
        for col in ("file", "dist m", "strides", "ATE ours", "ATE PyShoe", "final % ours", "final % PyShoe"):
            t.add_column(col, justify="left" if col == "file" else "right", no_wrap=col == "file")
        for s in vicon:
            p = s.pyshoe
            t.add_row(Path(s.source).name, f"{s.distance_m:.1f}", str(s.strides), f"{s.ours.ate_rmse_m:.3f}",
                      _f(p and p.ate_rmse_m, 3), f"{s.ours.final_error_pct:.2f}", _f(p and p.final_error_pct, 2))
        sm = report["summary"]["vicon"]
        t.add_row("mean", f"{sm['distance_m']:.0f}", "", f"{sm['ours']['mean_ate_rmse_m']:.3f}",
                  _f(sm["pyshoe"]["mean_ate_rmse_m"], 3), f"{sm['ours']['mean_final_error_pct']:.2f}",
                  _f(sm["pyshoe"]["mean_final_error_pct"], 2))
        out.print(t)
    if hall:
        t = Table(title="Hallway files: error at the ground control points after SE(2) fit (m)")
        for col in ("file", "dist m", "GCP", "strides", "mean ours", "mean PyShoe", "final ours", "final PyShoe"):
            t.add_column(col, justify="left" if col == "file" else "right", no_wrap=col == "file")
        for s in hall:
            p = s.pyshoe
            t.add_row(Path(s.source).name, f"{s.distance_m:.1f}", str(s.gcp), str(s.strides), f"{s.ours.gcp_mean_m:.2f}",
                      _f(p and p.gcp_mean_m, 2), f"{s.ours.gcp_final_m:.2f}", _f(p and p.gcp_final_m, 2))
        sm = report["summary"]["gcp"]
        t.add_row("mean", f"{sm['distance_m']:.0f}", "", "", f"{sm['ours']['mean_gcp_mean_m']:.2f}",
                  _f(sm["pyshoe"]["mean_gcp_mean_m"], 2), f"{sm['ours']['mean_gcp_final_m']:.2f}",
                  _f(sm["pyshoe"]["mean_gcp_final_m"], 2))
        out.print(t)
    cvr = report.get("cross_validation")
    if cvr and "error" not in cvr:
        out.print(f"cross-validated mean ATE (m): leave one file out {cvr['leave_one_file_out']['mean_ate_rmse_m']:.4f}"
                  + (f", leave one session out {cvr['leave_one_session_out']['mean_ate_rmse_m']:.4f}"
                     if cvr["leave_one_session_out"] else "")
                  + f"; in-sample best {cvr['in_sample_best']['mean_ate_rmse_m']:.4f}")


def _f(v, digits: int) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _plot(scores: list[FileScore], folder: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pdr.io import load

    folder.mkdir(parents=True, exist_ok=True)
    for s in scores:
        rec = load(s.source)
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.2, 1]})
        if rec.position_ref is not None:
            ref = rec.position_ref.values
            ax.plot(ref[:, 0], ref[:, 1], color="k", lw=1.0, label="Vicon")
        if "gcp" in rec.meta:
            g = rec.meta["gcp"]
            ax.plot(g[:, 0], g[:, 1], "o", color="k", ms=2.5, label="ground control points")
        if s.pyshoe is not None and s.pyshoe.aligned is not None:
            ax.plot(s.pyshoe.aligned[:, 0], s.pyshoe.aligned[:, 1], color="tab:blue", lw=0.8, label="PyShoe")
        ax.plot(s.ours.aligned[:, 0], s.ours.aligned[:, 1], color="tab:red", lw=0.8, label="firetrack ZUPT INS")
        ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=Path(s.source).name)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        t = s.run.t
        if rec.position_ref is not None:
            ref = rec.position_ref.values
            bx.plot(t - t[0], np.linalg.norm(s.ours.aligned - ref, axis=1), color="tab:red", lw=0.7,
                    label=f"ours (ATE {s.ours.ate_rmse_m:.3f} m)")
            if s.pyshoe is not None:
                bx.plot(t - t[0], np.linalg.norm(s.pyshoe.aligned - ref, axis=1), color="tab:blue", lw=0.7,
                        label=f"PyShoe (ATE {s.pyshoe.ate_rmse_m:.3f} m)")
            bx.set(ylabel="position error (m)")
        else:
            idx, g = rec.meta["stride_index"], rec.meta["gcp"]
            bx.plot(t[idx] - t[0], np.linalg.norm(s.ours.aligned[idx] - g, axis=1), "o-", color="tab:red", ms=2,
                    lw=0.7, label=f"ours (mean {s.ours.gcp_mean_m:.2f} m)")
            if s.pyshoe is not None:
                bx.plot(t[idx] - t[0], np.linalg.norm(s.pyshoe.aligned[idx] - g, axis=1), "o-", color="tab:blue",
                        ms=2, lw=0.7, label=f"PyShoe (mean {s.pyshoe.gcp_mean_m:.2f} m)")
            bx.set(ylabel="error at the ground control points (m)")
        bx.fill_between(t - t[0], 0, 1, where=s.run.stationary, transform=bx.get_xaxis_transform(), color="0.85",
                        label="zero velocity")
        bx.set(xlabel="time (s)")
        bx.legend(fontsize=8)
        bx.grid(alpha=0.3)
        fig.tight_layout()
        target = folder / (Path(s.source).name.split(".")[0] + "_zupt.png")
        fig.savefig(target, dpi=110)
        plt.close(fig)
        err.print(f"wrote {target}")
