"""The README's first phase keeps each ``xdist_group`` on one worker (tests/conftest.py::XdistGroups):
pytest-xdist's own grouping was lost under pytest 9.2, and the fault schedules ran side by side."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_tests_of_a_group_run_on_one_worker(tmp_path):
    (tmp_path / "conftest.py").write_text(
        "from tests.conftest import XdistGroups\n\n"
        "def pytest_configure(config):\n"
        "    config.pluginmanager.register(XdistGroups(), 'groups')\n")
    (tmp_path / "test_g.py").write_text(
        "import os, time, pytest\n\n"
        "def _note(kind):\n"
        "    with open('workers.txt', 'a') as f:\n"
        "        f.write(kind + ' ' + os.environ['PYTEST_XDIST_WORKER'] + '\\n')\n\n"
        "@pytest.mark.xdist_group('g')\n"
        "@pytest.mark.parametrize('i', range(6))\n"
        "def test_grouped(i):\n"
        "    time.sleep(0.2)\n"
        "    _note('grouped')\n\n"
        "@pytest.mark.parametrize('i', range(6))\n"
        "def test_free(i):\n"
        "    time.sleep(0.2)\n"
        "    _note('free')\n")
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadgroup",
                          "--rootdir", str(tmp_path), str(tmp_path)], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    seen: dict[str, set[str]] = {}
    for line in (tmp_path / "workers.txt").read_text().splitlines():
        kind, worker = line.split()
        seen.setdefault(kind, set()).add(worker)
    assert len(seen["grouped"]) == 1, seen  # (without XdistGroups: gw0 and gw1)
