"""A joint's warm-up: ``thermal:jK``.

Physics
-------
A joint's motor, gearbox and brake warm with its duty (a UR reports each joint's temperature
over RTDE, ``joint_temperatures``; CSV v1 ``temp_jK``).  The warm housing expands along the
joint's axis and the gear and encoder seat shift, so the joint's error motions change with
its own temperature, whatever the air around the arm does.  Linear in the rise::

    E_K += Trans(0, 0, a · ΔT_K) · Rz(e · ΔT_K),        ΔT_K = temp_jK − 20 °C

``a`` (m/K) is the joint's axial growth, ``e`` (rad/K) the drift of its angle, both in joint
K's frame (they add to its Chebyshev error motions δz and εz).  A joint's temperature is no
function of its angle, so no joint-angle polynomial expresses it, and it differs from the
ambient ``thermal`` (every link growing with the ``temp`` column): a joint that works warms
while the air stays flat, and the warm joint moves the arm at that joint only.  A constant
offset is a constant error motion, which the geometric model already fits: only the change of
the joint's temperature during the run is seen.  Regressor for plots: ``temp_jK − 20`` (K).
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
from . import T_REF_C, EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F, fitted_estimates, joint_index

#: The joint's two error motions its temperature drives: δz (axial) and εz (angle).
_MOTIONS = (2, 5)


@dataclass(frozen=True, eq=False)
class JointThermal(EffectBase):
    """Joint ``joint`` (0-based) grows ``a`` along its axis and turns ``e`` per kelvin of its
    own temperature rise."""

    joint: int
    name: str
    param_names: tuple[str, ...] = ("a", "e")
    param_units: tuple[str, ...] = ("m/K", "rad/K")
    prior_sigma: F = field(default_factory=lambda: np.array([1e-4, 1e-4]))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self, "regressor_name", f"temperature of joint {self.joint + 1} − 20 °C (K)"
            )

    @property
    def n_params(self) -> int:
        """Axial growth and angle drift."""
        return 2

    def regressor(self, ctx: EffectContext) -> F:
        """``temp_jK − 20`` (K), shape (n,)."""
        if ctx.joint_temp is None:
            raise InputError(
                f"effect {self.name!r} needs the joints' temperatures (temp_j1 … columns) in "
                "the measurements"
            )
        return np.asarray(ctx.joint_temp[:, self.joint], dtype=float) - T_REF_C

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """Joint K's δz and εz grow by ``a·ΔT`` and ``e·ΔT``."""
        dT = self.regressor(ctx)
        jm = np.zeros((ctx.n_poses, ctx.robot.n_joints, 6))
        for m, p in zip(_MOTIONS, params, strict=True):
            jm[:, self.joint, m] = p * dT
        return Perturbation(joint_motion=jm)

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """An axial growth of ``size`` (m/K) and an angle drift of ``size`` / 1 m (rad/K) of
        a random sign."""
        return np.array([size, size * rng.choice([-1.0, 1.0])])

    def correction(self, conditions: Mapping[str, Any]) -> str:
        """At the joint's temperature the program runs at."""
        t = conditions["joint_temp"][self.joint]
        return f"{self.name} at {t:g} °C of joint {self.joint + 1}"

    def describe_fit(self, fitted: Any) -> list[str]:
        """The fit summary's line: the growth and drift per kelvin, in µm and µrad."""
        v, s = fitted_estimates(fitted, self)
        return [
            f"{self.name}: per kelvin of joint {self.joint + 1}'s temperature it grows "
            f"{v[0] * 1e6:.3g} ± {s[0] * 1e6:.2g} µm along its axis and turns "
            f"{v[1] * 1e6:.3g} ± {s[1] * 1e6:.2g} µrad about it (zero at 20 °C)"
        ]


def _propose(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """Every joint whose temperature varies during the run (by more than 0.05 K)."""
    if meas.joint_temp is None:
        return []
    spread = np.ptp(meas.joint_temp, axis=0)
    return [f"thermal:j{k + 1}" for k in range(robot.n_joints) if spread[k] > 0.05]


@register(
    r"thermal:j(\d+)",
    "thermal:jK",
    requires=("joint_temp",),
    propose=_propose,
    twin=TwinSize("mm/K (axial; the angle drift is size / 1 m, rad/K)", 1e-3),
    example="thermal:j2=0.015",
)
def _make(m: re.Match[str], robot: RobotModel) -> JointThermal:
    j = joint_index(m.group(1), robot, m.group(0))
    return JointThermal(joint=j, name=f"thermal:j{j + 1}")
