"""The simulated cell's ground truth (``--sim`` only; real hardware never imports it).

What is really where: the robot is the digital twin (:mod:`quickhealth.identify.twin`, with
its true geometric and position-dependent errors), placed in the cell (planning/cell.py) in
front of the stereo rig of the vision reference design; the smart target turns on its pan
motor; the reference marker board of the instrument self-check stands beside the robot.

The instrument frame is the left camera's frame.  The right camera sits where the rig's
calibration puts it (``T_left_right``), so the rendered images agree with the rig the
measurement uses.

SYNOPSIS
    >>> world = build_world("reference", twin_seed=1)
    >>> T = world.T_instr_plate(q, pan=0.3, approach=np.ones(6))
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...identify.effects import CHANNELS, is_effect_name, parse_effect
from ...identify.errors import InputError
from ...identify.robot import RobotModel
from ...identify.transforms import inv_T, make_T
from ...identify.twin import Twin, TwinTruth, effect_params, make_twin, twin_from_truth
from ...vision.boards import TargetDescription
from ...vision.camera import StereoRig
from ...vision.reference import reference_rig
from ..hardware.target import T_target_plate, reference_board, reference_target
from ..planning import load_cell

F = NDArray[np.float64]


# Board frame in world axes: x = +y_world, y = −z_world (down), z = −x_world (into the
# plate, away from the cameras that stand at +x).
_R_WORLD_BOARD = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class SimWorld:
    """Ground truth of the simulated cell (SI)."""

    twin: Twin
    rig: StereoRig
    target: TargetDescription
    board: TargetDescription
    T_world_base: F
    T_world_instr: F  # the left camera
    T_world_board: F

    @property
    def T_instr_world(self) -> F:
        """World (table) in the instrument frame."""
        return inv_T(self.T_world_instr)

    @property
    def T_instr_board(self) -> F:
        """The self-check board in the instrument frame."""
        return self.T_instr_world @ self.T_world_board

    def T_instr_target0(
        self,
        q: ArrayLike,
        approach: ArrayLike | None = None,
        joint_temp: ArrayLike | None = None,
        joint_torque: ArrayLike | None = None,
    ) -> F:
        """True target frame at pan 0 for encoder joints ``q`` (6,), rad, with the joints at
        ``joint_temp`` (°C) carrying ``joint_torque`` (N·m; the arm's true state, which an
        effect hidden in it may depend on)."""
        q = np.asarray(q, dtype=float).reshape(1, -1)

        def row(v: ArrayLike | None) -> F | None:
            return None if v is None else np.asarray(v, dtype=float).reshape(1, -1)

        return self.twin.true_pose(
            q,
            approach=row(approach),
            joint_temp=row(joint_temp),
            joint_torque=row(joint_torque),
        )[0]

    def T_instr_plate(
        self,
        q: ArrayLike,
        pan: float,
        approach: ArrayLike | None = None,
        joint_temp: ArrayLike | None = None,
        joint_torque: ArrayLike | None = None,
    ) -> F:
        """True pose of the printed plate (what the cameras see) with the motor at ``pan`` rad."""
        T0 = self.T_instr_target0(q, approach, joint_temp, joint_torque)
        return T0 @ T_target_plate(pan)


def parse_degradation(text: str | None) -> dict[str, float]:
    """``"j2.ex.c0=5e-4,compliance:j2=2e-5"`` → ``{"j2.ex.c0": 5e-4, ...}`` (SI: m, rad, or
    an effect's size as :func:`~quickhealth.identify.twin.effect_params` reads it)."""
    out: dict[str, float] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        label, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[label.strip()] = float(value)
        except ValueError:
            raise InputError(
                f"degradation {item.strip()!r}: expected LABEL=VALUE such as j2.ex.c0=5e-4 (m or rad)"
            ) from None
    return out


def degrade_truth(
    truth: TwinTruth, changes: Mapping[str, float], robot: RobotModel | None = None
) -> TwinTruth:
    """The same twin with some true Chebyshev coefficients changed (wear, a crash, a repair),
    or a physical effect hidden in it.

    ``changes`` maps coefficient labels (``j2.ex.c0``: joint 2, tilt about x, order 0) to the
    amount added, in m or rad, and effect names (``compliance:j2``, ``backlash:j3``: any name
    with a colon) to the effect's size (:func:`~quickhealth.identify.twin.effect_params`: a
    compliance in rad/(N·m), a backlash play in rad), which needs the twin's ``robot``.  The
    simulated cell uses it for "a month later" runs and for effects a run must find.
    Effects that need a channel the simulated arm does not give its true pose
    (:data:`SIM_CHANNELS`: the time or the air's temperature, as ``thermal`` and ``drift``
    do) or belong to the camera (``depthscale``, an instrument effect) are refused: the
    images are rendered.  An effect of the joints' temperatures or torques (``thermal:j2``,
    ``compliance:j2:torque``) acts at the controller's joint temperatures and the torques the
    real arm carries.
    """
    labels = truth.spec.labels()
    coeffs = truth.coeffs.copy()
    effects = dict(truth.effects)
    for label, delta in changes.items():
        if is_effect_name(label):
            effects.update(_hidden_effect(label, delta, robot, truth.seed))
            continue
        if label not in labels:
            raise InputError(
                f"degradation {label!r}: not a coefficient of the twin's error model "
                f"(e.g. {labels[0]}, j2.ex.c0) nor an effect (compliance:j2, backlash:j3)"
            )
        coeffs[labels.index(label)] += float(delta)
    return replace(truth, coeffs=coeffs, effects=effects)


#: The channels the simulated arm gives its true pose (:data:`~quickhealth.identify.effects.
#: CHANNELS`): the approach directions, each joint's temperature and the torque it carries
#: (the controller's thermal model and dynamics); an effect that needs another cannot be
#: hidden in it.
SIM_CHANNELS = frozenset({"approach", "joint_temp", "joint_torque"})


def _hidden_effect(
    name: str, size: float, robot: RobotModel | None, seed: int
) -> dict[str, list[float]]:
    """``{effect name: true parameters}`` of an effect hidden in the simulated arm."""
    if robot is None:
        raise InputError(f"degradation {name!r}: a hidden effect needs the twin's robot")
    e = parse_effect(name, robot)
    if e.instrument:
        raise InputError(
            f"degradation {name!r}: the simulated arm hides arm effects only: {e.name} is the "
            "instrument's, and the camera is rendered"
        )
    lacking = sorted(set(e.requires()) - SIM_CHANNELS)
    if lacking:
        raise InputError(
            f"degradation {name!r}: the simulated arm has no clock or temperature of the air, "
            f"and {e.name} needs the {', '.join(CHANNELS[c].words for c in lacking)}"
        )
    return {e.name: list(map(float, effect_params(e, size, np.random.default_rng(seed))))}


def build_world(
    cell: str = "reference", *, twin_seed: int = 1, degrade: Mapping[str, float] | None = None
) -> SimWorld:
    """The simulated cell for a cell name or file, with a twin drawn from ``twin_seed``.

    ``degrade`` changes the twin's true error coefficients or hides an effect in it (see
    :func:`degrade_truth`).  The twin's robot is the cell's arm carrying the cell's smart
    target (``[target] mass_kg``), so a hidden compliance bends under both.
    """
    c = load_cell(cell)
    rig = reference_rig()
    T_world_instr = c.T_world_cam_left
    robot = c.robot_with_target()  # the arm carrying the smart target (gravity compliance)
    twin = make_twin(
        robot,
        seed=twin_seed,
        T_instr_base=inv_T(T_world_instr) @ c.T_world_base,
        T_flange_target=c.T_flange_target,
    )
    if degrade:
        twin = twin_from_truth(degrade_truth(twin.truth, degrade, robot), robot)
    board_center = _board_center(c)
    T_world_board = make_T(_R_WORLD_BOARD, board_center)
    return SimWorld(
        twin=twin,
        rig=rig,
        target=reference_target(),
        board=reference_board(),
        T_world_base=c.T_world_base,
        T_world_instr=T_world_instr,
        T_world_board=T_world_board,
    )


def _board_center(cell: object) -> F:
    """Face of the cell's ``reference board`` obstacle towards the cameras (world, m)."""
    for o in getattr(cell, "obstacles", ()):
        if "board" in o.name and o.size is not None:
            T = o.T_world_obstacle
            return T[:3, 3] + T[:3, :3] @ np.array([o.size[0] / 2 + 0.001, 0.0, 0.0])
    return np.array([0.711, -0.52, 0.16])
