"""Deterministic sliding grid search for filter gains (Justa 2022, §6.2 / ref. [99]).

The dissertation found Nelder-Mead unreliable on this non-convex problem and stochastic
search irreproducible, so it tunes with a deterministic local grid: around the current
point, each parameter is tried at 8 relative distances (×(1 ± r), r ∈ ``relative``) and
2 absolute ones (± its ``absolute`` step, which lets a parameter leave zero); the best
point is kept and the search repeats until no candidate improves. Same inputs, same
answer, every time.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

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
