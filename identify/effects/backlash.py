"""Backlash of one joint: ``backlash:jK``.

Physics
-------
Play in a gear train: the output lags the motor by half the play, on the side it was driven
from.  A joint last moved in the positive direction sits ``b/2`` short of where it sits when
approached from the negative side, so its angle is shifted by

    dq_K = (b / 2) · approach_K,          approach_K ∈ {+1, −1}

``b`` (rad) is the full play (sign included: which side the load pushes it to).  The approach
direction comes from the execution order (CSV v1: the previous row).  A joint-angle polynomial
cannot express it: the same reading gives two angles.  Regressor for plots: the approach
direction (+1 / −1).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..measurements import Measurements
from ..robot import RobotModel
from . import CheckFamily, EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F, joint_dq, joint_index


@dataclass(frozen=True, eq=False)
class Backlash(EffectBase):
    """Joint ``joint`` (0-based) shifts by ``± b/2`` with its approach direction."""

    joint: int
    name: str
    param_names: tuple[str, ...] = ("b",)
    param_units: tuple[str, ...] = ("rad",)
    prior_sigma: F = field(default_factory=lambda: np.array([2e-3]))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self, "regressor_name", f"approach direction of joint {self.joint + 1} (±1)"
            )

    @property
    def n_params(self) -> int:
        """One play."""
        return 1

    def regressor(self, ctx: EffectContext) -> F:
        """Approach direction of the joint, +1 / −1, shape (n,)."""
        return np.asarray(ctx.approach[:, self.joint], dtype=float)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = (b/2) · approach_K``."""
        v = 0.5 * params[0] * self.regressor(ctx)
        return Perturbation(dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, v))

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joint K's own higher orders: under a random execution order the approach direction
        correlates with q_K (a high reading was most likely approached from below), so an
        order search that stopped early would otherwise show up as backlash."""
        return (self.joint,)

    @property
    def check_family(self) -> CheckFamily:
        """The quick check's ``backlash`` family; its size is the TCP jump between the two
        approach directions, which no set-up change takes up."""
        return CheckFamily("backlash", jump=True)

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """By the direction the program moves the joint into each target."""
        return (
            f"{self.name} by the direction joint {self.joint + 1} moves into each target "
            "(the program's own order)"
        )

    def correction_notes(self, params: F, q_program: F) -> list[str]:
        """The first target's approach rule, and moves smaller than the play."""
        k = self.joint
        out = [
            f"note: {self.name}: the first target counts as reached with joint {k + 1} "
            "moving in the positive direction (the fit's rule for a first pose); make the "
            "move into it do so"
        ]
        step = np.abs(np.diff(q_program[:, k], prepend=q_program[0, k]))[1:]
        small = np.flatnonzero(step < abs(float(params[0])))
        if small.size:
            shown = ", ".join(str(int(i) + 2) for i in small[:8]) + (" …" if small.size > 8 else "")
            out.append(
                f"note: joint {k + 1} moves less than its play "
                f"({np.degrees(abs(float(params[0]))):.4g} deg) into target(s) {shown}: the side "
                f"its gear rests on there is uncertain; {self.name} assumes the direction of "
                "the move"
            )
        return out


def _propose(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """Every joint the data approach from both sides."""
    app = meas.approach_sign()
    return [f"backlash:j{k + 1}" for k in range(robot.n_joints) if np.unique(app[:, k]).size > 1]


@register(
    r"backlash:j(\d+)",
    "backlash:jK",
    requires=("approach",),
    propose=_propose,
    check=("backlash", lambda robot: [f"backlash:j{k + 1}" for k in range(robot.n_joints)]),
    twin=TwinSize("deg", np.pi / 180.0),
    example="backlash:j3=0.0229",
)
def _make(m: re.Match[str], robot: RobotModel) -> Backlash:
    j = joint_index(m.group(1), robot, m.group(0))
    return Backlash(joint=j, name=f"backlash:j{j + 1}")
