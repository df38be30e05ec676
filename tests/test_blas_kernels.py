"""The bit-exact tests, rerun under every OpenBLAS kernel this CPU can execute (issue 17).

OpenBLAS picks its kernel from the CPU at start-up; ``OPENBLAS_CORETYPE`` overrides that
choice. A result that depends on the kernel (a BLAS product on a streaming path) passed on
the developer's machine and failed on an AVX-512 one. Here the tests marked ``bitexact``
run in a fresh interpreter under each kernel the CPU supports, with 1 and 2 BLAS threads,
so CI on any machine exercises the kernels that machine can run. The static guard that
fails everywhere is ``tests/test_fixed_order.py``.

Every kernel of the matrix runs every bit-exact test except the long ones in :data:`SHARED`,
which are dealt out over the kernels instead (each runs under one of them, and all of them run
under the machine's own kernel in the suite itself). What the matrix looks for, a BLAS product
whose bits depend on the kernel or on the shape of the batch, lives in the arithmetic those
long tests share with the short ones each kernel runs: the fleet against a fleet of one in
rounds of random size (``test_a_floor_anchored_mid_walk_is_anchored_the_same_in_the_fleet``),
the core in rounds of any size (``test_rounds_of_any_size_give_the_same_poses_bit_for_bit``),
live frames against one batch (``test_pipeline.py``) and each stage alone in any batching.
This took the matrix from 4 full runs (58 tests each, about 218 s on CI) to one full run's worth.
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


# The long bit-exact tests (seconds of CPU each, measured under Prescott with 1 thread on the
# 2-core machine under load), dealt out over the matrix in this order: each runs under one kernel.
SHARED = [
    "tests/test_fleet.py::test_simulated_walkers_alone_and_in_a_fleet_give_the_same_events",  # 37.6 s
    "tests/test_fleet.py::test_real_walks_alone_and_in_a_fleet_give_the_same_events",  # 14.3 s
    "tests/test_review.py::test_handheld_and_boot_mounted_wearers_live_then_reprocessed_give_identical_poses",  # 11.8
    "tests/test_fleet.py::test_the_service_gives_a_responder_the_same_poses_alone_or_beside_others",  # 9.9 s
    "tests/test_review.py::test_four_person_exercise_recorded_live_then_reprocessed_gives_identical_poses",  # 5.2 s
    "tests/test_fleet.py::test_a_released_slot_serves_a_new_member_as_a_fresh_pipeline",  # 4.9 s
    "tests/test_fleet.py::test_a_crowd_that_leaves_gives_its_rows_back_and_the_fleet_goes_on",  # 4.3 s
    "tests/test_fleet.py::test_a_pickled_fleet_goes_on_like_the_original",  # 3.9 s
    "tests/test_service.py::test_replay_through_zenoh_equals_the_offline_pipeline",  # 3.1 s with its router
    "tests/test_ipin_eval.py::test_replayed_dead_reckoning_gives_the_same_tracks_bit_for_bit[2]",  # 1.6 s
    "tests/test_ipin_eval.py::test_replayed_dead_reckoning_gives_the_same_tracks_bit_for_bit[0]",  # 1.5 s
]


def bitexact_files() -> list[Path]:
    """The test files that hold bit-exact tests (the inner run collects only these)."""
    return sorted(p for p in (ROOT / "tests").glob("test_*.py")
                  if p.name != Path(__file__).name and "mark.bitexact" in p.read_text())


def inner_command(index: int, entries: int) -> list[str]:
    """pytest over the bit-exact tests for matrix entry ``index`` of ``entries``: all of them
    but the :data:`SHARED` ones dealt to the other entries."""
    skip = [nodeid for i, nodeid in enumerate(SHARED) if i % entries != index]
    return ([sys.executable, "-m", "pytest", "-q", "-m", "bitexact", "-p", "no:cacheprovider", "-x"]
            + [a for nodeid in skip for a in ("--deselect", nodeid)] + [str(p.relative_to(ROOT)) for p in bitexact_files()])


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


MATRIX = _matrix()


@pytest.mark.skipif(os.environ.get("FIRETRACK_BLAS_MATRIX") == "inner", reason="already inside the kernel matrix")
@pytest.mark.parametrize("index,core,threads", [(i, c, t) for i, (c, t) in enumerate(MATRIX)], ids=lambda v: str(v))
def test_bit_exact_results_hold_under_this_blas_kernel(index, core, threads):
    env = dict(os.environ, OPENBLAS_CORETYPE=core, OPENBLAS_NUM_THREADS=str(threads), FIRETRACK_BLAS_MATRIX="inner")
    proc = subprocess.run(inner_command(index, len(MATRIX)), cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)
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
    assert len({k for k, _ in MATRIX}) >= 2, MATRIX


def test_every_shared_test_is_a_bit_exact_test_that_exists():
    """A renamed long test would otherwise silently run under no kernel of the matrix."""
    files = {p.name: p.read_text() for p in bitexact_files()}
    for nodeid in SHARED:
        path, name = nodeid.split("::")
        text = files.get(Path(path).name, "")
        at = text.find(f"def {name.split('[')[0]}(")
        assert at >= 0 and "mark.bitexact" in text[max(0, text.rfind("\n\n\n", 0, at)):at], nodeid
    assert len(set(SHARED)) == len(SHARED)
