"""The bit-exact tests, rerun under every OpenBLAS kernel this CPU can execute (issue 17).

OpenBLAS picks its kernel from the CPU at start-up; ``OPENBLAS_CORETYPE`` overrides that
choice. A result that depends on the kernel (a BLAS product on a streaming path) passed on
the developer's machine and failed on an AVX-512 one. Here every test marked ``bitexact``
runs in a fresh interpreter under each kernel the CPU supports, with 1 and 2 BLAS threads,
so CI on any machine exercises the kernels that machine can run. The static guard that
fails everywhere is ``tests/test_fixed_order.py``.
"""
from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    m = re.search(r"^(?:flags|Features)\s*:\s*(.*)$", text, re.M)
    return set(m.group(1).split()) if m else set()


def runnable_coretypes() -> list[str]:
    """OpenBLAS kernels whose instructions this CPU has (a kernel it lacks would crash)."""
    flags, arch = _cpu_flags(), platform.machine().lower()
    if arch in ("x86_64", "amd64"):
        out = ["Prescott"]  # SSE3: every x86-64
        if {"avx2", "fma"} <= flags:
            out += ["Haswell", "Zen"]
        if {"avx512f", "avx512dq", "avx512bw", "avx512vl", "avx512cd"} <= flags:
            out += ["SkylakeX"]
            if "avx512_bf16" in flags:
                out += ["Cooperlake"]
        return out
    if arch in ("aarch64", "arm64"):
        out = ["ARMV8"]
        if "asimd" in flags:
            out += ["NEOVERSEN1"]
        if "sve" in flags:
            out += ["NEOVERSEV1"]
        return out
    return []


def kernel_taken(core: str) -> str | None:
    """The kernel OpenBLAS reports when asked for ``core`` (``OPENBLAS_VERBOSE=2``), or None."""
    env = dict(os.environ, OPENBLAS_CORETYPE=core, OPENBLAS_VERBOSE="2")
    proc = subprocess.run([sys.executable, "-c", "import numpy; numpy.ones((2, 2)) @ numpy.ones((2, 2))"],
                          env=env, capture_output=True, text=True, timeout=60)
    text = proc.stdout + proc.stderr
    if proc.returncode != 0 or "not found" in text:
        return None
    m = re.search(r"^Core: (\w+)", text, re.M)
    return m.group(1) if m else None


def _matrix() -> list[tuple[str, int]]:
    # every distinct kernel once, alternating 1 and 2 threads; the widest kernel with both
    if os.environ.get("FIRETRACK_BLAS_MATRIX") == "inner":
        return []
    taken: dict[str, str] = {}
    for core in runnable_coretypes():
        k = kernel_taken(core)
        if k is not None and k not in taken.values():
            taken[core] = k
    out = [(core, 1 + i % 2) for i, core in enumerate(taken)]
    if out:
        core = out[-1][0]
        out.append((core, 3 - out[-1][1]))
    return out


@pytest.mark.skipif(os.environ.get("FIRETRACK_BLAS_MATRIX") == "inner", reason="already inside the kernel matrix")
@pytest.mark.parametrize("core,threads", _matrix(), ids=lambda v: str(v))
def test_bit_exact_results_hold_under_this_blas_kernel(core, threads):
    env = dict(os.environ, OPENBLAS_CORETYPE=core, OPENBLAS_NUM_THREADS=str(threads), FIRETRACK_BLAS_MATRIX="inner")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "bitexact", "-p", "no:cacheprovider",
                           "-x", str(ROOT / "tests")], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    summary = (proc.stdout.strip().splitlines() or ["(no output)"])[-1]
    assert proc.returncode == 0, f"OPENBLAS_CORETYPE={core} threads={threads}: {summary}\n" \
                                 + proc.stdout[-4000:] + proc.stderr[-2000:]
    assert re.search(r"\d+ passed", summary), summary


def test_the_kernel_matrix_is_not_empty_on_a_known_cpu():
    """On x86-64 and ARM the matrix must hold at least two kernels, or CI checks nothing."""
    if platform.machine().lower() not in ("x86_64", "amd64", "aarch64", "arm64"):
        pytest.skip(f"no kernel list for {platform.machine()}")
    if os.environ.get("FIRETRACK_BLAS_MATRIX") == "inner":
        pytest.skip("inside the matrix")
    assert len({k for k, _ in _matrix()}) >= 2, _matrix()
