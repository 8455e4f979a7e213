"""Drift of the instrument-to-robot relation with time: ``drift``.

Physics
-------
A tripod settling, a warming camera bar or a creeping base moves the robot base in the
instrument frame slowly during a run.  Over the minutes of an assessment the motion is linear:

    base_twist = ξ · time,     ξ = (vx, vy, vz, wx, wy, wz)

a small motion ``E(δ, ε)`` applied after the base error ``E0``: three translation rates (m/s)
and three rotation rates (rad/s), about the base frame's axes.  Time zero is where the
constant base error is defined (the file's time origin).  Regressor for plots: time (s).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..measurements import Measurements
from ..robot import RobotModel
from . import EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F


@dataclass(frozen=True, eq=False)
class Drift(EffectBase):
    """Base-in-instrument motion linear in time."""

    name: str = "drift"
    joint: int | None = None  # the whole arm
    param_names: tuple[str, ...] = ("vx", "vy", "vz", "wx", "wy", "wz")
    param_units: tuple[str, ...] = ("m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")
    prior_sigma: F = field(default_factory=lambda: np.array([1e-5] * 3 + [1e-5] * 3))
    regressor_name: str = "time (s)"

    @property
    def n_params(self) -> int:
        """Six rates."""
        return 6

    def regressor(self, ctx: EffectContext) -> F:
        """Time (s), shape (n,)."""
        if ctx.time is None:
            raise InputError("effect 'drift' needs a 'time' column in the measurements")
        return np.asarray(ctx.time, dtype=float)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``base_twist = ξ · time``."""
        return Perturbation(base_twist=self.regressor(ctx)[:, None] * params[None, :6])

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """A translation rate ``size`` (m/s) in a random direction and a rotation rate of
        ``size`` / 1 m (rad/s) about a random axis."""
        v = rng.normal(size=3)
        w = rng.normal(size=3)
        return np.concatenate([size * v / np.linalg.norm(v), size * w / np.linalg.norm(w)])

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """At the time the program runs at."""
        return f"{self.name} at {conditions['time']:g} s on the fitted run's clock"


def _propose(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """When the data have a time that varies."""
    return ["drift"] if meas.time is not None and np.ptp(meas.time) > 0 else []


@register(
    r"drift",
    "drift",
    requires=("time",),
    propose=_propose,
    twin=TwinSize("mm/s (and size/1 m rad/s)", 1e-3),
    example="drift=2e-4",
)
def _make(m: re.Match[str], robot: RobotModel) -> Drift:
    return Drift()
