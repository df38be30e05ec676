"""The README's first lines give the two commands a new user and CI run; keep them true."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _commands():
    return re.findall(r"^    (python3 -m venv .*)$", (ROOT / "README.md").read_text(), flags=re.M)


def test_readme_opens_with_the_two_commands():
    cmds = _commands()
    assert len(cmds) >= 2
    main, tests = cmds[0], cmds[1]
    assert "pip install -e '.[all]'" in main and ".venv/bin/firetrack" in main  # the demo needs every extra
    assert "pytest" in tests and "[test]" in tests
    head = (ROOT / "README.md").read_text().splitlines()[:12]
    assert any(main in line for line in head) and any(tests in line for line in head)


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    assert "README.md" in ci and "pytest" in ci
    assert re.search(r"rc\" -eq 5", ci), "pytest's exit code 5 (no tests) must fail CI"


def test_ci_checks_the_layers():
    assert "lint-imports" in (ROOT / ".ci" / "run").read_text()
