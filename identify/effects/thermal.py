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
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..robot import RobotModel
from . import EffectContext, Perturbation, register
from ._base import F

#: The temperature (°C) the link lengths refer to: the thermal effect's zero and the reference
#: condition of the workspace map (:func:`~quickhealth.identify.workspace.reference_conditions`).
T_REF_C = 20.0


@dataclass(frozen=True, eq=False)
class Thermal:
    """Links grow by ``α · (temp − 20 °C)``."""

    name: str = "thermal"
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

    def requires(self) -> tuple[str, ...]:
        """The ``temp`` column."""
        return ("temp",)


@register(r"thermal", "thermal")
def _make(m: re.Match[str], robot: RobotModel) -> Thermal:
    return Thermal()
