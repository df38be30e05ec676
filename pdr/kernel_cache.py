"""Where numba keeps the compiled kernels: a folder named by a fingerprint of their sources.

numba's on-disk cache (``@njit(cache=True)``) checks only the time stamp and size of the
file that *defines* a kernel. A kernel that calls a kernel of another module (the fleet's
columnar stages call the AHRS, heading, height and floor kernels) keeps the old callee's
machine code after that other module changes: a stale result after an upgrade, silently.
So the cache lives in ``<base>/<fingerprint>``, where the fingerprint is a hash of every
``pdr`` source file that uses numba and of every ``pdr`` module those import, transitively (a
kernel freezes the globals it reads, e.g. ``pdr.constants.GRAVITY``, into its machine code).
Any change to any of them moves every kernel to a fresh folder and recompiles it once.

Inside that folder numba would name each file's subfolder by the file's absolute path, so a
fresh clone or another worktree of the same sources compiled everything again (about 35 s of
CPU for the path ``eval ipin`` takes, in every process that met a kernel first: each pytest
worker, each ``serve`` a test starts). :class:`pdr.kernel_locator.PackageCacheLocator` names it
by the file's place in ``pdr`` instead: the fingerprint already says the sources are the same,
and numba's own stamp (a hash of the defining file's bytes in numba 0.68) still guards each
file. It is installed through ``NUMBA_CACHE_LOCATOR_CLASSES`` unless that is set already; a
numba that does not read that variable keeps its own locator (correct, only slower).

``<base>`` is ``$NUMBA_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/firetrack/numba`` (default
``~/.cache/firetrack/numba``). When that folder cannot be made, numba's own default is left
in place. Nothing happens when numba is not installed (the wearable's light install).
"""
from __future__ import annotations

import ast
import hashlib
import importlib.util
import os
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


# numba's locators after ours, for the functions of other packages (names numba resolves itself)
_NUMBA_LOCATORS = "UserProvidedCacheLocator,InTreeCacheLocator,UserWideCacheLocator,IPythonCacheLocator,ZipCacheLocator"
LOCATORS = f"pdr.kernel_locator.PackageCacheLocator,{_NUMBA_LOCATORS}"


def kernel_sources() -> list[Path]:
    """The ``pdr`` source files that use numba, in a stable order."""
    return sorted(p for p in _PACKAGE.rglob("*.py") if "numba" in p.read_text(encoding="utf-8", errors="replace"))


def _module_file(name: str) -> Path | None:
    path = _PACKAGE.parent.joinpath(*name.split("."))
    return next((p for p in (path.with_suffix(".py"), path / "__init__.py") if p.is_file()), None)


def _pdr_imports(path: Path) -> set[Path]:
    """The ``pdr`` modules ``path`` imports (absolute imports: the package uses no relative ones)."""
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_bytes())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
    found = (_module_file(n) for n in names if n == _PACKAGE.name or n.startswith(_PACKAGE.name + "."))
    return {p for p in found if p is not None}


def fingerprinted_sources() -> list[Path]:
    """The kernel files and every ``pdr`` module they import, transitively, in a stable order."""
    seen: set[Path] = set()
    todo = kernel_sources()
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo += _pdr_imports(p)
    return sorted(seen)


def fingerprint(files: list[Path] | None = None) -> str:
    """SHA-1 (first 16 hex digits) over each fingerprinted file's path in the package and its bytes."""
    h = hashlib.sha1()
    for p in fingerprinted_sources() if files is None else files:
        h.update(p.relative_to(_PACKAGE).as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def cache_dir(env: dict | None = None) -> Path:
    env = os.environ if env is None else env
    base = env.get("NUMBA_CACHE_DIR") or os.path.join(
        env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "firetrack", "numba")
    fp = fingerprint()
    # a child process inherits the folder this module chose for its parent: keep it, do not nest
    return Path(base) if Path(base).name == fp else Path(base) / fp


def configure() -> Path | None:
    """Point numba's cache at :func:`cache_dir` (before any kernel is compiled); the folder, or None."""
    if importlib.util.find_spec("numba") is None:
        return None
    path = cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    own_locator = "NUMBA_CACHE_LOCATOR_CLASSES" not in os.environ
    if "numba" in sys.modules:  # numba read its environment already: set its config directly
        from numba.core import config

        config.CACHE_DIR = str(path)
        if own_locator and hasattr(config, "CACHE_LOCATOR_CLASSES"):
            config.CACHE_LOCATOR_CLASSES = LOCATORS
    else:
        os.environ["NUMBA_CACHE_DIR"] = str(path)
        if own_locator:
            os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = LOCATORS
    return path
