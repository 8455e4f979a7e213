"""The simulated cell's ground truth: where the robot base, the smart-target mount and the
reference marker board really are, and the arm's true kinematics (the digital twin).

Used by the controller simulator (``truth``: joints → true ``T_instr_flange``) and by the
simulated cameras (``T_instr_target`` = truth · mount · pan).  Real hardware never imports it.

The instrument frame is the left camera's frame (x right, y down, z along the optical axis).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.robot import RobotModel, ur5
from quickhealth.identify.transforms import exp_so3, inv_T, make_T

F = NDArray[np.float64]


def look_at(eye: F, target: F, up: F | None = None) -> F:
    """``T_base_cam`` of a camera at ``eye`` looking at ``target`` (x right, y down, z forward)."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), np.asarray(eye, float))


@dataclass(frozen=True, eq=False)
class CellGeometry:
    """Nominal geometry of the measurement cell (SI).

    Attributes
    ----------
    T_instr_base : ndarray (4, 4)
        Robot base in the instrument (left camera) frame.
    T_flange_mount : ndarray (4, 4)
        Pan-motor mount on the flange; the target turns about the target's pan axis there.
    T_instr_board : ndarray (4, 4)
        Fixed reference marker board (instrument self-check) in the instrument frame.
    """

    T_instr_base: F
    T_flange_mount: F
    T_instr_board: F


def reference_geometry() -> CellGeometry:
    """The paper's set-up: UR5 on a table, stereo camera ≈ 2 m in front, board beside the arm."""
    T_base_cam = look_at(np.array([2.0, 0.0, 0.55]), np.array([0.35, 0.0, 0.35]))
    T_instr_base = inv_T(T_base_cam)
    # Mount: 60 mm out along the flange axis; target y (its pan axis) along the flange z axis,
    # target normal (z) along flange -x at pan = 0.
    R = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # columns: target axes
    R = R @ exp_so3(np.array([-np.pi / 2, 0.0, 0.0]))
    T_flange_mount = make_T(R, np.array([0.0, 0.0, 0.06]))
    # Board: 0.5 m beside the robot on the table, facing the camera.
    p = np.array([0.6, 0.75, 0.1])
    T_base_board = look_at(np.array([2.0, 0.0, 0.55]), p)  # same orientation as a camera…
    T_base_board[:3, :3] = T_base_board[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # …facing back
    T_base_board[:3, 3] = p
    return CellGeometry(T_instr_base, T_flange_mount, T_instr_base @ T_base_board)


Truth = Callable[[F], F]


def nominal_truth(robot: RobotModel, geometry: CellGeometry) -> Truth:
    """``q -> T_instr_flange`` of the nominal arm (no robot error)."""

    def truth(q: F) -> F:
        return geometry.T_instr_base @ robot.fk(np.asarray(q, dtype=float))

    return truth


def load_truth(twin: str = "default", cell: str = "reference") -> Truth:
    """The arm's true ``q -> T_instr_flange``: the digital twin, or ``"none"`` for nominal.

    The digital twin (``quickhealth.identify.twin``) is used when it is installed; without it
    the arm is nominal, which keeps the station usable while the twin is developed.
    """
    geometry = reference_geometry() if cell == "reference" else reference_geometry()
    robot = ur5()
    if twin == "none":
        return nominal_truth(robot, geometry)
    try:
        from quickhealth.identify import twin as twin_mod  # noqa: F401
    except ImportError:
        return nominal_truth(robot, geometry)
    return _twin_truth(twin_mod, robot, geometry, twin)


def _twin_truth(twin_mod: object, robot: RobotModel, geometry: CellGeometry, name: str) -> Truth:
    """Adapter to the digital twin module (kept in one place so the swap is one line)."""
    make = getattr(twin_mod, "reference_twin", None) or getattr(twin_mod, "default_twin", None)
    if make is None:
        return nominal_truth(robot, geometry)
    tw = make()
    fk = getattr(tw, "T_base_flange", None) or getattr(tw, "fk", None)
    if fk is None:
        return nominal_truth(robot, geometry)

    def truth(q: F) -> F:
        return geometry.T_instr_base @ np.asarray(fk(np.asarray(q, dtype=float)))

    return truth
