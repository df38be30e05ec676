"""Deterministic sliding grid search for filter gains (Justa 2022, §6.2 / ref. [99]).

The dissertation found Nelder-Mead unreliable on this non-convex problem and stochastic
search irreproducible, so it tunes with a deterministic local grid: around the current
point, each parameter is tried at 8 relative distances (×(1 ± r), r ∈ ``relative``) and
2 absolute ones (± its ``absolute`` step, which lets a parameter leave zero); the best
point is kept and the search repeats until no candidate improves. Same inputs, same
answer, every time.

:func:`grid_points` and :func:`leave_one_out` choose settings by cross-validation instead:
every point of a fixed grid is scored on every recording, and for each recording the
point chosen on all the *others* is scored on it. The mean of those held-out scores is the
figure that says how well the choice generalises; the point chosen on all recordings is
the one to ship.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

RELATIVE = (0.5, 0.25, 0.1, 0.05)  # 8 relative distances: ×(1 ± r)


@dataclass
class SearchResult:
    params: dict[str, float]
    value: float
    evaluations: int
    history: list[tuple[dict[str, float], float]] = field(default_factory=list)


def sliding_grid_search(
    objective: Callable[[dict[str, float]], float],
    start: dict[str, float],
    absolute: dict[str, float] | None = None,
    relative: tuple[float, ...] = RELATIVE,
    max_rounds: int = 50,
    lower: float = 0.0,
    progress: Callable[[dict[str, float], float], None] | None = None,
) -> SearchResult:
    """Minimise ``objective(params)`` from ``start``; parameters stay ``>= lower``."""
    absolute = absolute or {k: max(abs(v) * 0.01, 1e-6) for k, v in start.items()}
    best = dict(start)
    cache: dict[tuple, float] = {}

    def evaluate(p: dict[str, float]) -> float:
        key = tuple(sorted(p.items()))
        if key not in cache:
            cache[key] = float(objective(p))
            if progress is not None:
                progress(p, cache[key])
        return cache[key]

    best_value = evaluate(best)
    history = [(dict(best), best_value)]
    for _ in range(max_rounds):
        improved = False
        for name in sorted(best):
            x = best[name]
            candidates = [x * (1 + s * r) for r in relative for s in (1, -1)]
            candidates += [x + absolute[name], x - absolute[name]]
            for c in candidates:
                if c < lower or c == x:
                    continue
                trial = dict(best, **{name: c})
                v = evaluate(trial)
                if v < best_value:
                    best, best_value, improved = trial, v, True
            history.append((dict(best), best_value))
        if not improved:
            break
    return SearchResult(best, best_value, len(cache), history)


# ---------------------------------------------------------------------------------------------
# Grid search with leave-one-recording-out cross-validation
# ---------------------------------------------------------------------------------------------


def grid_points(grid: dict[str, list[float]]) -> list[dict[str, float]]:
    """Every combination of the values in ``grid`` (the first name varies slowest)."""
    points: list[dict[str, float]] = [{}]
    for name, values in grid.items():
        if not values:
            raise ValueError(f"grid for {name!r} has no values")
        points = [dict(p, **{name: float(v)}) for p in points for v in values]
    return points


@dataclass
class CrossValidation:
    """Leave-one-out over the columns (recordings) of a score table (rows: grid points)."""

    chosen: int  # row minimising the criterion over every recording: the defaults to ship
    folds: list[tuple[int, int, float]]  # (held-out column, row chosen without it, its held-out score)

    @property
    def held_out_mean(self) -> float:
        """The cross-validated figure: mean of the held-out scores."""
        return sum(f[2] for f in self.folds) / len(self.folds)


def criterion(table, columns, groups=None) -> np.ndarray:
    """The selection criterion of every grid point over the recordings ``columns``.

    Without ``groups``: the mean score over those recordings, each one vote. With
    ``groups`` (one label per recording, e.g. its data set): the mean over groups of the
    mean within each group, so every data set (every IMU) has one vote however many
    recordings it holds:

        J_i = (1/|G|) Σ_g (1/|C_g|) Σ_{j ∈ C_g} table[i, j]

    where ``G`` are the groups present among ``columns`` and ``C_g`` their columns.
    """
    t = np.asarray(table, dtype=float)
    cols = list(columns)
    if groups is None:
        return t[:, cols].mean(axis=1)
    labels = [groups[j] for j in cols]
    means = [t[:, [j for j, g in zip(cols, labels) if g == label]].mean(axis=1) for label in dict.fromkeys(labels)]
    return np.mean(means, axis=0)


def leave_one_out(table, groups=None) -> CrossValidation:
    """For each recording j: the grid point with the lowest criterion over the others, scored on j.

    ``table[i][j]`` is grid point i's score (lower is better) on recording j; ``groups``
    (optional, one label per recording) balances the criterion by group (:func:`criterion`).
    Ties go to the first point, so the result is deterministic.
    """
    t = np.asarray(table, dtype=float)
    if t.ndim != 2 or t.shape[0] == 0 or t.shape[1] < 2:
        raise ValueError(f"leave-one-out needs a points x recordings table with >= 2 recordings, got {t.shape}")
    if groups is not None and len(groups) != t.shape[1]:
        raise ValueError(f"{len(groups)} group labels for {t.shape[1]} recordings")
    n = t.shape[1]
    folds = []
    for j in range(n):
        i = int(np.argmin(criterion(t, [k for k in range(n) if k != j], groups)))
        folds.append((j, i, float(t[i, j])))
    return CrossValidation(int(np.argmin(criterion(t, range(n), groups))), folds)
