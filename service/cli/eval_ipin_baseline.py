"""``eval ipin --write-baseline PATH`` and ``--check-baseline PATH``: the per-walk regression guard.

See :mod:`service.review.ipin_baseline` for what is kept and how to update it.
"""
from __future__ import annotations

import datetime
import subprocess
from pathlib import Path

from rich.table import Table

from service.cli.eval_ipin_robust import short_walk
from service.protocol.terminal import err, fail, out, progress
from service.review import ipin_baseline as B


def code_version() -> dict:
    """The commit of the code that runs (and whether its tree has uncommitted changes)."""
    root = Path(__file__).resolve().parents[2]

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": git("rev-parse", "HEAD") or "unknown", "uncommitted_changes": bool(status)}


def baseline_command(recordings, cfg, settings, use_gnss: bool, write: Path | None, check: Path | None,
                     incident_path: Path | None) -> int:
    if settings.engine != "fusion":
        fail("the per-walk baseline is made with --engine fusion (it keeps live, dead reckoning and smoothed)")
        return 2
    if check is not None:
        try:
            doc = B.read(check)
        except (OSError, ValueError) as e:
            fail(str(e))
            return 2
        wanted = set(doc["walks"])
        recordings = [r for r in recordings if B.walk_key(r.source) in wanted]
    walks = B.compute(recordings, cfg, settings, use_gnss, progress=progress)
    out.print(table(walks))
    digest = B.settings_digest(settings, use_gnss, cfg)
    if write is not None:
        made_with = {**code_version(), "settings_digest": digest, "gnss": use_gnss, "engine": settings.engine,
                     "incident": str(incident_path or "default (IPIN museum)"),
                     "made": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
        B.write(write, walks, made_with)
        err.print(f"wrote {write}: {len(walks)} walks, K = {', '.join(map(str, B.BASELINE_KS))}, commit "
                  f"{made_with['commit'][:10]}{' (with uncommitted changes)' if made_with['uncommitted_changes'] else ''}")
        return 0
    problems = B.compare(doc["walks"], walks, doc.get("tolerance_m", B.TOLERANCE_M))
    for line in B.improvements(doc["walks"], walks):
        err.print(f"better: {line}", highlight=False)
    made = doc.get("made_with", {})
    if made.get("settings_digest") not in (None, digest):
        err.print(f"note: the baseline was made with other settings ({made.get('settings_digest')}, now {digest})")
    for line in problems:
        fail(line)
    err.print(f"{len(problems)} regression(s) against {check} (made at {str(made.get('commit', '?'))[:10]})")
    return 1 if problems else 0


def table(walks: dict[str, dict]) -> Table:
    t = Table(title="per walk: p75 (m) live / dead reckoning / smoothed, floors (live)")
    t.add_column("walk")
    for k in B.BASELINE_KS:
        t.add_column(f"K = {k}", justify="right")
        t.add_column("floors", justify="right")
    for walk in sorted(walks):
        row = [short_walk(walk.split(".")[0])]
        for k in B.BASELINE_KS:
            fig = walks[walk].get(f"K{k}", {})
            row.append(" / ".join("—" if fig.get(kind) is None else f"{fig[kind]['p75_m']:.2f}" for kind in B.KINDS))
            row.append("—" if fig.get("live") is None else f"{fig['live']['floor_accuracy']:.0%}")
        t.add_row(*row)
    return t
