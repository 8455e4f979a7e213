"""Thermal growth of the links: ``thermal``.

Physics
-------
Aluminium links lengthen with temperature (α ≈ 2.3e-5 /K for the alloy; the effective value
of a whole arm, with steel shafts and warm motors, differs).  Every translation of the
nominal link transforms grows by the same fraction

    link_scale = α · (temp − 20 °C)

``α`` (1/K) is identified from the ``temp`` column.  A constant temperature offset is the same
as a constant link-length error, which the geometric model already fits: only the temperature
*change* during the run is seen.  Regressor for plots: ``temp − 20`` (K).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..measurements import Measurements
from ..robot import RobotModel
from . import T_REF_C, EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F


@dataclass(frozen=True, eq=False)
class Thermal(EffectBase):
    """Links grow by ``α · (temp − 20 °C)``."""

    name: str = "thermal"
    joint: int | None = None  # the whole arm
    param_names: tuple[str, ...] = ("alpha",)
    param_units: tuple[str, ...] = ("1/K",)
    prior_sigma: F = field(default_factory=lambda: np.array([1e-4]))
    regressor_name: str = "temperature − 20 °C (K)"

    @property
    def n_params(self) -> int:
        """One expansion coefficient."""
        return 1

    def regressor(self, ctx: EffectContext) -> F:
        """``temp − 20`` (K), shape (n,)."""
        if ctx.temp is None:
            raise InputError("effect 'thermal' needs a 'temp' column in the measurements")
        return np.asarray(ctx.temp, dtype=float) - T_REF_C

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``link_scale = α · (temp − 20)``."""
        return Perturbation(link_scale=params[0] * self.regressor(ctx))

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """At the temperature the program runs at."""
        return f"{self.name} at {conditions['temp']:g} °C"


def _propose(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """When the temperature varies: a constant offset looks like a link-length error."""
    return ["thermal"] if meas.temp is not None and np.ptp(meas.temp) > 0.05 else []


@register(
    r"thermal",
    "thermal",
    requires=("temp",),
    propose=_propose,
    twin=TwinSize("1/K", 1.0),
    example="thermal=5e-5",
)
def _make(m: re.Match[str], robot: RobotModel) -> Thermal:
    return Thermal()
