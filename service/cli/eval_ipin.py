"""``firetrack eval ipin``: track IPIN 2023 walks from their first landmark and score the others.

With ``--cv`` the figures are leave-one-route-out cross-validated (:mod:`service.review.ipin_cv`): the
headline ``p75_m`` is then the pooled held-out live p75, with the in-sample figure beside it.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import typer
from rich.table import Table

from pdr.evaluation.ipin import summary
from service.cli.recordings import load_all
from service.protocol.terminal import err, fail, out, print_json, progress
from service.review.ipin_run import IpinRun, PdrCache, run_ipin

KINDS = ("live", "smoothed", "pdr")
WALK_SUFFIXES = (".txt", ".txt.gz", ".mat")  # GetSensorData logs and the organisers' .mat parse of them


def walk_files(files: list[Path]) -> tuple[list[Path], list[Path]]:
    """(walks, skipped): the recordings among ``files``; a folder's plans and calibration files
    (``Map_Floor_-01.png``, ``*.cal``, ``*.csv``) are skipped, so ``ipin2023/*`` works."""
    walks, skipped = [], []
    for f in files:
        name = f.name.lower()
        (walks if f.is_dir() or name.endswith(WALK_SUFFIXES) else skipped).append(f)
    return walks, skipped


def eval_ipin(
    files: list[Path] = typer.Argument(..., help="IPIN 2023 walks: GetSensorData logs (.txt, .txt.gz) or the organisers' .mat"),
    fix_every: int = typer.Option(0, "--fix-every", "-k", help="hand landmarks 0, K, 2K, ... to the tracker as checkpoint fixes (0: only the first)"),
    no_gnss: bool = typer.Option(False, "--no-gnss", help="leave the logs' GNSS fixes out"),
    ble: bool = typer.Option(False, "--ble", help="feed the logs' BLE beacon readings as ble scans (beacons from the incident config)"),
    engine: str = typer.Option("fusion", "--engine", help="fusion (gtsam factor graph) or dr (dead reckoning alone)"),
    incident: Path = typer.Option(None, "--incident", help="incident config (origin, floors, floor plans); default: the IPIN museum demo"),
    cv: bool = typer.Option(False, "--cv", help="leave-one-route-out cross-validation of the tuned settings (routes: trial numbers)"),
    cv_grid: str = typer.Option("pdr", "--cv-grid", help="what --cv chooses: pdr (step length, PDR heading, GNSS spacing) or ble (the beacon model; with --ble)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    plot: Path = typer.Option(None, "--plot", help="write a PNG per file (track, heading evidence, floors over time) into this folder"),
    submit: Path = typer.Option(None, "--submit", help="write each walk's live estimate in the IPIN 2023 Track 3 result format "
                                                       "(<walk>.est, with its ground truth GT_<walk>.csv) into this folder and "
                                                       "score those files the organisers' way"),
    perturb: str = typer.Option(None, "--perturb", help="robustness suite: run every walk as logged and under each "
                                "perturbation NAME[,NAME...] or 'all' (names: pdr/evaluation/robustness.py)"),
    seed: str = typer.Option("27", "--seed", help="the robustness suite's random seed, or several (27,1,2): every perturbation once per seed"),
    write_baseline: Path = typer.Option(None, "--write-baseline", help="track every walk at K = 0 and 3 and write "
                                        "the per-walk regression baseline (JSON) to this path"),
    check_baseline: Path = typer.Option(None, "--check-baseline", help="track every walk of this baseline at K = 0 "
                                        "and 3 and name each figure worse by more than 0.5 m (exit 1 if any)"),
):
    """Error at each scored landmark = horizontal distance + 15 m x |floor error|; p75 and median pooled over all files."""
    from service.core.tracker import tracker_settings_for
    from service.protocol.incident import (
        IncidentConfigError,
        default_incident,
        load_incident,
    )

    if engine not in ("fusion", "dr"):
        fail(f"--engine must be fusion or dr, got {engine!r}")
        raise typer.Exit(2)
    if cv and engine != "fusion":
        fail("--cv tunes the fusion: use it with --engine fusion")
        raise typer.Exit(2)
    try:
        cfg = load_incident(incident) if incident else default_incident()
    except IncidentConfigError as e:
        fail(str(e))
        raise typer.Exit(2)
    modes = [o for o, v in (("--cv", cv), ("--perturb", perturb), ("--write-baseline", write_baseline),
                            ("--check-baseline", check_baseline)) if v]
    if len(modes) > 1:
        fail(f"{' and '.join(modes)} cannot be combined")
        raise typer.Exit(2)
    if perturb is not None:
        from pdr.evaluation.robustness import names_from, seeds_from

        try:
            names = names_from(perturb)
            seeds = seeds_from(seed)
        except ValueError as e:
            fail(str(e))
            raise typer.Exit(2)
    # the core's reject log speaks to a live incident's operator; here every refusal is counted
    # per walk instead (the JSON's ``refused``: e.g. a log's GNSS fixes from before its IMU)
    logging.getLogger("firetrack.service").setLevel(logging.ERROR)
    started = time.process_time()
    walks, skipped = walk_files(files)
    if skipped:
        err.print(f"skipped {len(skipped)} file(s) that are not walks: {', '.join(p.name for p in skipped)}")
    recordings, bad = load_all(walks)
    recordings = [r for r in recordings if _has_landmarks(r)]
    settings = tracker_settings_for(cfg, engine)
    if not recordings:
        fail("no walk with landmarks to score")
        raise typer.Exit(2)
    if perturb is not None:
        from service.cli.eval_ipin_robust import robustness

        robustness(recordings, cfg, names, fix_every, not no_gnss, settings, seeds[0] if len(seeds) == 1 else seeds, as_json)
        raise typer.Exit(1 if bad else 0)
    if write_baseline is not None or check_baseline is not None:
        from service.cli.eval_ipin_baseline import baseline_command

        code = baseline_command(recordings, cfg, settings, not no_gnss, write_baseline, check_baseline, incident)
        raise typer.Exit(code or (1 if bad else 0))
    cache = PdrCache()
    if cv:
        from service.review.ipin_cv import BLE_GRID, TUNING_GRID, cross_validate, default_candidate
        from service.review.ipin_cv import report as cv_report

        if cv_grid not in ("pdr", "ble") or (cv_grid == "ble" and not ble):
            fail(f"--cv-grid must be pdr, or ble with --ble; got {cv_grid!r}")
            raise typer.Exit(2)
        grid = BLE_GRID if cv_grid == "ble" else TUNING_GRID
        res = cross_validate(recordings, cfg, fix_every, not no_gnss, settings, cache=cache, progress=progress,
                             grid=grid, use_ble=ble)
        default = default_candidate(settings, grid)
        report = {**_report(res.runs[default or res.in_sample], fix_every, not no_gnss, engine), "cv": cv_report(res, default),
                  "ble": ble}
        pooled = report["cv"]["pooled"]["live"]
        report["in_sample_p75_m"] = report["p75_m"]
        report.update(p75_m=pooled["p75_m"], median_m=pooled["median_m"], floor_accuracy=pooled["floor_accuracy"],
                      n_eval=pooled["n_eval"], headline="cross-validated (leave one route out)")
        runs = [res.runs[res.chosen[r]][i] for i, r in enumerate(res.routes)]
    else:
        runs: list[IpinRun] = []
        for rec in progress(recordings, "tracking"):
            runs.append(run_ipin(rec, cfg, fix_every, not no_gnss, settings, pdr_cache=cache, use_ble=ble))
        report = _report(runs, fix_every, not no_gnss, engine)
    if submit is not None:
        report["submission"] = _submit(runs, cfg, submit)
    report["ble"] = ble
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
        if cv:
            for t in _cv_tables(report):
                out.print(t)
        if submit is not None:
            s = report["submission"]
            out.print(f"IPIN submission in {submit}/: {len(s['walks'])} walk(s); from those files, the organisers' metric: "
                      f"p75 {_fmt(s['p75_m'])} m pooled (numpy's percentile, as above), "
                      f"{_fmt(s['p75_organisers_m'])} m with MATLAB's quantile; n = {s['n_eval']}")
    if bad:
        raise typer.Exit(1)


def _submit(runs: list[IpinRun], cfg, folder: Path) -> dict:
    """Each run's result file and ground truth written, then scored from the files alone."""
    from service.review.ipin_submission import score_files, write_submission

    pairs = [write_submission(r, cfg, folder) for r in runs]
    return {"folder": str(folder), **score_files(pairs)}


def _has_landmarks(rec) -> bool:
    if rec.landmarks is None or len(rec.landmarks) == 0:
        fail(f"{rec.source}: no landmarks (POSI lines) to start from and score against")
        return False
    return True


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
            "files": [{"file": r.source, **summary([e]), "refused": r.refused} for r, e in errs],
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


def _short(name: str) -> str:
    return Path(name).name.replace("IPIN2023_T3_Training", "").split(".")[0]


def _table(report: dict) -> Table:
    kinds = [k for k in KINDS if report.get(k)]
    title = (f"IPIN landmarks, fix every {report['fix_every'] or '— (initial only)'}, "
             f"GNSS {'on' if report['gnss'] else 'off'}, engine {report['engine']} (error m)")
    if "cv" in report:
        title += "; per file: the shipped defaults, in sample"
    table = Table(title=title)
    table.add_column("file")
    for k in kinds:
        table.add_column(f"{k} p75", justify="right")
        table.add_column(f"{k} median", justify="right")
    table.add_column("floor ok", justify="right")
    table.add_column("n", justify="right")
    for i, f in enumerate(report["files"]):
        row = [_short(f["file"])]
        for k in kinds:
            fk = report[k]["files"][i]
            row += [_fmt(fk["p75_m"]), _fmt(fk["median_m"])]
        table.add_row(*row, _fmt(f["floor_accuracy"], ".0%"), str(f["n_eval"]))
    row = ["all (pooled)"]
    for k in kinds:
        row += [f"[bold]{_fmt(report[k]['p75_m'])}[/]", _fmt(report[k]["median_m"])]
    table.add_row(*row, _fmt(report[kinds[0]]["floor_accuracy"], ".0%"), str(report[kinds[0]]["n_eval"]), end_section=True)
    table.caption = f"{report['cpu_s']:.1f} s CPU"
    return table


def _cv_tables(report: dict) -> list[Table]:
    cv = report["cv"]
    routes = Table(title="leave-one-route-out cross-validation: p75 (m) of each route with the setting chosen on the others")
    for col, just in (("route", "left"), ("walks", "right"), ("setting chosen on the other routes", "left"),
                      ("live", "right"), ("smoothed", "right"), ("dead reckoning", "right"), ("live in sample", "right"),
                      ("floor ok", "right")):
        routes.add_column(col, justify=just)
    for r in cv["routes"]:
        routes.add_row(r["route"], str(r["walks"]), r["setting"], _fmt(r["live"]["p75_m"]), _fmt(r["smoothed"]["p75_m"]),
                       _fmt(r["pdr"]["p75_m"]), _fmt(r["live_in_sample"]["p75_m"]), _fmt(r["live"]["floor_accuracy"], ".0%"))
    p, ins = cv["pooled"], cv["in_sample"]
    routes.add_row("[bold]pooled, held out[/]", str(sum(r["walks"] for r in cv["routes"])), "",
                   f"[bold]{_fmt(p['live']['p75_m'])}[/]", _fmt(p["smoothed"]["p75_m"]), _fmt(p["pdr"]["p75_m"]), "",
                   _fmt(p["live"]["floor_accuracy"], ".0%"), end_section=True)
    routes.add_row("in sample", "", ins["setting"], _fmt(ins["live"]["p75_m"]), _fmt(ins["smoothed"]["p75_m"]),
                   _fmt(ins["pdr"]["p75_m"]), "", _fmt(ins["live"]["floor_accuracy"], ".0%"))
    walks = Table(title="per walk, held out: live against dead reckoning, p75 (m)")
    for col in ("walk", "live", "smoothed", "dead reckoning", "live − DR"):
        walks.add_column(col, justify="left" if col == "walk" else "right")
    for w in cv["walks"]:
        d = w["live_minus_pdr_m"]
        flag = "" if d is None or d <= 0.5 else " [red]> 0.5[/]"
        walks.add_row(_short(w["file"]), _fmt(w["live_p75_m"]), _fmt(w["smoothed_p75_m"]), _fmt(w["pdr_p75_m"]),
                      _fmt(d, "+.2f") + flag)
    return [routes, walks]
