"""Gravity-load compliance of one joint: ``compliance:jK``.

Physics
-------
A joint's gearbox and bearings are springs: under the static gravity torque ``τ_K`` it carries
(all links beyond it, with their masses and centres of mass) joint K turns by

    dq_K = c · τ_K

``c`` (rad/(N·m)) is the joint's compliance, the inverse of its torsional stiffness (harmonic
drives of arms like the UR5: 1e4 … 1e5 N·m/rad, so c ≈ 1e-5 … 1e-4).  The torque depends on
the *whole* configuration (for the UR5's joint 2 on q2 and q2 + q3 and the wrist), so no
polynomial in one joint angle expresses it.  ``τ_K`` comes from
:func:`quickhealth.identify.robot.gravity_torques` (base z up); the deflection has the sign of
the torque gravity applies.  The regressor, for plots, is ``τ_K`` (N·m).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..robot import RobotModel
from . import EffectContext, Perturbation, register
from ._base import F, joint_dq, joint_index


@dataclass(frozen=True, eq=False)
class Compliance:
    """Joint ``joint`` (0-based) deflects by ``c · τ``."""

    joint: int
    name: str
    param_names: tuple[str, ...] = ("c",)
    param_units: tuple[str, ...] = ("rad/(N·m)",)
    prior_sigma: F = field(default_factory=lambda: np.array([1e-4]))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self, "regressor_name", f"gravity torque of joint {self.joint + 1} (N·m)"
            )

    @property
    def n_params(self) -> int:
        """One compliance."""
        return 1

    def regressor(self, ctx: EffectContext) -> F:
        """Gravity torque of the joint, shape (n,), N·m."""
        if ctx.gravity_torque is None:
            raise InputError(
                f"{self.name} needs link masses and centres of mass; "
                f"robot {ctx.robot.name!r} has none"
            )
        return np.asarray(ctx.gravity_torque[:, self.joint], dtype=float)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = c · τ_K``."""
        tau = self.regressor(ctx)
        return Perturbation(
            dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, params[0] * tau)
        )

    def requires(self) -> tuple[str, ...]:
        """Only joint readings (and the robot's inertial data)."""
        return ()


@register(r"compliance:j(\d+)", "compliance:jK")
def _make(m: re.Match[str], robot: RobotModel) -> Compliance:
    if robot.masses is None or robot.coms is None:
        raise InputError(
            f"effect {m.group(0)!r} needs link masses and centres of mass; "
            f"robot {robot.name!r} has none"
        )
    j = joint_index(m.group(1), robot, m.group(0))
    return Compliance(joint=j, name=f"compliance:j{j + 1}")
