"""Shared helpers of the effects: the protocol's defaults (:class:`EffectBase`), joint index
parsing, per-joint perturbations."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..robot import RobotModel

F = NDArray[np.float64]


def joint_index(token: str, robot: RobotModel, name: str) -> int:
    """0-based joint index of ``jK`` (1-based K), checked against the robot."""
    k = int(token)
    if not 1 <= k <= robot.n_joints:
        raise InputError(
            f"effect {name!r}: joint j{k} does not exist on {robot.name} "
            f"(joints j1 … j{robot.n_joints})"
        )
    return k - 1


def joint_dq(n: int, nj: int, joint: int, values: F) -> F:
    """A ``dq`` array (n, nj) that is zero except column ``joint``."""
    dq = np.zeros((n, nj))
    dq[:, joint] = values
    return dq


class EffectBase:
    """Defaults of everything :class:`~quickhealth.identify.effects.Effect` declares: an effect
    class inherits them and declares what differs (see docs/effects.md, "Adding an effect").

    The defaults describe an effect of the whole arm with one form, that the diagnosis tests
    against the model alone, the quick check does not test, the simulated arm can carry when
    it records the effect's channels, and a program is compensated for at each target.
    """

    name: str
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    regressor_name: str
    joint: int | None  # a field of every effect class (None for the whole arm or instrument)
    instrument: bool = False

    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return len(self.param_names)

    @property
    def physical(self) -> str:
        """The physical effect this is a form of: its own name."""
        return self.name

    @property
    def form(self) -> str:
        """One form only."""
        return ""

    @property
    def family(self) -> str:
        """The first word of its name (``backlash`` of ``backlash:j2``)."""
        return self.name.split(":")[0]

    @property
    def check_family(self) -> Any:
        """Not a family of the quick check."""
        return None

    def regressor(self, ctx: Any) -> F:  # pragma: no cover - every effect defines it
        raise NotImplementedError

    def requires(self) -> tuple[str, ...]:
        """The channels its type declares (``register(..., requires=...)``)."""
        from . import channels_of

        return channels_of(self.name)

    def regressor_at(self, ctx: Any, params: F | None, T_model: F) -> tuple[F, str]:
        """The regressor of :meth:`regressor` (it does not depend on the parameters)."""
        return self.regressor(ctx), self.regressor_name

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Tested against the model alone."""
        return ()

    def spectrum_bin(self) -> tuple[str, int] | None:
        """Not part of a residual spectrum."""
        return None

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """A one-parameter effect's size is its parameter; more parameters need them all."""
        if self.n_params != 1:
            raise InputError(
                f"{self.name} has {self.n_params} parameters: give them all, not one size"
            )
        return np.array([float(size)])

    def correction(self, conditions: Mapping[str, Any]) -> str:
        """Evaluated at each target."""
        return f"{self.name} at each target"

    def correction_notes(self, params: F, q_program: F) -> list[str]:
        """Nothing to warn about."""
        return []

    def describe_fit(self, fitted: Any) -> list[str]:
        """No line beyond the effect's name in the summary's list."""
        return []

    def info(self) -> dict[str, Any]:
        """Beside the name and the parameters, the form of an effect that has several
        (``{"form": "torque"}``); nothing for one with a single form."""
        return {"form": self.form} if self.form else {}


def fitted_estimates(fitted: Any, effect: Any) -> tuple[F, F]:
    """The effect's fitted parameters and standard uncertainties in ``fitted`` (a FittedModel)."""
    names = [e.name for e in fitted.effects]
    k = names.index(effect.name)
    pos = fitted.spec.n_params + sum(e.n_params for e in fitted.effects[:k])
    sd = fitted.sigma[pos : pos + effect.n_params]
    return np.asarray(fitted.effect_params[k], float), np.asarray(sd, float)
