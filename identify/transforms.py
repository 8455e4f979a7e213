"""Rigid transforms, vectorised over poses.

Conventions
-----------
- ``T_a_b`` is a 4×4 homogeneous transform that maps points from frame b into frame a.
- Stacks of transforms have shape ``(n, 4, 4)``; stacks of rotations ``(n, 3, 3)``.
- Orientation angles of the measurement file (CONTRACTS.md): ``R = Rz(roll) · Ry(yaw) · Rx(pitch)``.
- Small error motions of the error model: ``Rot(εx, εy, εz) = Rx(εx) · Ry(εy) · Rz(εz)``.
All angles in radians, lengths in metres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F = NDArray[np.float64]


def rot_x(a: ArrayLike) -> F:
    """Rotation about x, shape ``(*a.shape, 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2
    )


def rot_y(a: ArrayLike) -> F:
    """Rotation about y, shape ``(*a.shape, 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2
    )


def rot_z(a: ArrayLike) -> F:
    """Rotation about z, shape ``(*a.shape, 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def rpy_to_R(pitch: ArrayLike, yaw: ArrayLike, roll: ArrayLike) -> F:
    """Measurement-file angles to rotation: ``R = Rz(roll) · Ry(yaw) · Rx(pitch)`` (rad)."""
    return rot_z(roll) @ rot_y(yaw) @ rot_x(pitch)


def R_to_rpy(R: ArrayLike) -> F:
    """Inverse of :func:`rpy_to_R`; returns ``(..., 3)`` as (pitch, yaw, roll) in rad.

    Yaw is in [-π/2, π/2]; near yaw = ±π/2 (gimbal lock) roll absorbs the free angle.
    """
    R = np.asarray(R, dtype=float)
    yaw = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    pitch = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    roll = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([pitch, yaw, roll], axis=-1)


def quat_to_R(q: ArrayLike) -> F:
    """Unit quaternions ``(..., 4)`` as ``(w, x, y, z)`` (Hamilton, active) to rotations.

    The quaternion is normalised first; a zero quaternion gives NaN (the caller validates).
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = (q[..., k] for k in range(4))
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def R_to_quat(R: ArrayLike) -> F:
    """Rotations ``(..., 3, 3)`` to unit quaternions ``(w, x, y, z)`` with ``w ≥ 0``.

    Shepperd's method: the largest of the four squared components is taken as the pivot, so
    the result is accurate for every rotation (no division by a small number).
    """
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.stack([tr, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], -1)
    k = np.argmax(d, axis=-1)
    r = R
    # pivot w
    s = np.sqrt(np.maximum(1.0 + tr, 1e-300)) * 2.0
    cand_w = np.stack(
        [
            0.25 * s,
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 1, 0] - r[..., 0, 1]) / s,
        ],
        -1,
    )
    s = np.sqrt(np.maximum(1.0 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2], 1e-300)) * 2.0
    cand_x = np.stack(
        [
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            0.25 * s,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
        ],
        -1,
    )
    s = np.sqrt(np.maximum(1.0 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2], 1e-300)) * 2.0
    cand_y = np.stack(
        [
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            0.25 * s,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
        ],
        -1,
    )
    s = np.sqrt(np.maximum(1.0 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2], 1e-300)) * 2.0
    cand_z = np.stack(
        [
            (r[..., 1, 0] - r[..., 0, 1]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
            0.25 * s,
        ],
        -1,
    )
    cands = np.stack([cand_w, cand_x, cand_y, cand_z], -2)
    out = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return np.where(out[..., :1] < 0, -out, out)


def small_error_transform(d: ArrayLike, e: ArrayLike) -> F:
    """Eq. 1 of METHOD.md: ``E = Trans(δx, δy, δz) · Rot(εx, εy, εz)``.

    Parameters
    ----------
    d : array, shape (..., 3), m
        Translations δx, δy, δz.
    e : array, shape (..., 3), rad
        Rotations εx, εy, εz; ``Rot = Rx(εx) · Ry(εy) · Rz(εz)``.

    Returns
    -------
    ndarray, shape (..., 4, 4)
    """
    d = np.asarray(d, dtype=float)
    e = np.asarray(e, dtype=float)
    shape = np.broadcast_shapes(d.shape, e.shape)[:-1]
    T = np.zeros((*shape, 4, 4))
    cx, cy, cz = np.cos(e[..., 0]), np.cos(e[..., 1]), np.cos(e[..., 2])
    sx, sy, sz = np.sin(e[..., 0]), np.sin(e[..., 1]), np.sin(e[..., 2])
    # Rx · Ry · Rz written out (the product of three stacks cost a third of a fit)
    T[..., 0, 0] = cy * cz
    T[..., 0, 1] = -cy * sz
    T[..., 0, 2] = sy
    T[..., 1, 0] = cx * sz + sx * sy * cz
    T[..., 1, 1] = cx * cz - sx * sy * sz
    T[..., 1, 2] = -sx * cy
    T[..., 2, 0] = sx * sz - cx * sy * cz
    T[..., 2, 1] = sx * cz + cx * sy * sz
    T[..., 2, 2] = cx * cy
    T[..., :3, 3] = d
    T[..., 3, 3] = 1.0
    return T


def make_T(R: ArrayLike, t: ArrayLike) -> F:
    """Assemble homogeneous transforms from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*shape, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: ArrayLike) -> F:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    return make_T(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def skew(v: ArrayLike) -> F:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def exp_so3(w: ArrayLike) -> F:
    """Rotation matrices from rotation vectors ``(..., 3)`` (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def log_so3(R: ArrayLike) -> F:
    """Rotation vectors ``(..., 3)`` from rotation matrices (robust near 0 and π)."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(cos)
    v = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1
    )
    s = np.sin(th)
    small = s < 1e-6
    k = np.where(small, 0.5 + th**2 / 12.0, th / (2.0 * np.where(small, 1.0, s)))
    w = v * k[..., None]
    # Near π the antisymmetric part vanishes: take the axis from the symmetric part.
    near_pi = th > np.pi - 1e-3
    if np.any(near_pi):
        Rp = R[near_pi]
        B = (Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - np.eye(3) * cos[near_pi][..., None, None]
        idx = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        ax = B[np.arange(len(idx)), idx]
        ax = ax / np.linalg.norm(ax, axis=-1, keepdims=True)
        sign = np.sign(np.einsum("...i,...i->...", ax, v[near_pi]))
        sign = np.where(sign == 0, 1.0, sign)
        w[near_pi] = ax * (th[near_pi] * sign)[..., None]
    return w


def kabsch(P: ArrayLike, Q: ArrayLike) -> F:
    """Best rigid transform ``T`` with ``Q ≈ T · P`` (least squares) for point sets ``(n, 3)``."""
    P = np.asarray(P, dtype=float)
    Q = np.asarray(Q, dtype=float)
    cp, cq = P.mean(0), Q.mean(0)
    H = (P - cp).T @ (Q - cq)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_T(R, cq - R @ cp)
