"""Readable per-sample SCF/FSCF written with :mod:`pdr.quaternion` operations.

This is the executable specification of Justa (2022) eqs. 17-34: the tests check the
compiled kernel against it, and the benchmark uses it as the in-process baseline. It is
about a hundred times slower than the kernel; never use it on a hot path.
"""
from __future__ import annotations

import numpy as np

from pdr import quaternion as quat

UP = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = np.linalg.norm(v)
    return None if n < 1e-12 else v / n


def scf_reference(q0, dt, acc, gyr, mag=None, gain_acc=0.2, gain_mag=0.02, exact=True) -> np.ndarray:
    """SCF (``exact``) or FSCF in the native frame (x magnetic north, z up); returns (N, 4)."""
    q = np.asarray(q0, float)
    out = np.empty((len(dt), 4))
    for i, h in enumerate(dt):
        w = np.asarray(gyr[i], float)
        if exact:  # eqs. 17-20
            s = np.sin(0.5 * w * h)
            q = quat.multiply(q, np.r_[np.sqrt(max(0.0, 1 - s @ s)), s])
        else:
            q = q + 0.5 * h * quat.multiply(q, np.r_[0.0, w])
        a_pred = quat.rotate_inverse(q, UP)  # eq. 23 (q not yet normalised: as in the paper)
        f = np.zeros(3)
        a = _unit(np.asarray(acc[i], float))
        if a is not None:
            axis = _unit(np.cross(a, a_pred))  # eq. 26
            if axis is not None:
                f += 0.5 * gain_acc * h * axis
        if mag is not None:
            m = _unit(np.asarray(mag[i], float))
            if m is not None:
                mz = float(np.clip(a_pred @ m, -1, 1))  # eq. 24
                m_pred = quat.rotate_inverse(q, np.array([np.sqrt(1 - mz * mz), 0.0, mz]))  # eq. 25
                axis = _unit(np.cross(m, m_pred))
                if axis is not None:
                    f += 0.5 * gain_mag * h * axis
        if exact:  # eqs. 31-32
            fn = np.linalg.norm(f)
            fc = f * (np.sin(fn) / fn if fn > 1e-12 else 1.0)
            q_cor = np.r_[np.sqrt(max(0.0, 1 - fc @ fc)), fc]
        else:  # eq. 33
            q_cor = np.r_[1.0, f]
        q = quat.multiply(q, q_cor)
        q = q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)  # eq. 34
        out[i] = q
    return out
