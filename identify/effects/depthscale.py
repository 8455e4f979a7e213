"""Depth-scale error of the instrument: ``depthscale``.

Physics
-------
A stereo camera measures depth by triangulation, ``Z = f · B / disparity``: an error in the
focal length f (or the baseline B) scales every depth by the same factor, while x and y
(perpendicular to the optical axis) follow ``X = Z · u / f`` and stay almost right.  The
measured point is

    p_measured = diag(1, 1, 1 + s) · p_true        (instrument frame, z = optical axis)

``s`` (dimensionless) is the fractional depth-scale error.  It is not a uniform scale
(``uniformscale``), which scaling every link, the base and the tool would imitate exactly;
with the camera ~2 m away it looks mostly like a base shift along the optical axis plus a
stretch of the work volume's depth, which the geometric model cannot imitate.  Regressor
for plots: the pose's depth (instrument z, m) — the diagnosis supplies it from the model; the
effect alone (``regressor``) returns ones, the factor its parameter multiplies.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..robot import RobotModel
from . import EffectContext, NotIdentifiable, Perturbation, TwinSize, register
from ._base import EffectBase, F

UNIFORM_SCALE_EXPLANATION = (
    "a uniform instrument scale is indistinguishable from scaling every link length, the "
    "tool and the base, which the geometric (Chebyshev order 0) model already fits: it cannot "
    "be identified from robot poses alone; a stereo camera's focal-length error is a depth "
    "scale: use 'depthscale'"
)


@dataclass(frozen=True, eq=False)
class DepthScale(EffectBase):
    """The instrument's z (optical axis) reads ``1 + s`` times too long."""

    instrument = True  # the camera's error: never compensated, never on the simulated arm

    name: str = "depthscale"
    joint: int | None = None  # the instrument
    param_names: tuple[str, ...] = ("s",)
    param_units: tuple[str, ...] = ("1",)
    prior_sigma: F = field(default_factory=lambda: np.array([1e-2]))
    regressor_name: str = "depth along the instrument's optical axis (m)"

    @property
    def n_params(self) -> int:
        """One scale factor."""
        return 1

    def regressor(self, ctx: EffectContext) -> F:
        """Ones, shape (n,): the depth itself comes from the model pose (see module doc)."""
        return np.ones(ctx.n_poses)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``instr_scale_z = s``."""
        return Perturbation(instr_scale_z=np.full(ctx.n_poses, float(params[0])))

    def regressor_at(self, ctx: EffectContext, params: F | None, T_model: F) -> tuple[F, str]:
        """The pose's depth (instrument z, m) from the model pose."""
        return T_model[:, 2, 3], self.regressor_name


@register(
    r"depthscale",
    "depthscale",
    propose=lambda robot, meas, options: ["depthscale"],
    twin=TwinSize("1 (fraction)", 1.0),
    example="depthscale=4e-4",
)
def _make(m: re.Match[str], robot: RobotModel) -> DepthScale:
    return DepthScale()


@register(r"uniformscale", "uniformscale (explained, not fitted)")
def _uniform(m: re.Match[str], robot: RobotModel) -> DepthScale:
    raise NotIdentifiable("uniformscale", UNIFORM_SCALE_EXPLANATION)
