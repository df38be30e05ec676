"""The per-walk regression guard (issue 27): no development walk may get worse.

Every IPIN 2023 development walk is tracked at K = 0 and K = 3 with the shipped defaults, and
each walk's live, dead-reckoning and smoothed p75 and floor accuracy are compared with
``tests/baselines/ipin_walks.json``. The test fails, naming each walk and figure, when a p75 is
worse by more than 0.5 m or a floor accuracy is lower (:func:`service.review.ipin_baseline.compare`).
A pooled figure cannot do this: one walk 20 m worse hides in the pooled p75 of forty.

When a change is meant to move the figures, update the baseline in the same commit::

    firetrack eval ipin ../shared/data/ipin2023/* --write-baseline tests/baselines/ipin_walks.json

(``--check-baseline`` instead of ``--write-baseline`` prints the same comparison as this test)
and say in the commit message why each walk that got worse did. A default (a filter, a gain,
a gate) changes only with the per-walk table (before / after) in the commit message.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from pdr.io import load
from service.core.tracker import tracker_settings_for
from service.protocol.incident import default_incident
from service.review import ipin_baseline as B

BASELINE = Path(__file__).resolve().parent / "baselines" / "ipin_walks.json"


@pytest.mark.recording
def test_no_development_walk_got_worse_than_its_baseline(shared_data):
    folder = shared_data("ipin2023")
    doc = B.read(BASELINE)
    files = [folder / walk for walk in sorted(doc["walks"])]
    missing = [f.name for f in files if not f.exists()]
    if missing:
        pytest.skip(f"walks of the baseline not in {folder}: {', '.join(missing)}")
    cfg = default_incident()
    settings = tracker_settings_for(cfg)
    now = B.compute([load(f) for f in files], cfg, settings, doc["made_with"].get("gnss", True))
    problems = B.compare(doc["walks"], now, doc["tolerance_m"])
    made = doc["made_with"]
    assert not problems, (
        f"{len(problems)} figure(s) worse than {BASELINE.name} (made at {made.get('commit', '?')[:10]}, settings "
        f"{made.get('settings_digest')}, now {B.settings_digest(settings, made.get('gnss', True), cfg)}):\n  "
        + "\n  ".join(problems)
        + "\nIf this change is meant, rewrite the baseline (see this module's docstring) and give the per-walk table "
          "in the commit message.")
