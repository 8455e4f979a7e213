"""Compliance of one joint driven by its measured torque: ``compliance:jK:torque``.

Physics
-------
The same spring as ``compliance:jK`` (a joint's gearbox, bearings or cables turn under the
torque they carry), with the torque the controller *measures* on the joint (CSV v1 ``tau_jK``:
the torque the joint's drive exerts, or its motor current times the joint's torque constant)
instead of a torque computed from link masses::

    dq_K = −c · τ_K,measured

At rest the drive holds the load: ``τ_K,measured = −τ_K,gravity``, so ``dq_K = c · τ_gravity``
and ``c`` (rad/(N·m)) means what it means in the mass form.  No masses are needed, and the
measured torque follows the real payload: a gripper that picks a part between two poses, a
probe or cable the robot model does not know.  A torque constant that is off by a factor on
joint K only rescales ``c``.  Regressor for plots: the torque joint K carries as measured,
``−τ_K,measured`` (N·m).

It is one physical effect with the other forms of ``compliance:jK`` (a model holds one of
them); diagnose tests it where the data have the torques.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..measurements import Measurements
from ..robot import RobotModel
from . import EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F, fitted_estimates, joint_dq, joint_index


@dataclass(frozen=True, eq=False)
class TorqueCompliance(EffectBase):
    """Joint ``joint`` (0-based) deflects by ``−c · τ_measured``."""

    joint: int
    name: str
    param_names: tuple[str, ...] = ("c",)
    param_units: tuple[str, ...] = ("rad/(N·m)",)
    prior_sigma: F = field(default_factory=lambda: np.array([1e-4]))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self,
                "regressor_name",
                f"torque joint {self.joint + 1} carries, as measured (N·m)",
            )

    @property
    def n_params(self) -> int:
        """One compliance."""
        return 1

    @property
    def physical(self) -> str:
        """A form of ``compliance:jK``."""
        return f"compliance:j{self.joint + 1}"

    @property
    def form(self) -> str:
        """The measured-torque form."""
        return "torque"

    def regressor(self, ctx: EffectContext) -> F:
        """``−τ_K,measured`` (N·m), shape (n,): the load the joint carries."""
        if ctx.joint_torque is None:
            raise InputError(
                f"effect {self.name!r} needs the joints' measured torques (tau_j1 … columns) "
                "in the measurements"
            )
        return -np.asarray(ctx.joint_torque[:, self.joint], dtype=float)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = −c · τ_K,measured``."""
        dq = params[0] * self.regressor(ctx)
        return Perturbation(dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, dq))

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joints K and K+1, as the other forms: what remains beyond their smooth errors is
        the load's dependence on the whole configuration and on the payload."""
        return tuple(j for j in (self.joint, self.joint + 1) if j < n_joints)

    def correction(self, conditions: Mapping[str, Any]) -> str:
        """By the torque the program's targets will load the joint with."""
        return f"{self.name} by {conditions['joint_torque']} at each target"

    def describe_fit(self, fitted: Any) -> list[str]:
        """The fit summary's line: the form and the estimate."""
        v, s = fitted_estimates(fitted, self)
        return [
            f"{self.name}: torque form (joint {self.joint + 1}'s measured torque, payload "
            f"included; no masses used): c = {v[0]:.3g} ± {s[0]:.2g} rad/(N·m)"
        ]


def _propose(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """Every joint whose measured torque varies during the run."""
    if meas.joint_torque is None:
        return []
    spread = np.ptp(meas.joint_torque, axis=0)
    return [f"compliance:j{k + 1}:torque" for k in range(robot.n_joints) if spread[k] > 1e-6]


@register(
    r"compliance:j(\d+):torque",
    "compliance:jK:torque",
    requires=("joint_torque",),
    propose=_propose,
    twin=TwinSize("deg/(N·m)", np.pi / 180.0),
    example="compliance:j2:torque=0.00143",
)
def _make(m: re.Match[str], robot: RobotModel) -> TorqueCompliance:
    j = joint_index(m.group(1), robot, m.group(0))
    return TorqueCompliance(joint=j, name=f"compliance:j{j + 1}:torque")
