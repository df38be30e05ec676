"""Products on the streaming paths are summed in a fixed order (issue 17).

A matrix product handed to BLAS sums in an order chosen by the CPU's kernel and by the
shape of the batch, so the same sample can give different bits alone and in a batch. The
service promises live = replay = reprocess bit for bit, so ``pdr/`` keeps such products off
its streaming paths. Two guards: the numbers (bit for bit across batch sizes, rerun under
several OpenBLAS kernels by ``tests/test_blas_kernels.py``), and a lint over the source,
which fails on any machine, AVX-512 or not.
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from pdr.fixed_order import mat_vec, row_dot
from pdr.step_length import MODELS, ResponderProfile, default_coefficients, step_lengths

ROOT = Path(__file__).resolve().parents[1]

# Offline code: loaders, scoring, the tuning grid, the pure-Python reference filter and the
# least-squares calibration (one fit over whole walks, never a live path).
OFFLINE = ("pdr/io/", "pdr/evaluation/", "pdr/ahrs/tuning.py", "pdr/ahrs/reference.py")
BLAS_CALLS = {"dot", "matmul", "inner", "vdot", "tensordot", "einsum", "solve", "lstsq", "inv", "eigh", "eig",
              "cholesky", "qr", "svd", "pinv", "det", "multi_dot", "cov"}
ALLOWED_MARK = "blas-ok:"  # a line may opt out with a reason, e.g. a product of a fixed shape


def _streaming_sources():
    for path in sorted((ROOT / "pdr").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if not rel.startswith(OFFLINE):
            yield rel, path.read_text()


def _offline_functions(tree) -> set[int]:
    """Line numbers inside functions documented as offline (``calibrate``)."""
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and node.name in {"calibrate"}:
            lines.update(range(node.lineno, (node.end_lineno or node.lineno) + 1))
    return lines


def blas_products(source: str) -> list[tuple[int, str]]:
    """``(line, what)`` for every matrix product or BLAS/LAPACK call in ``source``."""
    tree = ast.parse(source)
    skip = _offline_functions(tree)
    text = source.splitlines()
    found = []
    for node in ast.walk(tree):
        what = None
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            what = "@"
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
            if name in BLAS_CALLS:
                what = f"{name}()"
        if what and node.lineno not in skip and ALLOWED_MARK not in text[node.lineno - 1]:
            found.append((node.lineno, what))
    return found


def test_the_lint_sees_a_blas_product():
    assert blas_products("y = a @ b\n") == [(1, "@")]
    assert blas_products("y = np.dot(a, b)\nz = np.einsum('ij,j', a, b)\n") == [(1, "dot()"), (2, "einsum()")]
    assert blas_products("y = a @ b  # blas-ok: 2x2, one per step\n") == []


def test_no_blas_product_on_a_streaming_path():
    found = [f"{rel}:{line}: {what}" for rel, src in _streaming_sources() for line, what in blas_products(src)]
    assert not found, ("matrix products on streaming paths sum in a kernel- and shape-dependent order; "
                       "use pdr.fixed_order or mark a fixed-shape product '# blas-ok: why':\n" + "\n".join(found))


@pytest.mark.bitexact
@pytest.mark.parametrize("k", [1, 2, 3, 4, 8])
def test_row_dot_and_mat_vec_give_each_row_the_same_bits_in_any_batch(k):
    rng = np.random.default_rng(k)
    a = rng.normal(size=(257, k)) * 10.0 ** rng.integers(-3, 4, size=(257, k))
    x = rng.normal(size=k)
    whole = row_dot(a, x)
    for size in (1, 2, 3, 16, 100):
        parts = np.concatenate([row_dot(a[i:i + size], x) for i in range(0, len(a), size)])
        assert np.array_equal(parts, whole), size
    m = rng.normal(size=(257, 3, k))
    v = rng.normal(size=(257, k))
    whole = mat_vec(m, v)
    assert np.array_equal(np.concatenate([mat_vec(m[i:i + 1], v[i:i + 1]) for i in range(len(m))]), whole)
    np.testing.assert_allclose(whole, np.einsum("nij,nj->ni", m, v), rtol=1e-12, atol=1e-12)  # the same product


@pytest.mark.bitexact
@pytest.mark.parametrize("model", sorted(MODELS))
def test_a_step_has_the_same_length_alone_and_in_any_batch(model):
    rng = np.random.default_rng(17)
    n = 301
    x = {"a_max": rng.uniform(0.5, 9.0, n), "a_min": rng.uniform(-8.0, -0.5, n), "a_mean": rng.uniform(-1, 1, n),
         "a_mean_abs": rng.uniform(0.2, 4, n), "duration": rng.uniform(0.2, 1.2, n)}
    coeffs = {c: v * (1.0 + 1e-3 * (i + 1)) for i, (c, v) in enumerate(default_coefficients(model).items())}
    profile = ResponderProfile.with_model(model, coefficients=coeffs, height_m=1.83)
    whole = step_lengths(x, profile)
    for size in (1, 2, 5, 64):
        parts = np.concatenate([step_lengths({k: v[i:i + size] for k, v in x.items()}, profile)
                                for i in range(0, n, size)])
        assert np.array_equal(parts, whole), f"{model}: batches of {size}"
