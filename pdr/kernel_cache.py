"""Where numba keeps the compiled kernels: a folder named by a fingerprint of their sources.

numba's on-disk cache (``@njit(cache=True)``) checks only the time stamp and size of the
file that *defines* a kernel. A kernel that calls a kernel of another module (the fleet's
columnar stages call the AHRS, heading, height and floor kernels) keeps the old callee's
machine code after that other module changes: a stale result after an upgrade, silently.
So the cache lives in ``<base>/<fingerprint>``, where the fingerprint is a hash of every
``pdr`` source file that uses numba. Any change to any kernel moves every kernel to a fresh
folder and recompiles it once.

``<base>`` is ``$NUMBA_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/firetrack/numba`` (default
``~/.cache/firetrack/numba``). When that folder cannot be made, numba's own default is left
in place. Nothing happens when numba is not installed (the wearable's light install).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def kernel_sources() -> list[Path]:
    """The ``pdr`` source files that use numba, in a stable order."""
    return sorted(p for p in _PACKAGE.rglob("*.py") if "numba" in p.read_text(encoding="utf-8", errors="replace"))


def fingerprint(files: list[Path] | None = None) -> str:
    """SHA-1 (first 16 hex digits) over each kernel file's path in the package and its bytes."""
    h = hashlib.sha1()
    for p in kernel_sources() if files is None else files:
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
    if "numba" in sys.modules:  # numba read its environment already: set its config directly
        from numba.core import config

        config.CACHE_DIR = str(path)
    else:
        os.environ["NUMBA_CACHE_DIR"] = str(path)
    return path
