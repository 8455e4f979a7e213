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

Built-in models
---------------
Every Universal Robots arm of the manufacturer's table "DH parameters for calculations of
kinematics and dynamics" (universal-robots.com): the CB3 arms :func:`ur3`, :func:`ur5`,
:func:`ur10` and the e-Series :func:`ur3e`, :func:`ur5e`, :func:`ur10e`, :func:`ur16e`,
:func:`ur20`, :func:`ur30`; by name through :func:`builtin_robot` (:data:`BUILTIN_ROBOTS`).
Each carries the nominal standard-DH table, the link masses and centres of mass in DH frame i,
the joint position limits, the joint speed limits and an acceleration bound (:data:`UR_ARMS`
says where each number comes from), and its controller generation (CB3: 125 Hz, e-Series:
500 Hz).  Frames: the base is the controller's base frame (DH frame 0, the URDF ``base``
frame of ur_description, *not* ``base_link``, which is turned 180° about z), the flange is DH
frame 6 (the controller's tool flange with a zero TCP, the URDF ``tool0``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .transforms import make_T, rot_x, rot_z

F = NDArray[np.float64]
GRAVITY = np.array([0.0, 0.0, -9.80665])


@dataclass(frozen=True)
class Nominal:
    """Which nominal kinematics a model's figures are against.

    ``robot`` is the robot as named (a built-in name such as ``ur10e`` or a description file's
    name); ``calibration`` the file name of the controller calibration whose kinematics replace
    the robot's nominal ones (the UR ROS driver's ``ur_calibration`` YAML), with its SHA-256,
    or None for the published nominal kinematics.
    """

    robot: str
    calibration: str | None = None
    calibration_sha256: str | None = None

    def as_dict(self) -> dict[str, str | None]:
        """Plain JSON form (report.json ``nominal``, model.json ``robot.nominal``)."""
        return {
            "robot": self.robot,
            "calibration": self.calibration,
            "calibration_sha256": self.calibration_sha256,
        }

    def describe(self) -> str:
        """One line for reports: ``ur10e (nominal DH)`` or ``ur10e with calibration FILE``."""
        if self.calibration is None:
            return f"{self.robot} (published nominal kinematics)"
        sha = (self.calibration_sha256 or "")[:12]
        return f"{self.robot} with controller calibration {self.calibration} (sha256 {sha}…)"


def nominal_of(robot: RobotModel) -> str:
    """The one-line account of which nominal kinematics ``robot``'s figures are against."""
    nom = robot.nominal if robot.nominal is not None else Nominal(robot.name)
    return nom.describe()


@dataclass(frozen=True, eq=False)
class RobotModel:
    """Nominal kinematics and inertial data of a serial robot with revolute joints (SI).

    ``qd_max`` (rad/s) and ``qdd_max`` (rad/s²) are the joint speed and acceleration limits
    where known, ``controller`` the controller generation (``"CB3"``, ``"e-Series"`` or empty)
    with its real-time rate ``control_hz``, and ``nominal`` where the kinematics came from.
    """

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
    qd_max: F | None = None  # (n,) rad/s
    qdd_max: F | None = None  # (n,) rad/s²
    controller: str = ""  # "CB3", "e-Series" or "" (not a UR arm)
    control_hz: float | None = None  # the controller's real-time rate (125 Hz CB3, 500 Hz e)
    nominal: Nominal | None = None
    #: (n,) N·m/A: each joint's torque per A of motor current at its output (motor constant
    #: times gear ratio), as the robot file states it; None: the built-in estimate
    #: (:func:`~quickhealth.identify.jointload.torque_constant`)
    torque_constant: F | None = None

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


# ------------------------------------------------------------------ Universal Robots

UR_JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
_DEG = np.pi / 180.0
#: Every UR arm takes at most this joint acceleration in a move (rad/s²): PolyScope's and the
#: ur_rtde client's upper bound (2291.8 °/s²).  UR publishes no per-joint acceleration limit.
UR_JOINT_ACCEL_MAX = 40.0


@dataclass(frozen=True)
class UrArm:
    """One row group of UR's table "DH parameters for calculations of kinematics and dynamics".

    Standard DH with ``α = (π/2, 0, 0, π/2, −π/2, 0)`` and ``θ`` offsets 0: only ``d1, a2, a3,
    d4, d5, d6`` differ between arms.  Masses (kg) and centres of mass (m, in DH frame i) of
    links 1..6.  ``qd_max_deg`` is the joint speed limit of the user manual (°/s), joint
    ranges are ±360° on every joint (the manuals' figure; the elbow is physically limited to
    about ±180° by the upper arm).  ``inertia_source`` says where masses and centres of mass
    come from when not from the table itself.
    """

    name: str
    controller: str  # "CB3" or "e-Series"
    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float
    masses: tuple[float, ...]
    coms: tuple[tuple[float, float, float], ...]
    qd_max_deg: tuple[float, ...]
    payload_kg: float
    reach_m: float
    inertia_source: str = "UR's table"

    @property
    def control_hz(self) -> float:
        """The controller's real-time rate: CB3 125 Hz, e-Series 500 Hz."""
        return 125.0 if self.controller == "CB3" else 500.0

    def robot(self) -> RobotModel:
        """The nominal :class:`RobotModel` of this arm."""
        r = from_dh(
            self.name,
            a=[0.0, self.a2, self.a3, 0.0, 0.0, 0.0],
            d=[self.d1, 0.0, 0.0, self.d4, self.d5, self.d6],
            alpha=[np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0],
            q_min=np.full(6, -2 * np.pi),
            q_max=np.full(6, 2 * np.pi),
            masses=list(self.masses),
            coms=[list(c) for c in self.coms],
            joint_names=UR_JOINT_NAMES,
        )
        return replace(
            r,
            qd_max=np.asarray(self.qd_max_deg, dtype=float) * _DEG,
            qdd_max=np.full(6, UR_JOINT_ACCEL_MAX),
            controller=self.controller,
            control_hz=self.control_hz,
            nominal=Nominal(self.name),
        )


_UR3_COMS = ((0.0, -0.02, 0.0), (0.13, 0.0, 0.1157), (0.05, 0.0, 0.0238),
             (0.0, 0.0, 0.01), (0.0, 0.0, 0.01), (0.0, 0.0, -0.02))  # fmt: skip
_UR5_COMS = ((0.0, -0.02561, 0.00193), (0.2125, 0.0, 0.11336), (0.15, 0.0, 0.0265),
             (0.0, -0.0018, 0.01634), (0.0, 0.0018, 0.01634), (0.0, 0.0, -0.001159))  # fmt: skip
_UR10_COMS = ((0.021, 0.0, 0.027), (0.38, 0.0, 0.158), (0.24, 0.0, 0.068),
              (0.0, 0.007, 0.018), (0.0, 0.007, 0.018), (0.0, 0.0, -0.026))  # fmt: skip
_UR20_COMS = ((0.0, -0.061, 0.0062), (0.5226, 0.0, 0.2098), (0.3234, 0.0, 0.0604),
              (0.0, -0.0026, 0.0393), (0.0, 0.0024, 0.0379), (0.0, -0.0003, -0.0318))  # fmt: skip
_UR20_MASSES = (16.343, 29.632, 7.879, 3.054, 3.126, 0.846)
_SPEED_SMALL = (180.0, 180.0, 180.0, 360.0, 360.0, 360.0)  # UR3, UR3e
_SPEED_5 = (180.0,) * 6  # UR5, UR5e
_SPEED_10 = (120.0, 120.0, 180.0, 180.0, 180.0, 180.0)  # UR10, UR10e, UR16e
_SPEED_20 = (120.0, 120.0, 150.0, 210.0, 210.0, 210.0)  # UR20, UR30

#: The built-in Universal Robots arms by name (UR's published table; see :class:`UrArm`).
UR_ARMS: dict[str, UrArm] = {
    a.name: a
    for a in (
        UrArm("ur3", "CB3", 0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819,
              (2.0, 3.42, 1.26, 0.8, 0.8, 0.35), _UR3_COMS, _SPEED_SMALL, 3.0, 0.5),
        UrArm("ur5", "CB3", 0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823,
              (3.7, 8.393, 2.33, 1.219, 1.219, 0.1879),
              ((0.0, -0.02561, 0.00193), (0.2125, 0.0, 0.11336), (0.15, 0.0, 0.0265),
               (0.0, -0.0018, 0.01634), (0.0, 0.0018, 0.01634), (0.0, 0.0, -0.001159)),
              _SPEED_5, 5.0, 0.85),
        UrArm("ur10", "CB3", 0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922,
              (7.1, 12.7, 4.27, 2.0, 2.0, 0.365), _UR10_COMS, _SPEED_10, 10.0, 1.3),
        UrArm("ur3e", "e-Series", 0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921,
              (1.98, 3.4445, 1.437, 0.871, 0.805, 0.261), _UR3_COMS, _SPEED_SMALL, 3.0, 0.5),
        UrArm("ur5e", "e-Series", 0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996,
              (3.761, 8.058, 2.846, 1.37, 1.3, 0.365), _UR5_COMS, _SPEED_5, 5.0, 0.85),
        UrArm("ur10e", "e-Series", 0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655,
              (7.369, 13.051, 3.989, 2.1, 1.98, 0.615), _UR10_COMS, _SPEED_10, 12.5, 1.3),
        UrArm("ur16e", "e-Series", 0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655,
              (7.369, 10.45, 4.321, 2.18, 2.033, 0.907),
              ((0.0, -0.016, 0.03), (0.302, 0.0, 0.16), (0.194, 0.0, 0.065),
               (0.0, -0.009, 0.011), (0.0, 0.018, 0.012), (0.0, 0.0, -0.044)),
              _SPEED_10, 16.0, 0.9),
        UrArm("ur20", "e-Series", 0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543,
              _UR20_MASSES, _UR20_COMS, _SPEED_20, 20.0, 1.75),
        UrArm("ur30", "e-Series", 0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543,
              _UR20_MASSES,
              (_UR20_COMS[0], (0.5226 * 0.637 / 0.862, 0.0, 0.2098),
               (0.3234 * 0.5037 / 0.7287, 0.0, 0.0604), *_UR20_COMS[3:]),
              _SPEED_20, 30.0, 1.3,
              inertia_source=(
                  "estimate: the UR20's table (the UR30 shares its joints, wrist and "
                  "published masses in ur_description) with the upper-arm and forearm "
                  "centres of mass scaled to the UR30's link lengths"
              )),
    )
}  # fmt: skip


def builtin_robot(name: str) -> RobotModel:
    """The built-in arm called ``name`` (case-insensitive: ``UR10e`` = ``ur10e``).

    Raises
    ------
    KeyError
        ``name`` is not a built-in arm (:data:`BUILTIN_ROBOTS` lists them).
    """
    return UR_ARMS[name.strip().lower()].robot()


def ur3() -> RobotModel:
    """The built-in UR3 (CB3)."""
    return UR_ARMS["ur3"].robot()


def ur5() -> RobotModel:
    """The built-in UR5 (CB3): manufacturer's DH table, ±360° joints, link masses and CoMs."""
    return UR_ARMS["ur5"].robot()


def ur10() -> RobotModel:
    """The built-in UR10 (CB3)."""
    return UR_ARMS["ur10"].robot()


def ur3e() -> RobotModel:
    """The built-in UR3e (e-Series)."""
    return UR_ARMS["ur3e"].robot()


def ur5e() -> RobotModel:
    """The built-in UR5e (e-Series)."""
    return UR_ARMS["ur5e"].robot()


def ur10e() -> RobotModel:
    """The built-in UR10e (e-Series)."""
    return UR_ARMS["ur10e"].robot()


def ur16e() -> RobotModel:
    """The built-in UR16e (e-Series)."""
    return UR_ARMS["ur16e"].robot()


def ur20() -> RobotModel:
    """The built-in UR20 (e-Series)."""
    return UR_ARMS["ur20"].robot()


def ur30() -> RobotModel:
    """The built-in UR30 (e-Series; inertial data estimated, :data:`UR_ARMS`)."""
    return UR_ARMS["ur30"].robot()


#: Built-in robot names, in the order UR lists them (CB3 first).
BUILTIN_ROBOTS: tuple[str, ...] = tuple(UR_ARMS)


def with_payload(robot: RobotModel, mass: float, com: ArrayLike) -> RobotModel:
    """The robot carrying a rigid payload on its flange (the smart target, a tool).

    ``mass`` (kg) at ``com`` (m, in the flange frame, i.e. the frame after the last joint's
    ``Rz(θ_n) · C_n``) is lumped into the last link: its mass becomes ``m_n + mass`` and its
    centre of mass the mass-weighted mean.  The gravity torques of :func:`gravity_torques` are
    then those of arm and payload together.  A robot without masses gets none (the lumped
    compliance form needs none).
    """
    mass = float(mass)
    if not (np.isfinite(mass) and mass >= 0.0):
        raise ValueError(f"payload mass must be a finite number >= 0, got {mass}")
    c = np.asarray(com, dtype=float).reshape(3)
    if robot.masses is None or robot.coms is None or mass == 0.0:
        return robot
    masses = robot.masses.copy()
    coms = robot.coms.copy()
    m_n = masses[-1]
    coms[-1] = (m_n * coms[-1] + mass * c) / (m_n + mass)
    masses[-1] = m_n + mass
    return replace(robot, masses=masses, coms=coms)


def with_kinematics(
    robot: RobotModel,
    links: ArrayLike,
    *,
    name: str | None = None,
    nominal: Nominal | None = None,
    convention: str = "generic",
) -> RobotModel:
    """``robot`` with other constant link transforms (zero joint offsets), same bodies.

    For a controller calibration that replaces the nominal kinematics: the joint readings keep
    their meaning, the links are ``links`` (shape ``(n+1, 4, 4)``), and each link's centre of
    mass keeps its place on the link: it is carried over at the zero joint configuration
    (the world position of link i's centre of mass under ``robot`` is expressed in link i's
    frame of the new kinematics, which differs from the nominal one by the calibration's
    sub-millimetre deltas and any frame convention, e.g. a shift along a joint axis).
    """
    L = np.asarray(links, dtype=float)
    nj = robot.n_joints
    if L.shape != (nj + 1, 4, 4):
        raise ValueError(f"links must have shape {(nj + 1, 4, 4)}, got {L.shape}")
    new = replace(
        robot,
        name=name or robot.name,
        links=L,
        q_offset=np.zeros(nj),
        dh=None,
        convention=convention,
        nominal=nominal if nominal is not None else robot.nominal,
    )
    if robot.masses is None or robot.coms is None:
        return new
    q0 = np.zeros((1, nj))
    _, f_old = chain(robot, q0, return_frames=True)
    _, f_new = chain(new, q0, return_frames=True)
    body_old = f_old[0] @ robot.links[1:]  # (nj, 4, 4) link frames after Rz(θ_i)·C_i
    body_new = f_new[0] @ L[1:]
    c_world = (body_old[:, :3, :3] @ robot.coms[:, :, None])[..., 0] + body_old[:, :3, 3]
    R_new = body_new[:, :3, :3]
    coms = np.einsum("nji,nj->ni", R_new, c_world - body_new[:, :3, 3])
    return replace(new, coms=coms)


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
