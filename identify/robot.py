"""Robot models: nominal kinematics, joint limits and link inertial data.

Every serial robot is held in one form, whatever file it came from::

    T_base_flange = C0 · Rz(θ1 + o1) · C1 · Rz(θ2 + o2) · C2 · … · Rz(θn + on) · Cn

``C_i`` are constant transforms (``links``, shape ``(n+1, 4, 4)``), ``o_i`` the joint zero
offsets.  Standard DH (``A_i = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)``) gives ``C0 = I`` and
``C_i = Tz(d_i) Tx(a_i) Rx(α_i)``; modified DH and URDF files map onto it too.  The frame
right after ``Rz(θ_i)`` turns with joint i and has its z axis on the joint axis: the error
model puts joint i's error transform ``E_i`` there, so δz is axial, δx/δy radial, εx/εy
tilt and εz angular positioning of *that* joint (METHOD.md Eq. 1).

Link i's centre of mass is given in the frame after ``Rz(θ_i) · C_i`` (for standard DH:
the DH frame i, as manufacturers publish it).

``RobotModel`` is immutable (pinocchio's model/data split: nothing here holds scratch).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .transforms import make_T, rot_x, rot_z

F = NDArray[np.float64]
GRAVITY = np.array([0.0, 0.0, -9.80665])


@dataclass(frozen=True, eq=False)
class RobotModel:
    """Nominal kinematics and inertial data of a serial robot with revolute joints (SI)."""

    name: str
    links: F  # (n+1, 4, 4) constant transforms C0..Cn
    q_offset: F  # (n,) rad
    q_min: F  # (n,) rad
    q_max: F  # (n,) rad
    masses: F | None = None  # (n,) kg
    coms: F | None = None  # (n, 3) m, in the frame after Rz(θ_i)·C_i
    joint_names: tuple[str, ...] = ()
    dh: dict[str, list[float]] | None = field(default=None)  # the source table, for reference
    convention: str = "generic"  # "dh", "mdh", "urdf" or "generic"

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return int(self.q_offset.shape[0])

    def fk(self, q: ArrayLike) -> F:
        """Nominal forward kinematics ``T_base_flange``.

        Parameters
        ----------
        q : array, shape (n_poses, n_joints) or (n_joints,), rad

        Returns
        -------
        ndarray, shape (n_poses, 4, 4) or (4, 4)
        """
        q = np.asarray(q, dtype=float)
        single = q.ndim == 1
        T = chain(self, np.atleast_2d(q))
        return T[0] if single else T


def chain(
    robot: RobotModel,
    q: F,
    E_joint: F | None = None,
    dq: F | None = None,
    link_scale: F | None = None,
    return_frames: bool = False,
) -> F | tuple[F, F]:
    """Forward kinematics with optional error transforms and perturbations (vectorised).

    Parameters
    ----------
    robot : RobotModel
    q : ndarray, shape (n, nj), rad
        Joint readings.
    E_joint : ndarray, shape (n, nj, 4, 4), optional
        Error transform of each joint, inserted right after ``Rz(θ_i)``.
    dq : ndarray, shape (n, nj), rad, optional
        Joint angle perturbations (physical effects such as compliance or backlash): the
        joint turns to ``q + dq`` while ``E_joint`` stays evaluated at the reading ``q``.
    link_scale : ndarray, shape (n,), optional
        Factor on every translation of the constant link transforms (thermal growth).
    return_frames : bool
        Also return the joint frames ``T_base_Ji`` (after ``Rz`` and ``E_i``), shape
        ``(n, nj, 4, 4)``, for analytic Jacobians.

    Returns
    -------
    T_base_flange : ndarray, shape (n, 4, 4)
    frames : ndarray, shape (n, nj, 4, 4), only with ``return_frames``
    """
    n, nj = q.shape
    theta = q + robot.q_offset
    if dq is not None:
        theta = theta + dq
    Rz = np.zeros((n, nj, 4, 4))
    Rz[..., :3, :3] = rot_z(theta)
    Rz[..., 2, 2] = 1.0
    Rz[..., 3, 3] = 1.0
    if E_joint is not None:
        Rz = Rz @ E_joint
    links = np.broadcast_to(robot.links, (n, nj + 1, 4, 4))
    if link_scale is not None:
        links = links.copy()
        links[..., :3, 3] *= np.asarray(link_scale, dtype=float)[:, None, None]
    T = links[:, 0]
    frames = np.empty((n, nj, 4, 4)) if return_frames else None
    for i in range(nj):  # loop over joints (≤ 7), vectorised over poses
        T = T @ Rz[:, i]
        if frames is not None:
            frames[:, i] = T
        T = T @ links[:, i + 1]
    if frames is not None:
        return T, frames
    return T


def from_dh(
    name: str,
    a: ArrayLike,
    d: ArrayLike,
    alpha: ArrayLike,
    theta_offset: ArrayLike | None = None,
    q_min: ArrayLike | None = None,
    q_max: ArrayLike | None = None,
    masses: ArrayLike | None = None,
    coms: ArrayLike | None = None,
    modified: bool = False,
    joint_names: tuple[str, ...] = (),
) -> RobotModel:
    """Build a :class:`RobotModel` from a DH table (SI units).

    Standard DH: ``A_i = Rz(θ_i + o_i) Tz(d_i) Tx(a_i) Rx(α_i)``.
    Modified (Craig) DH: ``A_i = Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i + o_i) Tz(d_i)``, i.e. the
    table's row i holds ``a_{i-1}, α_{i-1}, d_i``.
    """
    a, d, alpha = (np.asarray(v, dtype=float) for v in (a, d, alpha))
    nj = a.shape[0]
    off = np.zeros(nj) if theta_offset is None else np.asarray(theta_offset, dtype=float)
    links = np.tile(np.eye(4), (nj + 1, 1, 1))
    for i in range(nj):
        Tz = make_T(np.eye(3), [0.0, 0.0, d[i]])
        Tx = make_T(np.eye(3), [a[i], 0.0, 0.0])
        Rx = make_T(rot_x(alpha[i]), np.zeros(3))
        if modified:
            links[i] = links[i] @ Rx @ Tx
            links[i + 1] = Tz
        else:
            links[i + 1] = Tz @ Tx @ Rx
    lo = np.full(nj, -2 * np.pi) if q_min is None else np.asarray(q_min, dtype=float)
    hi = np.full(nj, 2 * np.pi) if q_max is None else np.asarray(q_max, dtype=float)
    return RobotModel(
        name=name,
        links=links,
        q_offset=off,
        q_min=lo,
        q_max=hi,
        masses=None if masses is None else np.asarray(masses, dtype=float),
        coms=None if coms is None else np.asarray(coms, dtype=float),
        joint_names=joint_names or tuple(f"j{i + 1}" for i in range(nj)),
        dh={
            "a": list(map(float, a)),
            "d": list(map(float, d)),
            "alpha": list(map(float, alpha)),
            "theta_offset": list(map(float, off)),
        },
        convention="mdh" if modified else "dh",
    )


def ur5() -> RobotModel:
    """The built-in UR5 (CB3): manufacturer's DH table, ±360° joints, link masses and CoMs."""
    return from_dh(
        "ur5",
        a=[0.0, -0.425, -0.39225, 0.0, 0.0, 0.0],
        d=[0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823],
        alpha=[np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0],
        q_min=np.full(6, -2 * np.pi),
        q_max=np.full(6, 2 * np.pi),
        masses=[3.7, 8.393, 2.33, 1.219, 1.219, 0.1879],
        coms=[
            [0.0, -0.02561, 0.00193],
            [0.2125, 0.0, 0.11336],
            [0.15, 0.0, 0.0265],
            [0.0, -0.0018, 0.01634],
            [0.0, 0.0018, 0.01634],
            [0.0, 0.0, -0.001159],
        ],
        joint_names=(
            "shoulder_pan",
            "shoulder_lift",
            "elbow",
            "wrist_1",
            "wrist_2",
            "wrist_3",
        ),
    )


def gravity_torques(robot: RobotModel, q: ArrayLike, g: ArrayLike = GRAVITY) -> F:
    """Static gravity torque each joint carries, ``τ_i`` (N·m), shape ``(n, nj)``.

    ``τ_i = z_iᵀ Σ_{j ≥ i} (c_j − o_i) × (m_j g)`` with the joint axis ``z_i`` and origin
    ``o_i`` and the link centres of mass ``c_j``, all in the base frame (base z up).
    The sign is the torque gravity applies about the joint axis.
    """
    if robot.masses is None or robot.coms is None:
        raise ValueError(f"robot {robot.name!r} has no link masses and centres of mass")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    T, frames = chain(robot, q, return_frames=True)
    n, nj = q.shape
    body = frames @ robot.links[1:]  # frame after Rz(θ_i)·C_i, (n, nj, 4, 4)
    c = (body[..., :3, :3] @ robot.coms[None, :, :, None])[..., 0] + body[..., :3, 3]  # (n,nj,3)
    f = robot.masses[None, :, None] * np.asarray(g, dtype=float)  # (1, nj, 3)
    tau = np.empty((n, nj))
    for i in range(nj):
        z = frames[:, i, :3, 2]
        o = frames[:, i, :3, 3]
        m = np.cross(c[:, i:] - o[:, None, :], np.broadcast_to(f[:, i:], c[:, i:].shape)).sum(1)
        tau[:, i] = np.einsum("ni,ni->n", z, m)
    return tau


def gravity_regressor(robot: RobotModel, q: ArrayLike, joint: int, g: ArrayLike = GRAVITY) -> F:
    """Gravity torque on ``joint`` (0-based) per unit first mass moment of every link beyond it.

    ``Y[:, j, a] = z_kᵀ ((R_j e_a) × ĝ)`` for links ``j = joint … n−1`` and axes ``a = x, y,
    z`` of the frame right after ``Rz(θ_j)`` (joint j's frame: its z axis is the joint axis),
    with ``ĝ = g / |g|``.  Shape ``(n, nj − joint, 3)``, dimensionless.  With the first moments
    ``h_j`` of :func:`first_moments` (kg·m) the static torque is ``τ_k = |g| Σ_j Y[:, j] · h_j``:
    it depends on the joint rotations alone, linearly in the moments, so the masses need not
    be known to express the *shape* of the gravity load (:mod:`.effects.compliance`).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    g = np.asarray(g, dtype=float)
    ghat = g / np.linalg.norm(g)
    _, frames = chain(robot, q, return_frames=True)
    R = frames[:, joint:, :3, :3]  # (n, m, 3, 3): columns e_a of joint j's frame in the base
    z = frames[:, joint, :3, 2]  # (n, 3)
    # zᵀ (v × ĝ) = v · (ĝ × z)
    w = np.cross(ghat[None, :], z)  # (n, 3)
    return np.einsum("nmia,ni->nma", R, w)


def first_moments(robot: RobotModel) -> F:
    """First mass moment of every link in its joint frame, ``h_j`` (kg·m), shape ``(nj, 3)``.

    ``h_j = m_j · (R_Cj c_j + t_Cj) + (Σ_{i > j} m_i) · t_Cj`` with ``C_j`` the constant
    transform after joint j (``robot.links[j + 1]``) and ``c_j`` the centre of mass in the frame
    after it: the links beyond j hang at the origin of the next joint, which is fixed in joint
    j's frame.  Then :func:`gravity_torques` ``= |g| Σ_{j ≥ k} gravity_regressor · h_j``.
    """
    if robot.masses is None or robot.coms is None:
        raise ValueError(f"robot {robot.name!r} has no link masses and centres of mass")
    m = np.asarray(robot.masses, dtype=float)
    C = robot.links[1:]
    beyond = np.concatenate([np.cumsum(m[::-1])[::-1][1:], [0.0]])
    local = (C[:, :3, :3] @ robot.coms[:, :, None])[..., 0] + C[:, :3, 3]
    return m[:, None] * local + beyond[:, None] * C[:, :3, 3]
