"""A walk's estimate in the IPIN 2023 Track 3 result format, and the organisers' metric on it.

**The format** (``firetrack eval ipin FILES --submit DIR``), as the organisers' own evaluation
reads it: their script ``03 Evaluation/evaluateCompetitor2023.m`` in the competition's data
repository (github Kenny5269/2023_IPIN_Competition_Track03, the same Zenodo data set as
``../shared/data/ipin2023``, doi:10.5281/zenodo.8362205) loads a competitor's ``<name>.est``
with ``dlmread(file, ',', 2, 0)``: comma-separated numbers, the first two lines skipped, one
estimate per line, of which it uses column 1 (the trial time, s: the logger's ``AppTimestamp``
clock, the clock of the ``POSI`` lines), 5 (longitude, deg), 6 (latitude, deg) and 7 (floor,
integer). Columns 2-4 are the EvaalAPI's bookkeeping (wall clock, horizon, time-out in their
example ``tr_zenodo/S323ZENODOTS01.est``); the evaluation ignores them. We write the wall clock
0, the horizon :data:`STEP_S`, the time-out 0. Rows come every :data:`STEP_S` (the API's
0.5 s pace, from the walk's first landmark) plus one at each landmark time.

**The ground truth** beside it, ``GT_<name>.csv``, in the organisers' GT format
(``03 Evaluation/GT/GT_IPIN2023_T3_ScoringTrial01.csv``): ``time, longitude, latitude,
floor, index``, one row per scored landmark (landmark 0 and the ones handed to the tracker as
fixes are left out, as ``eval ipin`` leaves them out).

**The metric**, recomputed from these two files alone (:func:`score_files`), the organisers'
way: for each ground-truth row the estimate is the last row at or before its time + 10 ms;
both positions go to a local North-East plane with ``pymap3d.geodetic2ned`` at the ground
truth's smallest latitude and longitude and height :data:`ORGANISERS_HEIGHT_M` (their
``altitudeForThisYear``); error = horizontal distance + 15 m x |floor error|. The organisers
summarise a trial by MATLAB's ``quantile(e, 0.75)``, which places the i-th smallest of n
errors at (i − 0.5)/n (numpy's ``method="hazen"``): ``p75_organisers_m`` per walk. ``eval
ipin`` pools every walk's errors and takes numpy's default (linear) percentile: ``p75_m`` here
is that, and reproduces its figure.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d

from pdr.evaluation.ipin import FLOOR_PENALTY_M

STEP_S = 0.5  # s between estimates (the EvaalAPI's recommended pace)
MATCH_TOLERANCE_S = 0.01  # s: an estimate up to this much after a ground-truth time is taken for it
ORGANISERS_HEIGHT_M = 314.0  # m: the height evaluateCompetitor2023.m gives every point in 2023 (the museum)
LATLON_DECIMALS = 10  # deg: 1e-10 deg is ~0.01 mm


def walk_name(source: str) -> str:
    """``IPIN2023_T3_TrainingTrial01_repetition01`` of ``.../IPIN2023_..._repetition01.txt.gz``."""
    name = Path(source).name
    for suffix in (".gz", ".txt", ".mat"):
        name = name.removesuffix(suffix)
    return name


def estimate_rows(run, incident, step: float = STEP_S) -> np.ndarray:
    """(N, 7) rows ``time, 0, step, 0, lon, lat, floor`` of a run's live track (the poses as
    published: the causal estimate the competition asks for). The estimate at a time is the
    newest pose at or before it (the first pose before any), as ``eval ipin`` scores it."""
    off = run.app_to_sensor_offset_s
    lm_t = np.asarray(run.lm_t, dtype=np.float64)
    scored_t = lm_t[run.scored()]
    scored_app = scored_t - off
    last = float(run.live["t"][-1]) if run.live["t"].size else lm_t[-1]
    grid = np.arange(lm_t[0] - off, max(last, lm_t[-1]) - off + 1e-9, step)
    # a grid row just after a landmark (within twice the match tolerance, to be safe after the
    # file's rounding to 1 ms) would be taken for it instead of the landmark's own row: drop it
    if scored_app.size:
        before = np.searchsorted(scored_app, grid, side="right") - 1
        gap = grid - scored_app[np.maximum(before, 0)]
        grid = grid[~((before >= 0) & (gap <= 2 * MATCH_TOLERANCE_S))]
    t_app = np.concatenate([grid, scored_app])
    t_dev = np.concatenate([grid + off, scored_t])  # the landmark rows at the landmark's own device time
    order = np.argsort(t_app, kind="stable")
    t_app, t_dev = t_app[order], t_dev[order]
    tr = run.live
    i = np.clip(np.searchsorted(tr["t"], t_dev, side="right") - 1, 0, None)
    lat, lon, _ = incident.to_geodetic(tr["x"][i], tr["y"][i])
    n = len(t_app)
    return np.column_stack([t_app, np.zeros(n), np.full(n, step), np.zeros(n), np.atleast_1d(lon), np.atleast_1d(lat),
                            tr["floor"][i].astype(np.float64)])


def ground_truth_rows(run, incident) -> np.ndarray:
    """(M, 5) rows ``time, lon, lat, floor, index`` of the run's scored landmarks."""
    k = run.scored()
    lat, lon, _ = incident.to_geodetic(np.asarray(run.lm_x)[k], np.asarray(run.lm_y)[k])
    t = np.asarray(run.lm_t, dtype=np.float64)[k] - run.app_to_sensor_offset_s
    return np.column_stack([t, np.atleast_1d(lon), np.atleast_1d(lat), np.asarray(run.lm_floor)[k], k.astype(float)])


def write_submission(run, incident, folder: Path) -> tuple[Path, Path]:
    """``<walk>.est`` and ``GT_<walk>.csv`` of one run in ``folder``; returns both paths."""
    folder.mkdir(parents=True, exist_ok=True)
    name = walk_name(run.source)
    est, gt = folder / f"{name}.est", folder / f"GT_{name}.csv"
    rows = estimate_rows(run, incident)
    with open(est, "w", encoding="ascii") as f:
        f.write(f"% firetrack estimate of {name}: IPIN 2023 Track 3 format (evaluateCompetitor2023.m reads from line 3)\n")
        f.write("% time_s,wall_clock_s,horizon_s,timeout_s,longitude_deg,latitude_deg,floor\n")
        for r in rows:
            f.write(f"{r[0]:.3f},{r[1]:.3f},{r[2]:.3f},{r[3]:.3f},{r[4]:.{LATLON_DECIMALS}f},{r[5]:.{LATLON_DECIMALS}f},{int(r[6])}\n")
    with open(gt, "w", encoding="ascii") as f:
        for r in ground_truth_rows(run, incident):
            f.write(f"{r[0]:.3f},{r[1]:.{LATLON_DECIMALS}f},{r[2]:.{LATLON_DECIMALS}f},{int(r[3])},{int(r[4]):03d}\n")
    return est, gt


def read_estimates(path: Path) -> np.ndarray:
    """The (N, 7) numbers of an ``.est`` file, the first two lines skipped (as ``dlmread(f, ',', 2, 0)``)."""
    rows = np.loadtxt(path, delimiter=",", skiprows=2, ndmin=2)
    if rows.shape[1] < 7:
        raise ValueError(f"{path}: {rows.shape[1]} columns, the IPIN format has 7 (time, wall clock, horizon, "
                         "time-out, longitude, latitude, floor)")
    return rows


def organisers_errors(est: np.ndarray, gt: np.ndarray) -> dict[str, np.ndarray]:
    """Per ground-truth row: the matched estimate's horizontal error (m), floor error and
    error + 15 m per floor, the organisers' way (module docstring)."""
    t = est[:, 0]
    j = np.searchsorted(t, gt[:, 0] + MATCH_TOLERANCE_S, side="right") - 1
    if np.any(j < 0):
        raise ValueError(f"no estimate at or before ground-truth time {gt[int(np.argmax(j < 0)), 0]:.3f} s")
    lat0, lon0, h0 = float(gt[:, 2].min()), float(gt[:, 1].min()), ORGANISERS_HEIGHT_M
    n_gt, e_gt, _ = pymap3d.geodetic2ned(gt[:, 2], gt[:, 1], h0, lat0, lon0, h0)
    n_cl, e_cl, _ = pymap3d.geodetic2ned(est[j, 5], est[j, 4], h0, lat0, lon0, h0)
    horiz = np.hypot(np.asarray(n_gt) - n_cl, np.asarray(e_gt) - e_cl)
    floor = est[j, 6].astype(int) - gt[:, 3].astype(int)
    return {"horizontal_m": horiz, "floor_error": floor, "error_m": horiz + FLOOR_PENALTY_M * np.abs(floor)}


def score_files(pairs: list[tuple[Path, Path]]) -> dict:
    """The metric from ``(estimate file, ground-truth file)`` pairs: per walk and pooled."""
    walks, pooled = [], []
    for est_path, gt_path in pairs:
        e = organisers_errors(read_estimates(est_path), np.loadtxt(gt_path, delimiter=",", ndmin=2))
        err = e["error_m"]
        pooled.append(err)
        walks.append({"file": str(est_path), "n_eval": int(err.size),
                      "p75_organisers_m": float(np.percentile(err, 75, method="hazen")) if err.size else None,
                      "p75_m": float(np.percentile(err, 75)) if err.size else None,
                      "floor_accuracy": float(np.mean(e["floor_error"] == 0)) if err.size else None})
    allerr = np.concatenate(pooled) if pooled else np.empty(0)
    return {"walks": walks, "n_eval": int(allerr.size),
            "p75_m": float(np.percentile(allerr, 75)) if allerr.size else None,
            "p75_organisers_m": float(np.percentile(allerr, 75, method="hazen")) if allerr.size else None,
            "median_m": float(np.median(allerr)) if allerr.size else None}
