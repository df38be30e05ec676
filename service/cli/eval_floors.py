"""``firetrack eval floors``: floors in simulated buildings that the configuration gets wrong (pdr.evaluation.floors)."""
from __future__ import annotations

import itertools
import time

import typer
from rich.table import Table

from pdr.evaluation.floors import Building, run_scenario
from service.protocol.terminal import fail, out, print_json, progress

SCENARIOS = ("floor_by_floor", "between_known", "named_on_arrival")


def eval_floors(
    floors: list[int] = typer.Option([3, 4, 5], "--floors", help="storeys of the simulated buildings (repeat)"),
    spacing: list[float] = typer.Option([2.6, 3.2, 3.8, 4.5], "--spacing", help="real floor spacing, m (repeat)"),
    ratio: list[float] = typer.Option([0.6, 0.8, 1.0, 1.2, 1.4], "--ratio", help="real / configured spacing (repeat): 0.6 and 1.4 are a config 40 % off"),
    seeds: int = typer.Option(2, "--seeds", help="walks per building and scenario (different walkers and noise)"),
    fix_delay: list[float] = typer.Option([0.0, 3.0], "--fix-delay", help="named_on_arrival: s from pressing a "
                                          "checkpoint (3 s before the level) to the tracker hearing it (repeat)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
):
    """Floor accuracy at every dwell, and whether every trip up or down was counted right."""
    if min(floors) < 3 or seeds < 1 or min(spacing) <= 0 or min(ratio) <= 0:
        fail("need --floors >= 3 (the scenarios use floors 0-2), --seeds >= 1, positive --spacing and --ratio")
        raise typer.Exit(2)
    started = time.process_time()
    if min(fix_delay) < 0:
        fail("--fix-delay must not be negative")
        raise typer.Exit(2)
    variants = [(sc, 0.0) for sc in SCENARIOS if sc != "named_on_arrival"] + [("named_on_arrival", d) for d in fix_delay]
    cases = list(itertools.product(floors, spacing, ratio, variants, range(seeds)))
    rows = []
    for n, s, r, (scenario, delay), seed in progress(cases, "simulated walks"):
        sc = run_scenario(Building(n, s, r), scenario, seed=seed, fix_delay_s=delay)
        rows.append({"floors": n, "spacing_m": s, "ratio": r, "scenario": scenario, "fix_delay_s": delay, "seed": seed,
                     "dwell_samples": sc.dwell_samples, "dwell_accuracy": sc.accuracy, "trips_right": sc.trips_right,
                     "visits_true": list(sc.visits_true), "visits_seen": list(sc.visits_seen)})
    samples = sum(r["dwell_samples"] for r in rows)
    correct = sum(round(r["dwell_accuracy"] * r["dwell_samples"]) for r in rows)
    report = {
        "walks": len(rows),
        "dwell_accuracy": correct / samples if samples else None,
        "walks_all_trips_right": sum(r["trips_right"] for r in rows),
        "walks_wrong": [r for r in rows if r["dwell_accuracy"] < 1.0 or not r["trips_right"]],
        "cpu_s": time.process_time() - started,
    }
    if as_json:
        print_json({**report, "cases": rows})
        return
    table = Table(title="floors in simulated buildings: dwell accuracy per real/configured spacing ratio")
    table.add_column("floors × spacing")
    for r in ratio:
        table.add_column(f"ratio {r:g}", justify="right")
    for n, s in itertools.product(floors, spacing):
        cells = []
        for r in ratio:
            sel = [x for x in rows if x["floors"] == n and x["spacing_m"] == s and x["ratio"] == r]
            acc = sum(x["dwell_accuracy"] * x["dwell_samples"] for x in sel) / max(sum(x["dwell_samples"] for x in sel), 1)
            cells.append(f"{acc:.1%}" + ("" if all(x["trips_right"] for x in sel) else " [red]trips![/]"))
        table.add_row(f"{n} × {s:g} m", *cells)
    table.caption = (f"{report['walks']} walks, dwell accuracy {report['dwell_accuracy']:.2%}, all trips right in "
                     f"{report['walks_all_trips_right']}; {report['cpu_s']:.0f} s CPU")
    out.print(table)
