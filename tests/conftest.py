"""Shared pytest fixtures.

Real recordings live outside the repository, in ``../shared/data`` next to the project root
(see that folder's README; ``FIRETRACK_SHARED_DATA`` names another folder, e.g. from a git
worktree); tests that need one ask the ``shared_data`` fixture, which skips
the test with the missing path when the recording is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# No per-example deadline: speed is measured by the benchmarks, not by tests, and CI machines
# (and a busy laptop) are slower than the one a deadline would be tuned on.
settings.register_profile("firetrack", deadline=None)
settings.load_profile("firetrack")

SHARED_DATA = Path(os.environ.get("FIRETRACK_SHARED_DATA") or Path(__file__).resolve().parents[1].parent / "shared" / "data")


def shared_data_path(relpath: str | Path) -> Path:
    """Path of a recording under ../shared/data, or skip the calling test when it is absent."""
    path = SHARED_DATA / relpath
    if not path.exists():
        pytest.skip(f"recording {path} not present")
    return path


@pytest.fixture
def shared_data():
    """``shared_data("ipin2023/...")`` -> Path, skipping the test when the recording is absent."""
    return shared_data_path
