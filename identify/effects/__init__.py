"""Physical effects a joint-angle polynomial cannot express (CONTRACTS.md, "Effect names").

An effect adds a few parameters to the paper's Chebyshev model and perturbs the loop.  Every
effect is *linear in its parameters*: its :class:`Perturbation` is a sum of parameter times a
regressor computed from the :class:`EffectContext` (joint readings, approach directions,
gravity torques, time, temperature).  The fit evaluates the loop with the sum of all active
effects' perturbations, so effects compose with the Chebyshev model and with each other::

    T_instr_target = T_instr_base0 · E0 · E(base_twist) · Π_i [Rz(θ_i + dq_i) · E_i(θ_i) · C_i(link_scale)]
                     · T_flange_target0 · Etool
    measured point = diag(1, 1, 1 + instr_scale_z) · position of T_instr_target

Each effect lives in its own module of this package with its physics in the docstring, and
registers its name pattern in :data:`REGISTRY` (see :func:`parse_effect`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..measurements import approach_from_order
from ..robot import RobotModel, gravity_regressor, gravity_torques

F = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class EffectContext:
    """Everything an effect's regressor may depend on, per pose (SI units).

    Attributes
    ----------
    robot : RobotModel
    q : ndarray, shape (n, nj), rad
        Joint readings.
    approach : ndarray, shape (n, nj)
        +1 / −1: the direction each joint last moved in before reaching this pose.
    gravity_torque : ndarray, shape (n, nj), N·m, or None
        Torque gravity applies about each joint axis (None when the robot has no masses).
    time : ndarray, shape (n,), s, or None
    temp : ndarray, shape (n,), °C, or None
    """

    robot: RobotModel
    q: F
    approach: F
    gravity_torque: F | None = None
    time: F | None = None
    temp: F | None = None

    @property
    def n_poses(self) -> int:
        """Number of poses."""
        return int(self.q.shape[0])

    def gravity_regressor(self, joint: int) -> F:
        """Gravity torque on ``joint`` (0-based) per unit first moment of each link beyond it,
        ``(n, nj − joint, 3)`` (:func:`~quickhealth.identify.robot.gravity_regressor`; kinematics
        only, no masses).  Computed on first use and kept with the context."""
        cache = self.__dict__.setdefault("_gravity_regressor", {})
        if joint not in cache:
            cache[joint] = gravity_regressor(self.robot, self.q, joint)
        return cache[joint]


@dataclass(frozen=True, eq=False)
class Perturbation:
    """How effects perturb the loop; every field is optional and additive.

    Attributes
    ----------
    dq : ndarray, shape (n, nj), rad
        Added to the joint angle (the error transforms stay evaluated at the reading).
    link_scale : ndarray, shape (n,)
        Fractional growth of every link translation: ``C_i`` translations × (1 + link_scale).
    base_twist : ndarray, shape (n, 6)
        Small motion of the robot base in the instrument, ``E(δ, ε)`` after ``E0``: δ (m), ε (rad).
    instr_scale_z : ndarray, shape (n,)
        Fractional scale error of the instrument along its own z axis.
    """

    dq: F | None = None
    link_scale: F | None = None
    base_twist: F | None = None
    instr_scale_z: F | None = None

    def __add__(self, other: Perturbation) -> Perturbation:
        def add(a: F | None, b: F | None) -> F | None:
            if a is None:
                return b
            if b is None:
                return a
            return a + b

        return Perturbation(
            dq=add(self.dq, other.dq),
            link_scale=add(self.link_scale, other.link_scale),
            base_twist=add(self.base_twist, other.base_twist),
            instr_scale_z=add(self.instr_scale_z, other.instr_scale_z),
        )


def effect_context(
    robot: RobotModel,
    q: F,
    approach: F | None = None,
    time: F | None = None,
    temp: F | None = None,
) -> EffectContext:
    """The context of joints ``q`` (n, nj) in execution order; approach from the order if not given."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    app = approach_from_order(q) if approach is None else np.asarray(approach, dtype=float)
    tau = None
    if robot.masses is not None and robot.coms is not None:
        tau = gravity_torques(robot, q)
    return EffectContext(
        robot=robot,
        q=q,
        approach=np.atleast_2d(app),
        gravity_torque=tau,
        time=None if time is None else np.asarray(time, dtype=float).reshape(-1),
        temp=None if temp is None else np.asarray(temp, dtype=float).reshape(-1),
    )


class Effect(Protocol):
    """A physical effect: a few parameters, linear in its perturbation of the loop."""

    name: str  # the contract name, e.g. "compliance:j2"
    param_names: tuple[str, ...]  # e.g. ("c",)
    param_units: tuple[str, ...]  # SI units of each parameter, e.g. ("rad/(N·m)",)
    prior_sigma: F  # prior standard deviation of each parameter (SI), shape (n_params,)
    regressor_name: (
        str  # what to plot residuals against, in words (e.g. "gravity torque of joint 2 (N·m)")
    )

    @property
    def n_params(self) -> int: ...

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """The loop perturbation for parameters ``params`` (linear in ``params``)."""
        ...

    def regressor(self, ctx: EffectContext) -> F:
        """The scalar per pose the effect's size scales with, shape (n,): for plots."""
        ...

    def requires(self) -> tuple[str, ...]:
        """Measurement columns the effect needs, e.g. ("temp",)."""
        ...


EffectFactory = Callable[[re.Match[str], RobotModel], Effect]
REGISTRY: list[tuple[re.Pattern[str], EffectFactory, str]] = []


def register(pattern: str, doc: str) -> Callable[[EffectFactory], EffectFactory]:
    """Decorator: register a factory for effect names matching ``pattern`` (full match)."""

    def deco(factory: EffectFactory) -> EffectFactory:
        REGISTRY.append((re.compile(pattern), factory, doc))
        return factory

    return deco


def parse_effect(name: str, robot: RobotModel) -> Effect:
    """Effect object for a contract name such as ``backlash:j2`` or ``cyclic:j1:h11``."""
    _load_builtin()
    for pattern, factory, _ in REGISTRY:
        m = pattern.fullmatch(name.strip())
        if m:
            return factory(m, robot)
    known = ", ".join(doc for _, _, doc in REGISTRY) or "none"
    raise InputError(f"unknown effect {name!r}; known: chebyshev, {known}")


def parse_effects(spec: str | Sequence[str] | None, robot: RobotModel) -> list[Effect]:
    """Effects for a comma-separated list (``chebyshev`` is always present and skipped)."""
    if spec is None:
        return []
    names = spec.split(",") if isinstance(spec, str) else list(spec)
    out = [parse_effect(n, robot) for n in names if n.strip() and n.strip() != "chebyshev"]
    seen: set[str] = set()
    same: dict[str, str] = {}
    for e in out:
        if e.name in seen:
            raise InputError(f"effect {e.name!r} given twice")
        seen.add(e.name)
        key = same_effect_key(e)
        if key in same:
            raise InputError(
                f"effects {same[key]!r} and {e.name!r} are two forms of {key}: keep one"
            )
        same[key] = e.name
    return out


def same_effect_key(effect: Effect) -> str:
    """The physical effect an effect object is a form of (``compliance:j2`` for both the mass
    and the lumped form): a model holds each at most once."""
    return str(getattr(effect, "physical", effect.name))


def total_perturbation(
    effects: Sequence[Effect], params: Sequence[F], ctx: EffectContext
) -> Perturbation:
    """Sum of the perturbations of ``effects`` with their parameter vectors."""
    total = Perturbation()
    for e, p in zip(effects, params, strict=True):
        total = total + e.perturbation(ctx, np.asarray(p, dtype=float))
    return total


def _load_builtin() -> None:
    """Import the built-in effect modules so they register themselves (idempotent)."""
    import importlib
    import pkgutil

    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")
