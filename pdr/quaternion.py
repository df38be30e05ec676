"""Unit-quaternion algebra on numpy arrays.

Convention used everywhere in firetrack (see GUIDE.md):

* scalar first, ``q = [w, x, y, z]``;
* Hamilton product, ``(a ⊗ b)`` as in Tupý (2023) eq. 6.9 / Justa (2022) eq. 15;
* a quaternion *rotates body -> navigation*: ``v_nav = q ⊗ [0, v_body] ⊗ q*``.
  The predicted body-frame measurement of a navigation-frame vector is therefore
  ``v_body = q* ⊗ [0, v_nav] ⊗ q`` (Justa eq. 14, ``v' = q⁻¹ v q``).

Every function accepts a single quaternion of shape (4,) or a stack of shape (N, 4)
and broadcasts like numpy.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pdr.fixed_order import mat_vec

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of scalar-first quaternions (Tupý eq. 6.9)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def left_matrix(p: np.ndarray) -> np.ndarray:
    """4x4 matrix L with ``p ⊗ q = L q``: left multiplication by a fixed ``p`` as one matmul."""
    w, x, y, z = np.asarray(p, dtype=float)
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def conjugate(q: np.ndarray) -> np.ndarray:
    """``q* = [w, -x, -y, -z]``; the inverse of a unit quaternion (Justa eq. 14)."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R(q) with ``v_nav = R v_body`` (Justa eq. 13), shape (..., 3, 3)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    r = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return r.reshape(r.shape[:-1] + (3, 3))


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Body -> navigation: ``q ⊗ [0, v] ⊗ q*`` for unit ``q``; shapes (...,4), (...,3).

    Summed in a fixed order per element (:func:`pdr.fixed_order.mat_vec`), so a sample
    gives the same bits alone or in any batch, on any CPU's kernels.
    """
    return mat_vec(to_matrix(q), np.asarray(v, dtype=float))


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Navigation -> body: ``q* ⊗ [0, v] ⊗ q`` = ``R(q)ᵀ v`` (Justa eq. 14, 23)."""
    return mat_vec(np.swapaxes(to_matrix(q), -1, -2), np.asarray(v, dtype=float))


def from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """``[cos(θ/2), u sin(θ/2)]`` for a unit axis ``u`` (Justa eq. 12)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), axis * np.sin(half)], axis=-1)


def from_rotation_vector(rv: np.ndarray) -> np.ndarray:
    """Exponential map of a rotation vector (axis * angle, rad); safe at zero."""
    rv = np.asarray(rv, dtype=float)
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(θ/2)/θ -> 1/2 as θ -> 0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), rv * k], axis=-1)


def from_yaw(yaw: np.ndarray) -> np.ndarray:
    """Rotation about the navigation z axis by ``yaw`` (rad, counter-clockwise)."""
    yaw = np.asarray(yaw, dtype=float)
    z = np.zeros_like(yaw)
    return np.stack([np.cos(yaw / 2), z, z, np.sin(yaw / 2)], axis=-1)


def angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle ``θ(q) = 2 atan2(|q_xyz|, |q_w|)`` in [0, π] (Justa eq. 16).

    ``|q_w|`` makes q and -q (the same rotation) give the same angle.
    """
    q = np.asarray(q, dtype=float)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def angle_between(q_ref: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """Orientation error ``θ(q_ref ⊗ q_est*)`` (Justa eq. 35), rad."""
    return angle(multiply(q_ref, conjugate(q_est)))


def yaw(q: np.ndarray) -> np.ndarray:
    """Yaw of the body x axis in the navigation frame, counter-clockwise from nav x (rad).

    The heading of a body axis ``b`` is ``atan2`` of the horizontal part of ``R(q) b``;
    for ``b = x`` this is ``atan2(2(xy + wz), 1 - 2(y² + z²))`` (ZYX Euler yaw).
    """
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))


def from_two_vectors(acc: np.ndarray, mag: np.ndarray | None = None, north_axis: int = 1) -> np.ndarray:
    """Orientation (body -> nav, z up) from one gravity and optionally one magnetic sample.

    The navigation z axis is the measured specific force (up at rest); with ``mag`` the
    horizontal projection of the field defines nav axis ``north_axis`` (1 for ENU's y,
    0 for a frame whose x points to magnetic north). Without ``mag`` yaw is zero.
    """
    up = np.asarray(acc, dtype=float)
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    if mag is None:
        ref = np.array([1.0, 0.0, 0.0]) if abs(up[..., 0]).max() < 0.9 else np.array([0.0, 1.0, 0.0])
        north = ref - np.sum(ref * up, axis=-1, keepdims=True) * up
    else:
        m = np.asarray(mag, dtype=float)
        north = m - np.sum(m * up, axis=-1, keepdims=True) * up
    north = north / np.linalg.norm(north, axis=-1, keepdims=True)
    east = np.cross(north, up)
    if north_axis == 1:
        rows = [east, north, up]  # ENU: nav axes expressed in body coordinates
    else:
        rows = [north, -east, up]  # x north, y west, z up
    r = np.stack(rows, axis=-2)  # R_nav<-body has nav axes as rows
    return from_matrix(r)


def from_matrix(r: np.ndarray) -> np.ndarray:
    """Quaternion (w >= 0) of a rotation matrix ``v_nav = R v_body`` (via scipy's Rotation)."""
    r = np.asarray(r, dtype=float)
    q = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat(scalar_first=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(r.shape[:-2] + (4,))
