"""The per-walk regression guard: each development walk's figures, kept and compared.

A pooled p75 hides a walk that breaks while the others improve a little (issue 27: a levelling
filter chosen on an orientation benchmark moved the development K = 0 p75 by +0.07 m and two
unseen walks by +24 m and +16 m). The baseline keeps, per walk and for K = 0 and K = 3, the
live, dead-reckoning and smoothed p75 and floor accuracy; :func:`compare` names every walk and
figure that got worse by more than :data:`TOLERANCE_M`, or lost floor accuracy.

Updating it: ``firetrack eval ipin ../shared/data/ipin2023/* --write-baseline
tests/baselines/ipin_walks.json`` recomputes every walk and writes the file with the commit and
a digest of the settings it was made with. Commit it in the same commit as the change that
moved the figures, and say why in the message; a default (a filter, a gain, a gate) changes
only with the per-walk table (before / after) in the commit message. ``tests/test_ipin_regression_guard.py``
and ``--check-baseline`` compare the code against it.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

from pdr.evaluation.ipin import summary
from pdr.recording import Recording
from service.review.ipin_run import IpinRun, PdrCache, run_ipin

FORMAT = "firetrack.ipin-walks/1"
BASELINE_KS = (0, 3)
KINDS = {"live": "live", "pdr": "dead reckoning", "smoothed": "smoothed"}
TOLERANCE_M = 0.5  # a walk's p75 may get this much worse before the guard fails
FLOOR_TOLERANCE = 1e-9  # floor accuracy may not drop at all


def walk_key(source: str) -> str:
    return Path(source).name


def walk_figures(runs: list[IpinRun]) -> dict[str, dict]:
    """Per walk (file name): per track kind, its p75 (m) and floor accuracy (None if no such track)."""
    out = {}
    for r in runs:
        fig = {}
        for kind in KINDS:
            e = r.errors(kind)
            s = summary([e]) if e is not None else None
            fig[kind] = None if s is None else {"p75_m": s["p75_m"], "floor_accuracy": s["floor_accuracy"]}
        out[walk_key(r.source)] = fig
    return out


def settings_digest(settings, use_gnss: bool, incident) -> str:
    """A short digest of everything a run depends on besides the code: tracker settings, GNSS, incident."""
    text = repr((settings, use_gnss, incident.model_dump() if hasattr(incident, "model_dump") else incident))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def compute(recordings: list[Recording], incident, settings, use_gnss: bool = True, ks=BASELINE_KS,
            progress: Callable = lambda items, what, total=None: items) -> dict[str, dict]:
    """``{walk: {"K0": {kind: {...}}, "K3": {...}}}``: every walk tracked at each K."""
    out: dict[str, dict] = {}
    cache = PdrCache()
    jobs = [(k, rec) for k in ks for rec in recordings]
    for k, rec in progress(jobs, "per-walk baseline", len(jobs)):
        run = run_ipin(rec, incident, k, use_gnss, settings, pdr_cache=cache)
        for walk, fig in walk_figures([run]).items():
            out.setdefault(walk, {})[f"K{k}"] = fig
    return out


def document(walks: dict[str, dict], made_with: dict) -> dict:
    return {"format": FORMAT, "made_with": made_with, "tolerance_m": TOLERANCE_M,
            "update": "firetrack eval ipin ../shared/data/ipin2023/* --write-baseline tests/baselines/ipin_walks.json; "
                      "commit it with the change and the per-walk table in the message",
            "walks": walks}


def write(path: Path, walks: dict[str, dict], made_with: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document(walks, made_with), indent=1, sort_keys=True) + "\n")


def read(path: Path) -> dict:
    doc = json.loads(Path(path).read_text())
    if doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not a per-walk baseline (format {doc.get('format')!r}, expected {FORMAT!r})")
    return doc


def compare(baseline: dict[str, dict], current: dict[str, dict], tolerance_m: float = TOLERANCE_M) -> list[str]:
    """Every regression, one line each: a p75 worse by more than ``tolerance_m``, a floor accuracy
    lower than before, a figure or walk that is missing now."""
    problems = []
    for walk in sorted(baseline):
        if walk not in current:
            problems.append(f"{walk}: not evaluated")
            continue
        for k in sorted(baseline[walk]):
            for kind, label in KINDS.items():
                was = baseline[walk][k].get(kind)
                now = current[walk].get(k, {}).get(kind)
                if was is None:
                    continue
                where = f"{walk} {k[0]} = {k[1:]} {label}"
                if now is None:
                    problems.append(f"{where}: no track now")
                    continue
                if now["p75_m"] > was["p75_m"] + tolerance_m:
                    problems.append(f"{where} p75 {was['p75_m']:.2f} -> {now['p75_m']:.2f} m "
                                    f"(+{now['p75_m'] - was['p75_m']:.2f} > {tolerance_m} m)")
                if now["floor_accuracy"] < was["floor_accuracy"] - FLOOR_TOLERANCE:
                    problems.append(f"{where} floors {was['floor_accuracy']:.1%} -> {now['floor_accuracy']:.1%}")
    return problems


def improvements(baseline: dict[str, dict], current: dict[str, dict], tolerance_m: float = TOLERANCE_M) -> list[str]:
    """Figures better by more than ``tolerance_m``: a reason to update the baseline and tighten the guard."""
    lines = []
    for walk in sorted(set(baseline) & set(current)):
        for k in sorted(baseline[walk]):
            for kind, label in KINDS.items():
                was, now = baseline[walk][k].get(kind), current[walk].get(k, {}).get(kind)
                if was and now and now["p75_m"] < was["p75_m"] - tolerance_m:
                    lines.append(f"{walk} {k[0]} = {k[1:]} {label} p75 {was['p75_m']:.2f} -> {now['p75_m']:.2f} m")
    return lines
