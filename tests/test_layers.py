"""The layers are checked by a tool (import-linter), and the tool does catch an upward import."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    lint = Path(sys.executable).with_name("lint-imports")
    if not lint.exists():
        pytest.skip("import-linter is not installed (pip install 'firetrack[test]')")
    env = dict(os.environ, PYTHONPATH=str(cwd))
    return subprocess.run([str(lint), "--no-cache"], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_the_layer_and_no_cycle_contracts_hold():
    proc = _lint(ROOT)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


@pytest.mark.parametrize("module,upward", [
    ("service/protocol/wire.py", "import service.core.incident_core"),  # protocol reaching into the core
    ("pdr/pipeline.py", "import service.protocol.wire"),  # the algorithms reaching into the service
    ("service/core/tracker.py", "import client.wearable"),  # the service reaching into the client
])
def test_an_upward_import_breaks_the_contracts(tmp_path, module, upward):
    for pkg in ("pdr", "service", "client"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__", "static"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    target = tmp_path / module
    target.write_text(target.read_text() + f"\n{upward}  # deliberately upward\n")
    proc = _lint(tmp_path)
    assert proc.returncode != 0, proc.stdout[-3000:]
    assert "BROKEN" in proc.stdout
