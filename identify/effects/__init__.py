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
registers its name pattern in :data:`REGISTRY` (see :func:`parse_effect`) with what its type
declares (:class:`EffectType`: the channels it needs, the candidates it proposes, its quick-check
family, its size on the twin's command line, an example).  Everything else a consumer needs is
declared on the effect object (:class:`Effect`; defaults in :class:`._base.EffectBase`): the
diagnosis, the twin, compensate, the quick check, the simulated cell and the command line loop
over the registry and never name an effect (docs/effects.md, "Adding an effect").
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

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
    joint_temp : ndarray, shape (n, nj), °C, or None
        Each joint's temperature as the controller reports it.
    joint_torque : ndarray, shape (n, nj), N·m, or None
        Each joint's measured torque: what its drive exerts about the joint axis (at rest,
        minus the torque gravity applies).
    """

    robot: RobotModel
    q: F
    approach: F
    gravity_torque: F | None = None
    time: F | None = None
    temp: F | None = None
    joint_temp: F | None = None
    joint_torque: F | None = None

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
    joint_motion : ndarray, shape (n, nj, 6)
        Added to every joint's six error motions ``E_i`` (δx δy δz m, εx εy εz rad, in the
        joint's frame, as the Chebyshev terms): an axial growth is δz, a drift of the joint's
        angle εz.
    """

    dq: F | None = None
    link_scale: F | None = None
    base_twist: F | None = None
    instr_scale_z: F | None = None
    joint_motion: F | None = None

    def robot_only(self) -> Perturbation:
        """The robot's own part: without the instrument's scale and the base's motion."""
        return Perturbation(dq=self.dq, link_scale=self.link_scale, joint_motion=self.joint_motion)

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
            joint_motion=add(self.joint_motion, other.joint_motion),
        )


def effect_context(
    robot: RobotModel,
    q: F,
    approach: F | None = None,
    time: F | None = None,
    temp: F | None = None,
    joint_temp: F | None = None,
    joint_torque: F | None = None,
) -> EffectContext:
    """The context of joints ``q`` (n, nj) in execution order; approach from the order if not
    given.  ``time``, ``temp`` (n,) and ``joint_temp``, ``joint_torque`` (n, nj): the
    conditions of each pose, where known (:data:`CHANNELS`)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    app = approach_from_order(q) if approach is None else np.asarray(approach, dtype=float)
    tau = None
    if robot.masses is not None and robot.coms is not None:
        tau = gravity_torques(robot, q)

    def per_joint(v: F | None) -> F | None:
        return None if v is None else np.asarray(v, dtype=float).reshape(q.shape)

    return EffectContext(
        robot=robot,
        q=q,
        approach=np.atleast_2d(app),
        gravity_torque=tau,
        time=None if time is None else np.asarray(time, dtype=float).reshape(-1),
        temp=None if temp is None else np.asarray(temp, dtype=float).reshape(-1),
        joint_temp=per_joint(joint_temp),
        joint_torque=per_joint(joint_torque),
    )


@dataclass(frozen=True)
class Channel:
    """What an effect may need beyond the joint readings (:meth:`Effect.requires`).

    Each channel is an attribute of :class:`EffectContext`; all but ``approach`` (which the
    execution order gives every file) are also optional attributes of
    :class:`~quickhealth.identify.measurements.Measurements` and conditions a model is
    evaluated at (``FittedModel.predict``'s keywords).

    Attributes
    ----------
    words : str
        The channel in words, with its unit.
    condition : str or None
        Its key in report.json's ``workspace.conditions`` (the value the workspace map states
        for it); None for a channel that is no condition (the approach directions).
    """

    words: str
    condition: str | None


CHANNELS: dict[str, Channel] = {
    "approach": Channel("approach direction of every joint (from the execution order)", None),
    "time": Channel("time (s, on the fitted run's clock)", "time_s"),
    "temp": Channel("temperature (°C)", "temp_c"),
    "joint_temp": Channel("temperature of each joint (°C)", "joint_temp_c"),
    "joint_torque": Channel("measured torque of each joint (N·m)", "joint_torque"),
}

#: The channels that are conditions of a pose (keywords of ``FittedModel.predict``,
#: attributes of Measurements): all but the approach directions.
CONDITIONS = tuple(c for c in CHANNELS if c != "approach")

#: Channels every measurement file has (derived from the order of its rows).
ALWAYS = frozenset({"approach"})

#: The temperature (°C) the link lengths and the joints refer to: the thermal effects' zero
#: and the reference condition of the workspace map.
T_REF_C = 20.0


def reference_conditions(
    channels: Collection[str], robot: RobotModel, q: F, reference_time: float | None
) -> dict[str, F]:
    """The stated reference conditions of the commands ``q`` (n, nj), for the ``channels`` a
    model needs: ``temp`` and every ``joint_temp`` at :data:`T_REF_C`; ``time`` at
    ``reference_time`` (the fitted run's last pose; 0 when unknown); ``joint_torque`` the
    torque that holds the robot model's own masses against gravity (zero on a robot without
    masses: then the arm counts as unloaded).  What the workspace map, the registration of
    the nominal robot and the correction extent evaluate a model at."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    out: dict[str, F] = {}
    if "temp" in channels:
        out["temp"] = np.full(n, T_REF_C)
    if "time" in channels:
        out["time"] = np.full(n, reference_time or 0.0)
    if "joint_temp" in channels:
        out["joint_temp"] = np.full(q.shape, T_REF_C)
    if "joint_torque" in channels:
        has = robot.masses is not None and robot.coms is not None
        out["joint_torque"] = -gravity_torques(robot, q) if has else np.zeros(q.shape)
    return out


@dataclass(frozen=True)
class TwinSize:
    """How ``quickhealth twin --effects NAME=SIZE`` reads an effect's size.

    ``unit`` is the command line's unit in words; ``to_si`` multiplies the size into the SI
    size that :meth:`Effect.twin_params` takes.
    """

    unit: str
    to_si: float


@dataclass(frozen=True)
class CheckFamily:
    """An effect as a family of the quick check's change model
    (:func:`~quickhealth.identify.quickcheck.change_model`).

    ``kind`` is the family's name in ``CheckSettings.effects`` (``backlash``, ``compliance``).
    ``jump``: the effect's size is the TCP jump between two states of the joint (the two
    approach directions), which no set-up change takes up.
    """

    kind: str
    jump: bool = False


class Effect(Protocol):
    """A physical effect: a few parameters, linear in its perturbation of the loop.

    Everything a consumer needs is declared here; :class:`~._base.EffectBase` gives the
    defaults, so a new effect declares what differs.  The consumers (diagnose, the twin,
    compensate, the quick check, the simulated cell, the command line and the tests) loop over
    :data:`REGISTRY` and these attributes: none of them names an effect.
    """

    name: str  # the contract name, e.g. "compliance:j2"
    param_names: tuple[str, ...]  # e.g. ("c",)
    param_units: tuple[str, ...]  # SI units of each parameter, e.g. ("rad/(N·m)",)
    prior_sigma: F  # prior standard deviation of each parameter (SI), shape (n_params,)
    regressor_name: (
        str  # what to plot residuals against, in words (e.g. "gravity torque of joint 2 (N·m)")
    )
    joint: int | None  # 0-based joint the effect belongs to; None for the whole arm or instrument
    instrument: bool  # the instrument's error, not the robot's: never compensated or simulated

    @property
    def n_params(self) -> int: ...

    @property
    def physical(self) -> str:
        """The physical effect this is a form of (``compliance:j2`` for its mass and lumped
        forms): a model holds each at most once."""
        ...

    @property
    def form(self) -> str:
        """Which form of the physical effect (``masses``, ``lumped``; ``""`` when it has one)."""
        ...

    @property
    def family(self) -> str:
        """The kind of effect in one word (``backlash``, ``compliance``, ``cyclic``, ``thermal``):
        what a fault dictionary or a report groups it by."""
        ...

    @property
    def check_family(self) -> CheckFamily | None:
        """Its family in the quick check's change model (None: the check does not test it)."""
        ...

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """The loop perturbation for parameters ``params`` (linear in ``params``)."""
        ...

    def regressor(self, ctx: EffectContext) -> F:
        """The scalar per pose the effect's size scales with, shape (n,): for plots."""
        ...

    def regressor_at(self, ctx: EffectContext, params: F | None, T_model: F) -> tuple[F, str]:
        """The plot regressor per pose and its label, once the parameters (or the model pose
        ``T_model``, (n, 4, 4)) are known."""
        ...

    def requires(self) -> tuple[str, ...]:
        """Channels the effect needs (:data:`CHANNELS`), e.g. ("temp",): its type's
        (:attr:`EffectType.requires`)."""
        ...

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joints (0-based) whose smooth Chebyshev errors the diagnosis must see the effect
        beyond (a low harmonic *is* a smooth function of its joint's angle)."""
        ...

    def spectrum_bin(self) -> tuple[str, int] | None:
        """``(joint key, harmonic)`` when the effect is a bin of the diagnosis's residual
        spectrum against a joint angle (``("j1", 9)``), else None."""
        ...

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """True parameters of a hidden instance of SI ``size`` (the twin; InputError when one
        size cannot say it)."""
        ...

    def correction(self, conditions: Mapping[str, Any]) -> str:
        """What compensating it at each target of a program uses, in words (``conditions``:
        what the program runs at, by channel: ``temp`` °C and ``time`` s, ``joint_temp`` one
        °C per joint, ``joint_torque`` where the torques come from, in words)."""
        ...

    def correction_notes(self, params: F, q_program: F) -> list[str]:
        """Warnings about a compensated program ``q_program`` (n, nj) rad (e.g. moves smaller
        than a backlash's play)."""
        ...

    def describe_fit(self, fitted: Any) -> list[str]:
        """The fit summary's lines about this effect (its form, estimates in words and units)."""
        ...

    def info(self) -> dict[str, Any]:
        """What model.json keeps beside the name and parameters."""
        ...


EffectFactory = Callable[[re.Match[str], RobotModel], Effect]
#: ``(robot, measurements, options)`` → the effect names of one type worth testing on the data.
Proposer = Callable[[RobotModel, Any, "ProposalOptions"], list[str]]


@dataclass(frozen=True)
class ProposalOptions:
    """Options of the diagnosis's candidate proposal."""

    max_harmonic: int = 30


@dataclass(frozen=True)
class EffectType:
    """One registered effect name pattern and what it declares beyond its objects.

    Attributes
    ----------
    pattern : compiled regex
        The contract names it makes (full match), e.g. ``backlash:j(\\d+)``.
    make : callable
        ``(match, robot) → Effect``.
    doc : str
        The pattern in words, e.g. ``backlash:jK``.
    requires : tuple of str
        The channels (:data:`CHANNELS`) its effects need, e.g. ``("temp",)``.
    propose : callable, optional
        The names of this type diagnose tests on a robot and data set (None: never proposed).
    check : (str, callable), optional
        The quick check's family kind (``backlash``) and the names of this type its change
        model holds on a robot.
    twin : TwinSize, optional
        How the twin's command line reads a size (None: not hidden by one size).
    example : str, optional
        ``NAME=SIZE`` in the twin's command-line units: a hidden instance diagnose must name
        (the command-line test of every effect runs it).
    """

    pattern: re.Pattern[str]
    make: EffectFactory
    doc: str
    requires: tuple[str, ...] = ()
    propose: Proposer | None = None
    check: tuple[str, Callable[[RobotModel], list[str]]] | None = None
    twin: TwinSize | None = None
    example: str | None = None


REGISTRY: list[EffectType] = []


def register(
    pattern: str,
    doc: str,
    *,
    requires: tuple[str, ...] = (),
    propose: Proposer | None = None,
    check: tuple[str, Callable[[RobotModel], list[str]]] | None = None,
    twin: TwinSize | None = None,
    example: str | None = None,
) -> Callable[[EffectFactory], EffectFactory]:
    """Decorator: register a factory for effect names matching ``pattern`` (full match), with
    what the type declares (see :class:`EffectType`)."""

    def deco(factory: EffectFactory) -> EffectFactory:
        REGISTRY.append(
            EffectType(re.compile(pattern), factory, doc, requires, propose, check, twin, example)
        )
        return factory

    return deco


class NotIdentifiable(InputError):
    """A registered name that is explained, never fitted (``uniformscale``): ``reason`` says
    why the data cannot identify it."""

    def __init__(self, name: str, reason: str) -> None:
        super().__init__(f"effect {name!r} is not fitted: {reason}")
        self.name = name
        self.reason = reason


def effect_types() -> list[EffectType]:
    """Every registered effect type, built-ins first (in the order diagnose proposes them),
    whatever order their modules were imported in."""
    _load_builtin()
    return sorted(REGISTRY, key=lambda t: _module_rank(t.make.__module__.rsplit(".", 1)[-1]))


def effect_type(name: str) -> EffectType:
    """The registered type a contract name belongs to (InputError for an unknown name)."""
    for t in effect_types():
        if t.pattern.fullmatch(name.strip()):
            return t
    raise InputError(f"unknown effect {name!r}; known: chebyshev, {_known()}")


def is_effect_name(name: str) -> bool:
    """True when ``name`` is a registered effect name (``compliance:j2``, ``thermal``), as
    opposed to, e.g., a coefficient label (``j2.ex.c0``)."""
    return any(t.pattern.fullmatch(name.strip()) for t in effect_types())


def _known() -> str:
    return ", ".join(t.doc for t in REGISTRY) or "none"


def propose(
    robot: RobotModel, meas: Any, options: ProposalOptions = ProposalOptions()
) -> list[str]:
    """Every effect name worth testing on ``meas`` (diagnose's candidates), type by type."""
    out: list[str] = []
    for t in effect_types():
        if t.propose is not None:
            out += t.propose(robot, meas, options)
    return out


def check_kinds() -> tuple[str, ...]:
    """Every quick-check family kind an effect type declares (``backlash``, ``compliance``)."""
    return tuple(sorted({t.check[0] for t in effect_types() if t.check is not None}))


def check_effects(kinds: Sequence[str], robot: RobotModel) -> list[Effect]:
    """The effects of the quick check's families ``kinds`` on ``robot`` (InputError for a kind
    no registered effect declares)."""
    checked = [t.check for t in effect_types() if t.check is not None]
    known = check_kinds()
    out: list[Effect] = []
    for kind in kinds:
        if kind not in known:
            raise InputError(f"a check tests {' and '.join(known)} families, not {kind!r}")
        out += [parse_effect(n, robot) for k, names in checked if k == kind for n in names(robot)]
    return out


def channels_of(name: str) -> tuple[str, ...]:
    """The channels the effects of a registered name need (no robot needed)."""
    return effect_type(name).requires


def missing_channels(effect: Effect, data: Any) -> list[str]:
    """The channels ``effect`` needs that ``data`` (Measurements or EffectContext) lacks."""
    return [c for c in effect.requires() if c not in ALWAYS and getattr(data, c, None) is None]


def parse_effect(name: str, robot: RobotModel) -> Effect:
    """Effect object for a contract name such as ``backlash:j2`` or ``cyclic:j1:h11``."""
    t = effect_type(name)
    m = t.pattern.fullmatch(name.strip())
    assert m is not None
    return t.make(m, robot)


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
    return effect.physical


def total_perturbation(
    effects: Sequence[Effect], params: Sequence[F], ctx: EffectContext
) -> Perturbation:
    """Sum of the perturbations of ``effects`` with their parameter vectors."""
    total = Perturbation()
    for e, p in zip(effects, params, strict=True):
        total = total + e.perturbation(ctx, np.asarray(p, dtype=float))
    return total


#: The built-in modules in the order their candidates are proposed (the diagnosis's output
#: order); any other module of this package registers after them, by name.
_BUILTIN = ("compliance", "backlash", "cyclic", "thermal", "drift", "depthscale")


def _module_rank(name: str) -> tuple[int, str]:
    return (_BUILTIN.index(name) if name in _BUILTIN else len(_BUILTIN), name)


_LOADED: list[bool] = []


def _load_builtin() -> None:
    """Import the effect modules of this package so they register themselves (once)."""
    import importlib
    import pkgutil

    if _LOADED:
        return
    names = [i.name for i in pkgutil.iter_modules(__path__) if not i.name.startswith("_")]
    for name in sorted(names, key=_module_rank):
        importlib.import_module(f"{__name__}.{name}")
    _LOADED.append(True)
