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


def test_the_test_command_runs_every_test_once_and_the_serial_ones_alone():
    """Phase one on parallel workers without the ``serial`` tests, phase two those alone: between
    them every test, none twice."""
    runs = re.findall(r"pytest ([^&]*)", _commands()[1])
    marks = [re.search(r'-m ("[^"]+"|\S+)', r) for r in runs]
    assert [m.group(1).strip('"') if m else None for m in marks] == ["not serial", "serial"], runs
    assert re.search(r"-n \d", runs[0]) and "--dist loadgroup" in runs[0] and "-n" not in runs[1].split(), runs


def test_every_serial_and_realtime_entry_names_a_test_that_exists():
    """A renamed test would otherwise leave ``SERIAL``, ``REALTIME`` or ``SHARED_SETUP`` silently and run beside the others."""
    from tests.conftest import REALTIME, SERIAL, SHARED_SETUP

    assert not set(SERIAL) & set(REALTIME) and not (set(SERIAL) | set(REALTIME)) & set(SHARED_SETUP)
    for key in [*SERIAL, *REALTIME, *SHARED_SETUP]:
        path, _, name = key.partition("::")
        assert (ROOT / path).is_file(), key
        assert not name or re.search(rf"^def {re.escape(name)}\(", (ROOT / path).read_text(), flags=re.M), key


def test_ci_checks_the_layers():
    assert "lint-imports" in (ROOT / ".ci" / "run").read_text()


def _links(md: Path) -> list[str]:
    """The relative targets of a Markdown file's links and images, without their #anchors."""
    targets = re.findall(r"\]\(([^)\s]+)\)", md.read_text())
    return [t.split("#", 1)[0] for t in targets if not re.match(r"[a-z]+:", t) and not t.startswith("#")]


def test_every_link_of_the_readme_and_docs_leads_to_a_file():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = [f"{md.relative_to(ROOT)} -> {t}" for md in pages for t in _links(md) if not (md.parent / t).exists()]
    assert not broken, broken


def test_docs_index_names_every_page_and_picture_of_docs():
    """docs/README.md is the index: a page or a screenshot nobody links is either linked there or removed."""
    index = {(ROOT / "docs" / t).resolve() for t in _links(ROOT / "docs" / "README.md")}
    files = [p for p in (ROOT / "docs").rglob("*") if p.is_file() and p.suffix in (".md", ".png") and p.name != "README.md"]
    assert files and not [str(p.relative_to(ROOT)) for p in files if p.resolve() not in index]
    assert (ROOT / "docs" / "README.md").resolve() in {(ROOT / t).resolve() for t in _links(ROOT / "README.md")}
