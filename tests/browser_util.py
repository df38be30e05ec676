"""Debian's Chromium through Playwright for the browser tests: skipped with the reason when
Playwright or the browser is missing."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

CHROMIUM = Path(os.environ.get("FIRETRACK_CHROMIUM", "/usr/bin/chromium"))


def launch_chromium(*args: str):
    """Yield a headless Chromium (``args`` beyond ``--no-sandbox``); stops it afterwards."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')")
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium (.ci/apt-packages.txt) to run the browser tests")
    pw = sync_api.sync_playwright().start()
    try:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox", *args])
    except Exception:
        pw.stop()
        raise
    yield b
    b.close()
    pw.stop()
