"""Per-slot buffers of the columnar PDR engine (:mod:`pdr.fleet_rows`): numba typed lists of
arrays, one per responder, whose length follows the data (trailing windows, the detector's
tail, the pressure history). Kept as the single-responder classes keep theirs
(``np.concatenate`` then a mask)."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _kept_suffix(buf, lim):  # pragma: no cover - compiled
    """``(k0, suffix)``: the rows from ``k0`` on are above ``lim`` (the row before is not), and
    ``suffix``: no row before ``k0`` is above it (the rows kept are exactly those)."""
    n = buf.shape[0]
    k0 = n
    for i in range(n - 1, -1, -1):
        if buf[i, 0] > lim:
            k0 = i
        else:
            break
    for i in range(k0):
        if buf[i, 0] > lim:
            return k0, False
    return k0, True


@njit(cache=True)
def keep_after(buf, lim, extra):  # pragma: no cover - compiled
    """The rows of ``buf`` whose first column is above ``lim`` (``buf[buf[:, 0] > lim]``), in a
    new array with ``extra`` rows left free at the end; one block copy when they are a suffix
    (times in order, the usual case)."""
    n = buf.shape[0]
    k0, suffix = _kept_suffix(buf, lim)
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


@njit(cache=True)
def kept_with_room(buf, base, end, lim, extra):  # pragma: no cover - compiled
    """``keep_after(buf, lim, extra)`` without copying the rows kept, where it can: ``buf`` is
    ``base[end - len(buf):end]`` (a view; ``end`` < 0: no such base), so when the rows kept are
    a suffix and ``base`` has ``extra`` free rows after ``end``, the answer is the view
    ``base[start:end + extra]``. Otherwise the rows kept go to a new base with room for as
    many again (the copy is paid once per that many rows, not once per frame). Returns the
    view, its base and the view's end in the base. The values are those of :func:`keep_after`."""
    n = buf.shape[0]
    k0, suffix = _kept_suffix(buf, lim)
    if (suffix and n <= end <= base.shape[0] - extra
            and (n == 0 or (base[end - n, 0] == buf[0, 0] and base[end - 1, 0] == buf[n - 1, 0]))):
        return base[end - n + k0:end + extra], base, end + extra
    kept = buf[k0:] if suffix else keep_after(buf, lim, 0)
    k = kept.shape[0]
    nb = np.empty((2 * (k + extra) + 16, buf.shape[1]))
    nb[:k] = kept
    return nb[:k + extra], nb, k + extra


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
