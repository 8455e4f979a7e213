"""What the simulated controller knows of its arm: its factory calibration, limits and checks.

A real UR controller does not compute with the published DH table: it computes TCP poses,
inverse kinematics and straight lines with its own per-robot factory calibration, which
differs from nominal by up to millimetres (and the real arm differs from both: the digital
twin is the truth here, :mod:`.world`).  :func:`factory_calibration` makes such a
calibration for a simulated robot, reproducibly from a seed; :func:`calibration_from_yaml`
takes it from the UR ROS driver's calibration YAML (:mod:`quickhealth.identify.ur_calibration`
describes and writes that file: ``quickhealth ur-calibration``).

:class:`JointLimits` are the arm's hardware limits (UR's published joint ranges and speeds,
:data:`quickhealth.identify.robot.UR_ARMS`), not a cell's narrower planning limits.
:func:`check_joint_move` and :func:`check_path` say why the controller refuses a motion (a
protective stop on a real one), or None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.robot import UR_ARMS, Nominal, RobotModel, with_kinematics
from ...identify.transforms import exp_so3, make_T, rot_z
from ..formats import read_ur_calibration
from .arm import MAX_JOINT_STEP, Path

F = NDArray[np.float64]

CALIBRATION_SIGMA_M = 4e-4  # m, per link translation delta of a simulated factory calibration
CALIBRATION_SIGMA_RAD = 4e-4  # rad, per link rotation delta
REACH_TOL_M = 1e-6  # a planned line whose samples miss their poses by more is unreachable


@dataclass(frozen=True)
class JointLimits:
    """Hardware joint limits: positions (rad), speeds (rad/s), accelerations (rad/s²)."""

    q_min: F
    q_max: F
    qd_max: F
    qdd_max: F

    @classmethod
    def of(cls, robot: RobotModel) -> JointLimits:
        """The limits of the UR arm ``robot`` is (by name; its published table), else the
        model's own, with UR5 speeds where the model has none."""
        base = UR_ARMS[robot.name].robot() if robot.name in UR_ARMS else robot
        qd = base.qd_max if base.qd_max is not None else np.full(robot.n_joints, math.pi)
        qdd = base.qdd_max if base.qdd_max is not None else np.full(robot.n_joints, 40.0)
        return cls(
            np.asarray(base.q_min, float),
            np.asarray(base.q_max, float),
            np.asarray(qd, float),
            np.asarray(qdd, float),
        )

    def outside(self, q: np.ndarray) -> int | None:
        """Index of the first joint of ``q`` (n,) or any row of ``q`` (m, n) outside its
        range, or None."""
        q = np.atleast_2d(q)
        bad = np.any((q < self.q_min - 1e-9) | (q > self.q_max + 1e-9), axis=0)
        return int(np.argmax(bad)) if np.any(bad) else None


def factory_calibration(robot: RobotModel, seed: int) -> RobotModel:
    """``robot`` with a simulated factory calibration: the base and each joint's origin moved
    by a small random rigid delta (σ 0.4 mm, 0.4 mrad), reproducible from ``seed``.  The TCP
    it computes differs from nominal by about a millimetre over the workspace.  The flange
    stays on the last joint as nominal, so the UR ROS driver's calibration YAML (six joint
    origins) describes the calibration exactly."""
    rng = np.random.default_rng(int(seed) + 7919)
    links = np.array(robot.links, dtype=float)
    for i in range(links.shape[0] - 1):
        dT = make_T(
            exp_so3(rng.normal(0.0, CALIBRATION_SIGMA_RAD, 3)),
            rng.normal(0.0, CALIBRATION_SIGMA_M, 3),
        )
        links[i] = links[i] @ dT
    # Joint offsets folded into the links: the calibrated chain has zero offsets.
    for i, off in enumerate(robot.q_offset):
        if off:
            R = np.eye(4)
            R[:3, :3] = rot_z(float(off))
            links[i] = links[i] @ R
    nominal = Nominal(robot.name, calibration=f"simulated factory calibration (seed {seed})")
    return with_kinematics(robot, links, name=robot.name, nominal=nominal)


def calibration_from_yaml(robot: RobotModel, path: str) -> RobotModel:
    """``robot`` with the kinematics of a UR ROS driver calibration YAML (``ur_calibration``).

    Raises
    ------
    InputError
        The file is not such a YAML (one line naming it).
    """
    kin, sha = read_ur_calibration(path)
    nominal = Nominal(robot.name, calibration=str(path), calibration_sha256=sha)
    return with_kinematics(robot, kin.links(), name=robot.name, nominal=nominal)


def calibration_offset(nominal: RobotModel, calibrated: RobotModel, n: int = 64) -> float:
    """Largest flange position difference (m) between two kinematics over random joints."""
    rng = np.random.default_rng(0)
    q = rng.uniform(-math.pi, math.pi, (n, nominal.n_joints))
    return float(
        np.max(np.linalg.norm(nominal.fk(q)[:, :3, 3] - calibrated.fk(q)[:, :3, 3], axis=1))
    )


def check_joint_move(
    limits: JointLimits, q0: np.ndarray, q1: np.ndarray, speed: float, accel: float
) -> str | None:
    """Why a synchronised joint move (leading-joint ``speed`` rad/s, ``accel`` rad/s²) breaks
    the limits, or None.  Each joint moves at its share of the leading joint's speed."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    j = limits.outside(q1)
    if j is not None:
        return (
            f"joint position limit: joint {j + 1} target {math.degrees(q1[j]):.1f} deg outside "
            f"{math.degrees(limits.q_min[j]):.0f}..{math.degrees(limits.q_max[j]):.0f} deg"
        )
    d = np.abs(q1 - q0)
    lead = float(np.max(d)) if d.size else 0.0
    if lead <= 0.0:
        return None
    share = d / lead
    v = share * speed
    a = share * accel
    j = int(np.argmax(v / limits.qd_max))
    if v[j] > limits.qd_max[j] * (1 + 1e-9):
        return (
            f"joint speed limit: joint {j + 1} would move at {math.degrees(v[j]):.0f} deg/s, "
            f"limit {math.degrees(limits.qd_max[j]):.0f} deg/s"
        )
    j = int(np.argmax(a / limits.qdd_max))
    if a[j] > limits.qdd_max[j] * (1 + 1e-9):
        return (
            f"joint acceleration limit: joint {j + 1} {a[j]:.1f} rad/s^2, "
            f"limit {limits.qdd_max[j]:.1f} rad/s^2"
        )
    return None


def check_path(
    robot: RobotModel,
    tcp: np.ndarray,
    limits: JointLimits,
    path: Path,
    T_goal: np.ndarray,
    speed: float,
    accel: float,
) -> str | None:
    """Why a planned straight line cannot be run, or None.

    Unreachable (the last sample is not at ``T_goal``, or a sample jumps like a branch
    switch), outside the joint ranges, or faster than a joint may turn at the line's cruise
    ``speed`` (m/s) and ``accel`` (m/s²)."""
    q = path.q
    T_end = robot.fk(q[-1]) @ tcp
    miss = float(np.linalg.norm(T_end[:3, 3] - T_goal[:3, 3]))
    R = T_end[:3, :3].T @ T_goal[:3, :3]
    miss_rot = math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0)))
    if miss > REACH_TOL_M or miss_rot > REACH_TOL_M:
        return (
            f"inverse kinematics: the target pose is out of reach "
            f"(the line ends {miss * 1e3:.1f} mm from it)"
        )
    steps = np.abs(np.diff(q, axis=0))
    if steps.size and float(np.max(steps)) > 2 * MAX_JOINT_STEP:
        return "inverse kinematics: the line passes a singularity (joint flip)"
    j = limits.outside(q)
    if j is not None:
        return f"joint position limit: joint {j + 1} leaves its range along the line"
    m = q.shape[0]
    if m > 1 and path.distance > 0:
        ds = path.distance / (m - 1)
        v = np.max(steps, axis=0) / ds * speed  # rad/s at the cruise speed
        j = int(np.argmax(v / limits.qd_max))
        if v[j] > limits.qd_max[j] * (1 + 1e-9):
            return (
                f"joint speed limit: joint {j + 1} would turn at {math.degrees(v[j]):.0f} deg/s "
                f"on this line, limit {math.degrees(limits.qd_max[j]):.0f} deg/s"
            )
    return None
