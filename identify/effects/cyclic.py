"""Cyclic (periodic) error of one joint: ``cyclic:jK:hM``.

Physics
-------
Gear tooth-mesh errors, a strain-wave gear's two-per-revolution wave, an eccentric encoder
disc or a worn bearing race repeat M times per joint revolution:

    dq_K = a · sin(M q_K) + b · cos(M q_K)

``a``, ``b`` (rad) are the sine and cosine amplitudes; the amplitude is ``√(a² + b²)``.  With
several cycles over the joint's range no low-order Chebyshev term captures it, and the
paper's one-step order search never gets there (the BIC does not fall on the way); the
diagnosis finds M from the residual spectrum against the joint angle.  Regressor for plots:
the phase ``M q_K`` wrapped to [0, 2π).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..robot import RobotModel
from . import EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F, joint_dq, joint_index


@dataclass(frozen=True, eq=False)
class Cyclic(EffectBase):
    """Joint ``joint`` (0-based) has an error with ``harmonic`` cycles per revolution."""

    joint: int
    harmonic: int
    name: str
    param_names: tuple[str, ...] = ("a_sin", "b_cos")
    param_units: tuple[str, ...] = ("rad", "rad")
    prior_sigma: F = field(default_factory=lambda: np.array([1e-3, 1e-3]))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self,
                "regressor_name",
                f"phase {self.harmonic}·q{self.joint + 1} of joint {self.joint + 1} (rad)",
            )

    @property
    def n_params(self) -> int:
        """Sine and cosine amplitude."""
        return 2

    def regressor(self, ctx: EffectContext) -> F:
        """Phase ``M q_K`` wrapped to [0, 2π), shape (n,)."""
        return np.mod(self.harmonic * ctx.q[:, self.joint], 2 * np.pi)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = a sin(M q_K) + b cos(M q_K)``."""
        ph = self.harmonic * ctx.q[:, self.joint]
        v = params[0] * np.sin(ph) + params[1] * np.cos(ph)
        return Perturbation(dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, v))

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joint K's own higher orders: a low harmonic is a smooth function of q_K."""
        return (self.joint,)

    def spectrum_bin(self) -> tuple[str, int]:
        """Harmonic M of the residual spectrum against joint K's angle."""
        return f"j{self.joint + 1}", self.harmonic

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """Amplitude ``size`` (rad) at a random phase."""
        ph = rng.uniform(0, 2 * np.pi)
        return np.array([size * np.cos(ph), size * np.sin(ph)])

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """By the phase at each target."""
        return f"{self.name} by the phase at each target"


def _propose(robot: RobotModel, meas: object, options: ProposalOptions) -> list[str]:
    """Every joint and harmonic up to ``options.max_harmonic``."""
    nh = options.max_harmonic
    return [f"cyclic:j{k + 1}:h{m}" for k in range(robot.n_joints) for m in range(1, nh + 1)]


@register(
    r"cyclic:j(\d+):h(\d+)",
    "cyclic:jK:hM",
    propose=_propose,
    twin=TwinSize("deg (amplitude)", np.pi / 180.0),
    example="cyclic:j1:h9=0.01146",
)
def _make(m: re.Match[str], robot: RobotModel) -> Cyclic:
    j = joint_index(m.group(1), robot, m.group(0))
    h = int(m.group(2))
    if h < 1:
        raise InputError(f"effect {m.group(0)!r}: the harmonic M must be at least 1")
    return Cyclic(joint=j, harmonic=h, name=f"cyclic:j{j + 1}:h{h}")
