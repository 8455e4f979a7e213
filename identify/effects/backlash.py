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
from dataclasses import dataclass, field

import numpy as np

from ..robot import RobotModel
from . import EffectContext, Perturbation, register
from ._base import F, joint_dq, joint_index


@dataclass(frozen=True, eq=False)
class Backlash:
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

    def requires(self) -> tuple[str, ...]:
        """The execution order, which every measurement file has."""
        return ()


@register(r"backlash:j(\d+)", "backlash:jK")
def _make(m: re.Match[str], robot: RobotModel) -> Backlash:
    j = joint_index(m.group(1), robot, m.group(0))
    return Backlash(joint=j, name=f"backlash:j{j + 1}")
