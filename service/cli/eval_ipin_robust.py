"""``firetrack eval ipin FILES --perturb NAME[,NAME...]|all``: the robustness suite's table.

Every walk runs as logged and under each perturbation (:mod:`pdr.evaluation.robustness` lists
them, with the physical situation each models); the table puts each beside the unperturbed run:
pooled live p75, its change, dead reckoning, the worst walk and whether the perturbation passes
issue 27's criteria (pooled p75 at most 25 % worse, no walk above 2 x its unperturbed p75 + 2 m).
"""
from __future__ import annotations

from rich.table import Table

from pdr.evaluation.robustness import BROKEN_FACTOR, BROKEN_MARGIN_M, POOLED_TOLERANCE
from service.protocol.terminal import err, out, print_json, progress
from service.review.ipin_robustness import run_suite


def robustness(recordings, cfg, names: list[str], fix_every: int, use_gnss: bool, settings, seed: int,
               as_json: bool) -> dict:
    """Run the suite, print its table (or JSON) and return the report."""
    report = run_suite(recordings, cfg, names, fix_every, use_gnss, settings, seed, progress=progress,
                       log=lambda line: err.print(line, highlight=False))
    if as_json:
        print_json(report)
    else:
        out.print(table(report))
    return report


def short_walk(name: str) -> str:
    """``IPIN2023_T3_TrainingTrial25_repetition03`` -> ``T25r03``."""
    return name.replace("IPIN2023_T3_Training", "").replace("Trial", "T").replace("_repetition", "r")


def _worst(name: str, p75: float) -> str:
    return f"{short_walk(name)} {p75:.1f}"


def table(report: dict) -> Table:
    base = report["unperturbed"]
    t = Table(title=f"robustness suite at K = {report['fix_every']}, {len(base['walks'])} walks, "
                    + (f"seeds {', '.join(map(str, report['seed']))}" if isinstance(report["seed"], list)
                       else f"seed {report['seed']}"))
    for col, just in (("perturbation", "left"), ("p75", "right"), ("change", "right"), ("DR p75", "right"),
                      ("floors", "right"), ("worst walk", "left"), ("was", "right"), ("broken", "left"),
                      ("verdict", "left")):
        t.add_column(col, justify=just)
    t.add_row("none", f"{base['p75_m']:.2f}", "", f"{base['pdr_p75_m']:.2f}", f"{base['floor_accuracy']:.0%}",
              _worst(base["worst_walk"], base["worst_p75_m"]), "", "", "", end_section=True)
    for r in report["perturbations"]:
        broken = ", ".join(short_walk(b["walk"]) for b in r["broken"][:3]) + (" ..." if len(r["broken"]) > 3 else "")
        broken = f"{len(r['broken'])}" + (f": {broken}" if broken else "")
        if r.get("errors"):
            broken += f"; {len(r['errors'])} failed to run"
        if r.get("p75_m") is None:
            t.add_row(r["name"], "—", "", "—", "—", "—", "", broken, "[red]FAIL[/]")
            continue
        t.add_row(r["name"], f"{r['p75_m']:.2f}", f"{r['pooled_change']:+.0%}", f"{r['pdr_p75_m']:.2f}",
                  f"{r['floor_accuracy']:.0%}", _worst(r["worst_walk"], r["worst_p75_m"]),
                  f"{r['worst_unperturbed_p75_m']:.1f}", broken, "[green]pass[/]" if r["passes"] else "[red]FAIL[/]")
    t.caption = (f"pooled live p75 (m) and its change; worst walk: its p75 (m), 'was' the same walk as logged; "
                 f"pass: pooled p75 at most {POOLED_TOLERANCE:.0%} worse than as logged and no walk broken "
                 f"(p75 > {BROKEN_FACTOR:g} x its own as logged + {BROKEN_MARGIN_M:g} m)")
    return t
