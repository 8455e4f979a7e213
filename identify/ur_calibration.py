"""The UR ROS driver's calibration kinematics: six joint origins (x, y, z, roll, pitch, yaw).

A UR controller does not compute with the nominal DH table but with its factory calibration.
The ROS driver's ``ur_calibration`` tool reads it from the controller and writes it as a YAML
file that ur_description's URDF takes as ``kinematics_params`` (the same layout as the
description's own ``config/<arm>/default_kinematics.yaml``)::

    kinematics:
      shoulder:  {x: 0, y: 0, z: 0.1273, roll: 0, pitch: 0, yaw: 0}
      upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: 0}
      forearm:   {x: -0.612, y: 0, z: 0, roll: 0, pitch: 0, yaw: 0}
      wrist_1:   {x: -0.5723, y: 0, z: 0.163941, roll: 0, pitch: 0, yaw: 0}
      wrist_2:   {x: 0, y: -0.1157, z: 0, roll: 1.570796327, pitch: 0, yaw: 0}
      wrist_3:   {x: 0, y: 0.0922, z: 0, roll: 1.570796327, pitch: 3.141592654, yaw: 3.141592654}
      hash: calib_17227329492635474227

Meaning: segment i is the ``<origin>`` of joint i in ur_description's ``ur_macro.xacro``, the
transform from the previous link frame to joint i's frame, whose z axis is the joint axis::

    T_base_tool0(q) = O_1 · Rz(q1) · O_2 · Rz(q2) · … · O_6 · Rz(q6),
    O_i = Trans(x, y, z) · Rot(roll, pitch, yaw)

``base`` is the controller's base frame (ur_description's ``base`` = ``base_link_inertia``,
``base_link`` turned 180° about z) and the chain ends on ``wrist_3_link`` = ``tool0``, the
controller's tool flange with a zero TCP.  These are the frames of the built-in DH models
(:mod:`quickhealth.identify.robot`), so the nominal file of an arm and its DH table give the
same forward kinematics (to the file's rounding, ~1e-10 m).  ``hash`` is the controller's
checksum of its calibration: the driver compares it with the connected robot's and logs a
mismatch.

The angles (:data:`CONVENTIONS`).  ``ur_calibration`` computes them with Eigen's
``eulerAngles(0, 1, 2)``: ``Rot = Rx(roll) · Ry(pitch) · Rz(yaw)``, and with that reading the
file reproduces the controller's calibrated DH chain exactly (to 1e-12 m for the deltas of
ur_calibration's own unit test, with its chain correction re-implemented in the tests).  A
URDF ``<origin rpy>`` reads the same three numbers as ``Rot = Rz(yaw) · Ry(pitch) ·
Rx(roll)``: the two agree on the nominal files (single-axis rotations) and differ on a
calibrated one by the small angles of the upper arm and wrists: 0.043 mm and 0.061 mrad at
the flange for that unit test's UR10.  This module reads a file the way ``ur_calibration``
wrote it (what the controller computes: the point of ``--calibration``) and writes files whose
joint frames are turned about their axes so that both readings agree to within what a real
calibration's last-joint offset leaves (2 µm for the same UR10, reported in the export).

Pure functions; the file is read by :func:`quickhealth.station.formats.read_ur_calibration`.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .robot import RobotModel, chain
from .transforms import log_so3, rot_x, rot_y, rot_z

F = NDArray[np.float64]

#: The six segments of the ``kinematics`` block, base to flange.
SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
KEYS = ("x", "y", "z", "roll", "pitch", "yaw")


#: How the three angles make a rotation.  ``"ur_calibration"``: as the driver's calibration tool
#: computes them (Eigen ``eulerAngles(0, 1, 2)``), ``R = Rx(roll) · Ry(pitch) · Rz(yaw)``;
#: ``"urdf"``: as a URDF ``<origin rpy>`` reads them, ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``.
CONVENTIONS = ("ur_calibration", "urdf")


def origin_transform(xyz: ArrayLike, rpy: ArrayLike, convention: str = "ur_calibration") -> F:
    """A joint origin as 4×4 from ``xyz`` (m) and ``roll, pitch, yaw`` (rad), shape
    ``(..., 4, 4)``; ``convention`` one of :data:`CONVENTIONS`."""
    xyz = np.asarray(xyz, dtype=float)
    rpy = np.asarray(rpy, dtype=float)
    Rx, Ry, Rz = rot_x(rpy[..., 0]), rot_y(rpy[..., 1]), rot_z(rpy[..., 2])
    if convention == "ur_calibration":
        R = Rx @ Ry @ Rz
    elif convention == "urdf":
        R = Rz @ Ry @ Rx
    else:
        raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
    T = np.zeros((*xyz.shape[:-1], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = xyz
    T[..., 3, 3] = 1.0
    return T


def intrinsic_xyz(R: ArrayLike) -> F:
    """Angles ``(roll, pitch, yaw)`` with ``R = Rx(roll) · Ry(pitch) · Rz(yaw)``, shape
    ``(..., 3)`` (pitch in [−π/2, π/2])."""
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    roll = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    yaw = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


@dataclass(frozen=True)
class UrKinematics:
    """The ``kinematics`` block: origin of each joint (m, rad, URDF convention) and the hash.

    Attributes
    ----------
    xyz : ndarray, shape (6, 3), m
    rpy : ndarray, shape (6, 3), rad — roll, pitch, yaw: ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``
    hash : str — the controller's calibration checksum (``calib_…``) or this tool's stamp
    """

    xyz: F
    rpy: F
    hash: str = ""

    def origins(self, convention: str = "ur_calibration") -> F:
        """The six joint origins ``O_i``, shape (6, 4, 4) (angles read per ``convention``)."""
        return origin_transform(self.xyz, self.rpy, convention)

    def links(self, convention: str = "ur_calibration") -> F:
        """The constant link transforms of a :class:`RobotModel`: ``C_{i-1} = O_i``, ``C_6 = I``
        (zero joint offsets), shape (7, 4, 4)."""
        return np.concatenate([self.origins(convention), np.eye(4)[None]], axis=0)


@dataclass(frozen=True)
class KinematicsExport:
    """A robot's kinematics in the calibration layout and what the layout cannot hold.

    ``flange_pos`` (m) / ``flange_rot`` (rad): the part of the last link transform that is not
    a shift along or a turn about joint 6's axis (a tilted or offset flange): the layout ends
    on joint 6's frame, so this part is left out (it belongs to the tool's TCP).
    ``urdf_pos`` (m) / ``urdf_rot`` (rad): the largest flange difference over the joint space
    when the written angles are read the URDF's way instead of ``ur_calibration``'s.
    """

    kinematics: UrKinematics
    flange_pos: float
    flange_rot: float
    urdf_pos: float = 0.0
    urdf_rot: float = 0.0


def _rz_tz(phi: float, s: float) -> F:
    T = np.eye(4)
    T[:3, :3] = rot_z(phi)
    T[2, 3] = s
    return T


def layout(robot: RobotModel) -> F:
    """The joint origins of ``robot`` in the calibration layout's frame convention, shape
    (6, 4, 4): from a standard DH table as ``ur_calibration`` builds them (``O_1 = Rz(θ1) ·
    Tz(d1)``, ``O_i = Tx(a_{i-1}) · Rx(α_{i-1}) · Rz(θ_i) · Tz(d_i)``: each joint's frame sits
    where the DH offset ``d_i`` along its axis ends), otherwise the robot's own joint frames
    (``O_i = C_{i-1} · Rz(o_i)``, e.g. a model read from a calibration file)."""
    if robot.dh is not None and robot.convention == "dh" and robot.n_joints == 6:
        a, d = np.asarray(robot.dh["a"]), np.asarray(robot.dh["d"])
        alpha, th = np.asarray(robot.dh["alpha"]), np.asarray(robot.dh["theta_offset"])
        O = np.empty((6, 4, 4))
        for i in range(6):
            T = _rz_tz(th[i], d[i])
            if i > 0:
                P = np.eye(4)
                P[:3, :3] = rot_x(alpha[i - 1])
                P[0, 3] = a[i - 1]
                T = P @ T
            O[i] = T
        return O
    O = np.empty((robot.n_joints, 4, 4))
    for i in range(robot.n_joints):
        O[i] = robot.links[i] @ _rz_tz(robot.q_offset[i], 0.0)
    return O


def kinematics_of(robot: RobotModel, reference: RobotModel | None = None) -> KinematicsExport:
    """A 6-joint robot's kinematics as the six joint origins of the calibration layout.

    The forward kinematics are kept exactly; the joint frames are placed like those of
    ``reference`` (default: the robot itself; the nominal robot for a corrected one), so the
    link frames of the URDF, and the meshes and collision models drawn in them, stay where
    ur_description puts them: each joint's frame may slide along and turn about its own axis
    (both commute with the joint's rotation), and is moved to the point and heading nearest
    the reference's at the zero configuration.  The turns are then adjusted (by as much as the
    calibration's small angles) until the written angles mean nearly the same read either way
    (:data:`CONVENTIONS`): the file serves ur_calibration's readers and the URDF alike, the
    difference that remains is reported (``urdf_pos``, ``urdf_rot``).  The last joint's frame
    is put on the flange (the layout ends on ``tool0``); what of the last link transform is
    not a shift along or a turn about joint 6's axis is left out and reported
    (``flange_pos``, ``flange_rot``).  Angles are written in ``ur_calibration``'s convention.

    Raises
    ------
    ValueError
        The robot does not have six joints.
    """
    from scipy.optimize import least_squares

    if robot.n_joints != 6:
        raise ValueError(
            f"robot {robot.name!r} has {robot.n_joints} joints; the UR calibration layout has 6"
        )
    ref = robot if reference is None else reference
    if ref.n_joints != 6:
        raise ValueError(f"reference robot {ref.name!r} does not have 6 joints")
    O_ref = layout(ref)
    F_ref = np.empty((6, 4, 4))
    acc = np.eye(4)
    for i in range(6):
        acc = acc @ O_ref[i]
        F_ref[i] = acc
    _, frames = chain(robot, np.zeros((1, 6)), return_frames=True)
    F = frames[0]  # joint frames after Rz(θ_i) at q = 0
    flange = F[5] @ robot.links[6]
    target = F_ref.copy()
    target[5] = flange
    s_i, phi = np.empty(6), np.empty(6)
    for i in range(6):
        D = np.linalg.inv(F[i]) @ target[i]
        s_i[i], phi[i] = D[2, 3], math.atan2(D[1, 0], D[0, 0])

    def origins(extra: F) -> F:
        turn = phi + np.append(extra, 0.0)  # the last frame stays on the flange
        Fp = np.stack([F[i] @ _rz_tz(turn[i], s_i[i]) for i in range(6)])
        O = np.empty((6, 4, 4))
        O[0] = Fp[0]
        O[1:] = np.linalg.inv(Fp[:-1]) @ Fp[1:]
        return O

    q_s = np.random.default_rng(1).uniform(-np.pi, np.pi, (32, 6))

    def mismatch(extra: F) -> F:
        """Flange difference between the two readings (m; rad × 0.1 m), at 32 configurations."""
        O = origins(extra)
        kin = UrKinematics(xyz=O[:, :3, 3], rpy=intrinsic_xyz(O[:, :3, :3]))
        A, B = _fk(kin.links("ur_calibration"), q_s), _fk(kin.links("urdf"), q_s)
        rot = log_so3(np.swapaxes(B[:, :3, :3], -1, -2) @ A[:, :3, :3])
        return np.concatenate(
            [(A[:, :3, 3] - B[:, :3, 3]).ravel(), 0.1 * rot.ravel(), 1e-6 * extra]
        )

    sol = least_squares(mismatch, np.zeros(5), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    c0, c1 = float(np.sum(mismatch(np.zeros(5)) ** 2)), float(np.sum(sol.fun**2))
    # frames that are already the best stay as they are: writing a file read back gives it again
    extra = sol.x if c0 - c1 > max(1e-6 * c0, 1e-24) else np.zeros(5)
    O = origins(extra)
    Fp5 = np.linalg.multi_dot(list(O))
    rest = np.linalg.inv(Fp5) @ flange  # identity for every UR arm's DH table
    kin = UrKinematics(xyz=O[:, :3, 3].copy(), rpy=intrinsic_xyz(O[:, :3, :3]))
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (256, 6))
    T_cal = _fk(kin.links("ur_calibration"), q)
    T_urdf = _fk(kin.links("urdf"), q)
    return KinematicsExport(
        kinematics=kin,
        flange_pos=float(np.linalg.norm(rest[:3, 3])),
        flange_rot=float(np.linalg.norm(log_so3(rest[:3, :3]))),
        urdf_pos=float(np.linalg.norm(T_cal[:, :3, 3] - T_urdf[:, :3, 3], axis=1).max()),
        urdf_rot=float(
            np.linalg.norm(
                log_so3(np.swapaxes(T_urdf[:, :3, :3], -1, -2) @ T_cal[:, :3, :3]), axis=1
            ).max()
        ),
    )


def _fk(links: F, q: F) -> F:
    """Flange poses of the zero-offset chain ``links`` at joints ``q`` (n, 6)."""
    n = q.shape[0]
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    Rz = np.zeros((n, 6, 4, 4))
    Rz[..., :3, :3] = rot_z(q)
    Rz[..., 2, 2] = 1.0
    Rz[..., 3, 3] = 1.0
    for i in range(6):
        T = T @ links[i] @ Rz[:, i]
    return T @ links[6]


def convention_difference(kin: UrKinematics, n: int = 256) -> tuple[float, float]:
    """Largest flange difference (m, rad) over ``n`` joint configurations between reading
    ``kin``'s angles as ``ur_calibration`` writes them and as the URDF reads them."""
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (n, 6))
    A, B = _fk(kin.links("ur_calibration"), q), _fk(kin.links("urdf"), q)
    dp = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1).max()
    dr = np.linalg.norm(log_so3(np.swapaxes(B[:, :3, :3], -1, -2) @ A[:, :3, :3]), axis=1).max()
    return float(dp), float(dr)


def _num(v: float) -> str:
    """A float that reads back bit for bit, always as a YAML float (``1e-05`` would be a string
    to YAML 1.1 readers such as PyYAML: the mantissa gets a dot)."""
    v = float(v)
    if v == 0.0:
        return "0.0"
    s = repr(v)
    mant, e, exp = s.partition("e")
    if e and "." not in mant:
        s = f"{mant}.0e{exp}"
    return s


def kinematics_hash(kin: UrKinematics) -> str:
    """This tool's stamp for the ``hash`` field: ``quickhealth_`` and 16 hex digits of the
    SHA-256 of the 36 numbers (the controller's own ``calib_…`` checksum cannot be computed
    from the kinematics; the driver will report that the file differs from the robot's)."""
    body = ",".join(_num(v) for v in np.concatenate([kin.xyz, kin.rpy], axis=1).ravel())
    return "quickhealth_" + hashlib.sha256(body.encode("ascii")).hexdigest()[:16]


def kinematics_yaml(kin: UrKinematics, comments: Sequence[str] = ()) -> str:
    """The ``kinematics`` YAML (the layout ``ur_calibration`` writes); ``comments`` become
    ``#`` lines on top.  Numbers are written to read back exactly."""
    head = "".join("# " + " ".join(str(c).split()) + "\n" for c in comments)
    lines = [head + "kinematics:"]
    for i, seg in enumerate(SEGMENTS):
        lines.append(f"  {seg}:")
        vals = (*kin.xyz[i], *kin.rpy[i])
        lines += [f"    {k}: {_num(v)}" for k, v in zip(KEYS, vals, strict=True)]
    h = kin.hash or kinematics_hash(kin)
    lines.append(f"  hash: {h}")
    return "\n".join(lines) + "\n"
