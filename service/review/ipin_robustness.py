"""The robustness suite's driver: every walk as logged and under each perturbation, scored alike.

The perturbations and the verdict are :mod:`pdr.evaluation.robustness`; this runs each
perturbed recording through :func:`service.review.ipin_run.run_ipin` (the incident core, as
``eval ipin`` does) and reports, per perturbation, the pooled live and dead-reckoning p75, the
worst walk and the walks it breaks. No PDR cache: every run is a different recording.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from pdr.evaluation.ipin import summary
from pdr.evaluation.robustness import DEFAULT_SEED, PERTURBATIONS, perturbed, verdict
from pdr.recording import Recording
from service.review.ipin_run import IpinRun, run_ipin

UNPERTURBED = "none"


def walk_name(source: str) -> str:
    return Path(source).name.split(".")[0]


def figures(runs: list[IpinRun]) -> dict:
    """Pooled live and dead-reckoning p75 and floor accuracy, and each walk's live p75."""
    live = [r.errors("live") for r in runs]
    pdr = [e for e in (r.errors("pdr") for r in runs) if e is not None]
    pooled = summary([e for e in live if e is not None])
    return {
        "p75_m": pooled["p75_m"],
        "floor_accuracy": pooled["floor_accuracy"],
        "pdr_p75_m": summary(pdr)["p75_m"],
        "walks": {walk_name(r.source): summary([e])["p75_m"] for r, e in zip(runs, live) if e is not None},
    }


def run_suite(recordings: list[Recording], incident, names: list[str], fix_every: int = 0, use_gnss: bool = True,
              settings=None, seed: int | Sequence[int] = DEFAULT_SEED,
              progress: Callable = lambda items, what, total=None: items,
              log: Callable[[str], None] = lambda line: None) -> dict:
    """Run the walks as logged, then under each named perturbation; see the module docstring.

    ``seed``: one seed, or several: then every perturbation runs once per seed (one draw of a
    random perturbation is luck), a row each with its ``seed``, named ``NAME@SEED``.
    ``progress(items, description, total)`` wraps the loop (a bar on a terminal), ``log`` gets a
    line per finished perturbation (for logs that are not terminals)."""
    seeds = [int(seed)] if isinstance(seed, int) else [int(x) for x in seed]
    if not seeds:
        raise ValueError("the robustness suite needs a seed")
    several = len(seeds) > 1
    cases = [(UNPERTURBED, UNPERTURBED, seeds[0])] + [(f"{n}@{s}" if several else n, n, s) for s in seeds for n in names]
    jobs = [(case, rec) for case in cases for rec in recordings]
    runs: dict[str, list[IpinRun]] = {}
    errors: dict[str, list[dict]] = {}
    rows: list[dict] = []
    for (label, name, sd), rec in progress(jobs, "robustness suite", len(jobs)):
        r = rec if name == UNPERTURBED else perturbed(rec, name, sd)
        try:
            runs.setdefault(label, []).append(run_ipin(r, incident, fix_every, use_gnss, settings))
        except Exception as e:  # noqa: BLE001 -- a perturbation that breaks the pipeline is a finding, not the end
            if name == UNPERTURBED:
                raise
            errors.setdefault(label, []).append({"walk": walk_name(rec.source), "error": f"{type(e).__name__}: {e}"[:300]})
            runs.setdefault(label, [])
            log(f"{label}: {walk_name(rec.source)} failed: {errors[label][-1]['error']}")
        if len(runs[label]) + len(errors.get(label, [])) < len(recordings):
            continue
        fig = figures(runs.pop(label))
        fig["errors"] = errors.get(label, [])
        if name == UNPERTURBED:
            base = fig
            base["worst_walk"] = max(fig["walks"], key=fig["walks"].get)
            base["worst_p75_m"] = fig["walks"][base["worst_walk"]]
            log(f"unperturbed: pooled p75 {fig['p75_m']:.2f} m, worst {base['worst_walk']} {base['worst_p75_m']:.2f} m")
            continue
        head = {"name": label, "perturbation": name, "seed": sd, "what": PERTURBATIONS[name].what}
        if not fig["walks"]:
            rows.append({**head, **fig, "passes": False, "broken": []})
            log(f"{label}: no walk could be run: FAIL")
            continue
        row = {**head, **fig, **verdict(base["p75_m"], base["walks"], fig["p75_m"], fig["walks"])}
        row["passes"] = row["passes"] and not fig["errors"]  # a walk the pipeline could not run is broken
        rows.append(row)
        log(f"{label}: pooled p75 {row['p75_m']:.2f} m ({row['pooled_change']:+.0%}), worst {row['worst_walk']} "
            f"{row['worst_p75_m']:.2f} m, {len(row['broken'])} broken: {'pass' if row['passes'] else 'FAIL'}")
    return {"seed": seeds[0] if not several else seeds, "fix_every": fix_every, "gnss": use_gnss, "unperturbed": base,
            "perturbations": rows, "passes": all(r["passes"] for r in rows)}
