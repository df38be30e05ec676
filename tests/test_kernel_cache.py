"""numba's kernel cache is keyed by every kernel's source, not only the defining file's."""
from __future__ import annotations

import os
import subprocess
import sys

from pdr import kernel_cache


def test_the_fingerprint_changes_with_any_kernel_source(tmp_path):
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("import numba\n# caller\n")
    b.write_text("import numba\n# callee v1\n")
    files = [a, b]
    orig = kernel_cache._PACKAGE
    kernel_cache._PACKAGE = tmp_path
    try:
        before = kernel_cache.fingerprint(files)
        b.write_text("import numba\n# callee v2\n")  # only the callee changes
        after = kernel_cache.fingerprint(files)
    finally:
        kernel_cache._PACKAGE = orig
    assert before != after


def test_the_fleet_and_the_kernels_it_calls_are_in_the_fingerprint():
    names = {p.name for p in kernel_cache.kernel_sources()}
    assert {"fleet_kernels.py", "_decoupled_kernel.py", "heading_kernels.py", "height.py", "floor_kernels.py",
            "detector_kernels.py", "window_kernels.py", "fleet_buffers.py"} <= names


def test_a_child_process_uses_the_same_folder_and_numba_caches_there(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    code = ("import os, pdr, subprocess, sys\n"
            "from numba.core import config\n"
            "print(config.CACHE_DIR)\n"
            "sys.stdout.flush()\n"
            "subprocess.run([sys.executable, '-c', 'import pdr; from numba.core import config; print(config.CACHE_DIR)'])\n"
            "import numpy as np\n"
            "from pdr.detector_kernels import np_sum\n"
            "np_sum(np.ones(3))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    parent, child = out.stdout.split()
    want = tmp_path / "firetrack" / "numba" / kernel_cache.fingerprint()
    assert parent == child == str(want)
    assert any(p.suffix == ".nbi" for p in want.rglob("*"))  # numba cached the kernel it compiled there


def test_another_checkout_of_the_same_sources_loads_the_kernels_compiled_by_the_first(tmp_path):
    """A fresh clone (CI, a worktree) finds what a checkout elsewhere compiled: numba's cache
    hit counts, from a copy of ``pdr`` at two paths (pdr.kernel_locator)."""
    import shutil

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "NUMBA_CACHE_LOCATOR_CLASSES")}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    code = ("import numpy as np\n"
            "from pdr.detector_kernels import np_sum\n"
            "np_sum(np.ones(3))\n"
            "print(sum(np_sum.stats.cache_hits.values()), sum(np_sum.stats.cache_misses.values()))\n")
    counts = []
    for checkout in ("a", "b"):
        shutil.copytree(kernel_cache._PACKAGE, tmp_path / checkout / "pdr", ignore=shutil.ignore_patterns("__pycache__"))
        out = subprocess.run([sys.executable, "-c", code], env=dict(env, PYTHONPATH=str(tmp_path / checkout)),
                             cwd=tmp_path / checkout, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        counts.append(tuple(map(int, out.stdout.split())))
    assert counts == [(0, 1), (1, 0)]  # (hits, misses): compiled in a, loaded in b
    assert list((tmp_path / "cache" / "firetrack" / "numba").glob("*/pdr/detector_kernels.np_sum-*.nbi"))
