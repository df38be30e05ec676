"""Per-slot buffers of the columnar PDR engine (:mod:`pdr.fleet_rows`): numba typed lists of
arrays, one per responder, whose length follows the data (trailing windows, the detector's
tail, the pressure history). Kept as the single-responder classes keep theirs
(``np.concatenate`` then a mask)."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def keep_after(buf, lim, extra):  # pragma: no cover - compiled
    """The rows of ``buf`` whose first column is above ``lim`` (``buf[buf[:, 0] > lim]``), in a
    new array with ``extra`` rows left free at the end; one block copy when they are a suffix
    (times in order, the usual case)."""
    n = buf.shape[0]
    k0 = n
    for i in range(n - 1, -1, -1):  # the kept suffix
        if buf[i, 0] > lim:
            k0 = i
        else:
            break
    suffix = True
    for i in range(k0):
        if buf[i, 0] > lim:
            suffix = False
            break
    if suffix:
        out = np.empty((n - k0 + extra, buf.shape[1]))
        out[:n - k0] = buf[k0:]
        return out
    k = 0
    for i in range(n):
        if buf[i, 0] > lim:
            k += 1
    out = np.empty((k + extra, buf.shape[1]))
    k = 0
    for i in range(n):
        if buf[i, 0] > lim:
            out[k] = buf[i]
            k += 1
    return out


# ------------------------------------------------------------------ heading, detector buffer, motion windows


@njit(cache=True)
def get_rows(lst, r):  # pragma: no cover - compiled
    return lst[r]


@njit(cache=True)
def set_rows(lst, r, a):  # pragma: no cover - compiled
    lst[r] = a


@njit(cache=True)
def append_rows(lst, a):  # pragma: no cover - compiled
    lst.append(a)


@njit(cache=True)
def pack_rows(lst, cols):  # pragma: no cover - compiled
    """A typed list of ``(k_i, cols)`` arrays as one ``(sum k_i, cols)`` array and the ``k_i``
    (a snapshot's form: one array, not one object per slot)."""
    n = len(lst)
    lens = np.empty(n, np.int64)
    total = 0
    for i in range(n):
        if lst[i].shape[1] != cols:
            raise ValueError("pack_rows: an entry with another number of columns")
        lens[i] = lst[i].shape[0]
        total += lens[i]
    out = np.empty((total, cols))
    k = 0
    for i in range(n):
        out[k:k + lens[i]] = lst[i]
        k += lens[i]
    return lens, out


@njit(cache=True)
def pack_vectors(lst):  # pragma: no cover - compiled
    """A typed list of 1-D arrays as one array and their lengths (see :func:`pack_rows`)."""
    n = len(lst)
    lens = np.empty(n, np.int64)
    total = 0
    for i in range(n):
        lens[i] = lst[i].shape[0]
        total += lens[i]
    out = np.empty(total)
    k = 0
    for i in range(n):
        out[k:k + lens[i]] = lst[i]
        k += lens[i]
    return lens, out
