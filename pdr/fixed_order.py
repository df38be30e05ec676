"""Small products summed in a fixed order, so that results never depend on batching or CPU.

A numpy matrix product (``@``, ``np.dot``, ``einsum(..., optimize=True)``) hands the work
to BLAS. OpenBLAS picks its kernel from the CPU (Haswell, SkylakeX with AVX-512, Zen, ...)
*and* from the operand shapes: one row and a hundred rows go through different code, which
sum the same terms in different orders or with fused multiply-adds. Then a step's length,
or a rotated vector, differs in the last bit depending on how many samples arrived with it,
and the service's promise "live = replay = reprocess, bit for bit" breaks on some machines
(issue 17: ``0.6944444444444436`` against ``...438`` under ``OPENBLAS_CORETYPE=SkylakeX``).

The products on the algorithms' hot paths are tiny (2-8 terms), so they are written here as
elementwise numpy with an explicit left-to-right sum: each output element is
``((a0*b0 + a1*b1) + a2*b2) + ...``, rounded after every operation, whatever the shape of
the batch. numpy's elementwise ufuncs never fuse a multiply and an add, so this order is the
order the hardware computes on every CPU.

``tests/test_fixed_order.py`` checks these against batches of every size and lints ``pdr/``
for matrix products on the streaming paths.
"""
from __future__ import annotations

import numpy as np


def row_dot(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``a @ x`` over the last axis of ``a`` (shape ``(..., k)``) with ``x`` of shape (k,).

    :math:`y = \\sum_{j=0}^{k-1} a_{\\cdot j} x_j`, accumulated for j = 0, 1, ... in turn.
    """
    a = np.asarray(a, dtype=float)
    x = np.asarray(x, dtype=float).reshape(-1)
    if a.shape[-1] != x.shape[0]:
        raise ValueError(f"row_dot: last axis {a.shape[-1]} does not match {x.shape[0]} coefficients")
    if x.shape[0] == 0:
        return np.zeros(a.shape[:-1])
    out = a[..., 0] * x[0]
    for j in range(1, x.shape[0]):
        out = out + a[..., j] * x[j]
    return out


def mat_vec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m @ v`` per element of a stack: ``m`` (..., r, k), ``v`` (..., k) -> (..., r).

    :math:`y_i = \\sum_j m_{ij} v_j`, accumulated for j = 0, 1, ... in turn; the leading
    axes broadcast.
    """
    m = np.asarray(m, dtype=float)
    v = np.asarray(v, dtype=float)
    k = m.shape[-1]
    if v.shape[-1] != k:
        raise ValueError(f"mat_vec: matrix has {k} columns, vector has {v.shape[-1]} entries")
    out = m[..., :, 0] * v[..., None, 0]
    for j in range(1, k):
        out = out + m[..., :, j] * v[..., None, j]
    return out


def mean0(a: np.ndarray) -> np.ndarray | np.float64:
    """``np.mean(a, axis=0)`` of a float64 array with at least one row, the same bits: numpy's mean
    is ``np.add.reduce`` along the axis, then one division by the count. Without its Python
    wrapper (a few µs a call): the per-step code calls it several times a step."""
    return np.add.reduce(a, axis=0) / a.shape[0]
