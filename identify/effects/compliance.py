"""Gravity-load compliance of one joint: ``compliance:jK`` and ``compliance:jK:lumped``.

Physics
-------
A joint's gearbox, bearings or cables are springs: under the static gravity torque ``τ_K`` it
carries (all links beyond it, with their masses and centres of mass) joint K turns by

    dq_K = c · τ_K

``c`` (rad/(N·m)) is the joint's compliance, the inverse of its torsional stiffness (harmonic
drives of arms like the UR5: 1e4 … 1e5 N·m/rad, so c ≈ 1e-5 … 1e-4).  The torque depends on
the *whole* configuration (for the UR5's joint 2 on q2 and q2 + q3 and the wrist), so no
polynomial in one joint angle expresses it.  The deflection has the sign of the torque gravity
applies (base z up).

Two forms, one physical effect (CONTRACTS.md: "joint K deflects in proportion to the gravity
torque it carries"):

**Mass form** (``compliance:jK`` on a robot with link masses and centres of mass): ``τ_K``
comes from :func:`quickhealth.identify.robot.gravity_torques`; one parameter ``c``.  The
regressor, for plots, is ``τ_K`` (N·m).

**Lumped form** (``compliance:jK:lumped``; also what ``compliance:jK`` means on a robot
without inertial data, which most industrial robots are): the torque is linear in the first
mass moments ``h_j`` (kg·m, :func:`~quickhealth.identify.robot.first_moments`) of the links
``j ≥ K``, with regressors that need the kinematics only
(:func:`~quickhealth.identify.robot.gravity_regressor`)::

    dq_K = c · τ_K = Σ_{j ≥ K} Σ_{a ∈ xyz} Y_{j,a}(q) · θ_{j,a},     θ_{j,a} = c · |g| · h_{j,a}

Each ``θ`` (rad) is a lumped gravity moment divided by the stiffness: the deflection that
moment alone would cause with its lever horizontal.  Stiffness and moments cannot be told
apart (only their product acts), and the ``3·(n − K + 1)`` columns are linearly dependent:
the moment of link j along its own joint axis turns with link j − 1 and is absorbed by
link j − 1's moments; link K's moment along axis K puts no torque on joint K; parallel axes
and the vertical direction of gravity add more.  :func:`structural_basis` reduces them to a
*base set* (sequential Gram–Schmidt over the regressor at poses spread over the joint
ranges, links from joint K outwards, axes x, y, z): each kept column's parameter stands for
a fixed combination of the moments (:meth:`LumpedBasis.combinations`, e.g.
``h2x + 1·h3z``).  Which of these the *data* determine is the fit's own identifiability
check (a combination the Chebyshev terms already express — link K's own moments, whose
torque is a function of q_K alone — is held at zero and listed as not identifiable).
The regressor for plots is the modelled deflection at the fitted parameters (mrad), or
without parameters the torque pattern of the base set's principal direction.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..measurements import Measurements
from ..robot import RobotModel, gravity_regressor, gravity_torques
from . import CheckFamily, EffectContext, Perturbation, ProposalOptions, TwinSize, register
from ._base import EffectBase, F, fitted_estimates, joint_dq, joint_index

AXES = ("x", "y", "z")
#: Prior standard deviation of a lumped parameter (rad): 10 mrad, far above any sane deflection.
LUMPED_PRIOR = 1e-2
_SAMPLES = 256  # poses over the joint ranges for the structural base set
_REL_TOL = 1e-7  # a column adding less new direction than this (relative) is dependent


@dataclass(frozen=True, eq=False)
class Compliance(EffectBase):
    """Joint ``joint`` (0-based) deflects by ``c · τ`` (mass form)."""

    joint: int
    name: str
    param_names: tuple[str, ...] = ("c",)
    param_units: tuple[str, ...] = ("rad/(N·m)",)
    prior_sigma: F = field(default_factory=lambda: np.array([1e-4]))
    regressor_name: str = ""
    form: str = "masses"

    def __post_init__(self) -> None:
        if not self.regressor_name:
            object.__setattr__(
                self, "regressor_name", f"gravity torque of joint {self.joint + 1} (N·m)"
            )

    @property
    def n_params(self) -> int:
        """One compliance."""
        return 1

    @property
    def physical(self) -> str:
        """The contract name of the effect (both forms share it)."""
        return f"compliance:j{self.joint + 1}"

    def regressor(self, ctx: EffectContext) -> F:
        """Gravity torque of the joint, shape (n,), N·m."""
        if ctx.gravity_torque is None:
            raise InputError(
                f"{self.name} needs link masses and centres of mass; "
                f"robot {ctx.robot.name!r} has none"
            )
        return np.asarray(ctx.gravity_torque[:, self.joint], dtype=float)

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = c · τ_K``."""
        tau = self.regressor(ctx)
        return Perturbation(
            dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, params[0] * tau)
        )

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joints K and K+1, whose angles the gravity torque depends on most: what remains is
        the torque's non-additive dependence (on q_K + q_K+1), which no per-joint polynomial
        expresses."""
        return _own_and_next(self.joint, n_joints)

    @property
    def check_family(self) -> CheckFamily:
        """The quick check's ``compliance`` family."""
        return CheckFamily("compliance")

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """By the gravity torque at each target."""
        return f"{self.name} by the gravity torque at each target"

    def describe_fit(self, fitted: Any) -> list[str]:
        """The fit summary's line: the form and the estimate."""
        v, s = fitted_estimates(fitted, self)
        return [
            f"{self.name}: mass form (gravity torque from the robot's link masses and centres "
            f"of mass): c = {v[0]:.3g} ± {s[0]:.2g} rad/(N·m)"
        ]


@dataclass(frozen=True, eq=False)
class LumpedBasis:
    """The structural base set of joint ``joint``'s gravity regressor.

    Attributes
    ----------
    joint : int
        0-based joint index.
    full_names : tuple of str
        ``h{j}{a}`` for every link ``j ≥ joint`` (1-based) and axis of its joint frame.
    keep : tuple of int
        Indices into ``full_names`` of the base set (the effect's parameters).
    M : ndarray, shape (n_base, n_full)
        ``θ_base = M θ_full``: the combination of moments each base parameter stands for.
    zero : tuple of str
        Moments that never load the joint (their torque about axis K is identically zero).
    principal : ndarray, shape (n_base,)
        Unit weights of the base set's principal direction (the plot regressor without
        parameters).
    """

    joint: int
    full_names: tuple[str, ...]
    keep: tuple[int, ...]
    M: F
    zero: tuple[str, ...]
    principal: F

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the base parameters."""
        return tuple(self.full_names[i] for i in self.keep)

    def combinations(self) -> list[str]:
        """What each base parameter stands for, e.g. ``h2x = h2x + 1·h3z − 0.707·h4y``."""
        out = []
        for b, name in enumerate(self.names):
            terms = [name]  # a kept column stands for itself with weight 1
            for i, c in enumerate(self.M[b]):
                if abs(c) < 1e-9 or self.full_names[i] == name:
                    continue
                terms.append(f"{'−' if c < 0 else '+'} {abs(c):.4g}·{self.full_names[i]}")
            out.append(f"{name} = " + " ".join(terms))
        return out


def structural_basis(robot: RobotModel, joint: int, n_samples: int = _SAMPLES) -> LumpedBasis:
    """The base set of the lumped gravity moments beyond ``joint`` (0-based), from kinematics.

    The regressor of :func:`~quickhealth.identify.robot.gravity_regressor` is evaluated at
    ``n_samples`` poses drawn (fixed seed) over the joint ranges (within ±180°: the regressor
    is periodic); a sequential Gram–Schmidt in the order links K … n, axes x, y, z keeps the
    columns that add a new direction.  Structural dependencies are exact, so the tolerance is
    far below anything data could resolve; what the data of a given run cannot determine is
    left to the fit.
    """
    nj = robot.n_joints
    lo = np.maximum(robot.q_min, -np.pi)
    hi = np.minimum(robot.q_max, np.pi)
    bad = hi <= lo
    lo = np.where(bad, robot.q_min, lo)
    hi = np.where(bad, robot.q_max, hi)
    q = np.random.default_rng(12345).uniform(lo, hi, (n_samples, nj))
    Y = gravity_regressor(robot, q, joint).reshape(n_samples, -1)
    full = tuple(f"h{j + 1}{a}" for j in range(joint, nj) for a in AXES)
    norms = np.linalg.norm(Y, axis=0)
    scale = float(norms.max()) if norms.size else 0.0
    zero = tuple(full[i] for i in range(len(full)) if norms[i] <= _REL_TOL * max(scale, 1e-300))
    basis: list[F] = []
    keep: list[int] = []
    for i in range(Y.shape[1]):
        if full[i] in zero:
            continue
        v = Y[:, i] / norms[i]
        for b in basis:
            v = v - b * (b @ v)
        nv = float(np.linalg.norm(v))
        if nv > 1e-6:
            basis.append(v / nv)
            keep.append(i)
    if not keep:
        return LumpedBasis(joint, full, (), np.zeros((0, len(full))), zero, np.zeros(0))
    Yk = Y[:, keep]
    M, *_ = np.linalg.lstsq(Yk, Y, rcond=None)
    M[np.abs(M) < 1e-9] = 0.0
    M = np.round(M, 9)
    _, _, Vt = np.linalg.svd(Yk, full_matrices=False)
    w = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
    return LumpedBasis(joint, full, tuple(keep), M, zero, w)


@dataclass(frozen=True, eq=False)
class LumpedCompliance(EffectBase):
    """Joint ``joint`` (0-based) deflects by ``Σ Y_b(q) θ_b`` over the structural base set.

    ``reason`` says why this form was chosen when the name asked for did not (the fallback of
    ``compliance:jK`` on a robot without masses).
    """

    joint: int
    name: str
    basis: LumpedBasis
    reason: str = ""
    form: str = "lumped"
    param_names: tuple[str, ...] = ()
    param_units: tuple[str, ...] = ()
    prior_sigma: F = field(default_factory=lambda: np.zeros(0))
    regressor_name: str = ""

    def __post_init__(self) -> None:
        n = len(self.basis.keep)
        object.__setattr__(self, "param_names", self.basis.names)
        object.__setattr__(self, "param_units", ("rad",) * n)
        object.__setattr__(self, "prior_sigma", np.full(n, LUMPED_PRIOR))
        if not self.regressor_name:
            object.__setattr__(
                self,
                "regressor_name",
                f"gravity-torque pattern of joint {self.joint + 1} (principal lumped moment, 1)",
            )

    @property
    def n_params(self) -> int:
        """Size of the base set."""
        return len(self.basis.keep)

    @property
    def physical(self) -> str:
        """The contract name of the effect (both forms share it)."""
        return f"compliance:j{self.joint + 1}"

    def columns(self, ctx: EffectContext) -> F:
        """The base set's regressor ``Y_b(q)`` (n, n_params), dimensionless."""
        Y = ctx.gravity_regressor(self.joint).reshape(ctx.n_poses, -1)
        return Y[:, list(self.basis.keep)]

    def regressor(self, ctx: EffectContext) -> F:
        """Torque pattern along the base set's principal direction, shape (n,) (for plots)."""
        return self.columns(ctx) @ self.basis.principal

    def regressor_at(self, ctx: EffectContext, params: F | None, T_model: F) -> tuple[F, str]:
        """The modelled deflection at ``params`` (mrad) and its label: the plot regressor once
        the parameters are known (a single number per pose the residual should follow)."""
        if params is None or not np.any(np.asarray(params, float)):
            return self.regressor(ctx), self.regressor_name
        return (
            self.columns(ctx) @ np.asarray(params, float) * 1e3,
            f"modelled gravity deflection of joint {self.joint + 1} (mrad)",
        )

    def perturbation(self, ctx: EffectContext, params: F) -> Perturbation:
        """``dq_K = Σ_b Y_b(q) θ_b``."""
        dq = self.columns(ctx) @ np.asarray(params, float)
        return Perturbation(dq=joint_dq(ctx.n_poses, ctx.robot.n_joints, self.joint, dq))

    def nuisance_joints(self, n_joints: int) -> tuple[int, ...]:
        """Joints K and K+1, as the mass form."""
        return _own_and_next(self.joint, n_joints)

    def twin_params(self, size: float, rng: np.random.Generator) -> F:
        """Many parameters, not one size: the twin hides compliance in its mass form."""
        raise InputError(
            f"{self.name} has {self.n_params} parameters, not one size; hide compliance as "
            f"compliance:j{self.joint + 1}=SIZE (deg/(N·m), with the twin's masses)"
        )

    def correction(self, conditions: Mapping[str, float | None]) -> str:
        """By the gravity torque at each target."""
        return f"{self.name} by the gravity torque at each target"

    def info(self) -> dict[str, Any]:
        """What model.json keeps beside the name: form, base set and what it stands for."""
        return {
            "form": self.form,
            "reason": self.reason,
            "combinations": self.basis.combinations(),
            "no_torque": list(self.basis.zero),
        }

    def describe_fit(self, fitted: Any) -> list[str]:
        """The fit summary's lines: the form, which combinations the data identify, estimates."""
        v, s = fitted_estimates(fitted, self)
        labels = [f"{self.name}.{n}" for n in self.param_names]
        unident = set(fitted.unidentifiable) | set(fitted.held)
        ok = [n for n, lb in zip(self.param_names, labels, strict=True) if lb not in unident]
        no = [n for n, lb in zip(self.param_names, labels, strict=True) if lb in unident]
        why = f" ({self.reason})" if self.reason else ""
        full = len(self.basis.full_names)
        lines = [
            f"{self.name}: lumped form, no link masses used{why}: joint {self.joint + 1}'s "
            f"gravity deflection from {self.n_params} base combinations of the {full} first "
            f"mass moments beyond it (divided by the joint stiffness)",
            f"  identifiable from this data: {', '.join(ok) if ok else 'none'}"
            + (f"; not identifiable (held at 0): {', '.join(no)}" if no else ""),
        ]
        if ok:
            est = ", ".join(
                f"{n} {1e3 * x:.3g} ± {1e3 * e:.2g}"
                for n, lb, x, e in zip(self.param_names, labels, v, s, strict=True)
                if lb not in unident
            )
            lines.append(f"  estimates (mrad): {est}")
        return lines


def _own_and_next(joint: int, n_joints: int) -> tuple[int, ...]:
    return tuple(j for j in (joint, joint + 1) if j < n_joints)


def lumped(robot: RobotModel, joint: int, reason: str = "") -> LumpedCompliance:
    """The lumped compliance of ``joint`` (0-based); InputError if gravity never loads it."""
    name = f"compliance:j{joint + 1}:lumped"
    basis = structural_basis(robot, joint)
    if not basis.keep:
        raise InputError(
            f"effect {name!r}: gravity puts no torque on joint {joint + 1} of {robot.name} in "
            "any pose (its axis is vertical), so it cannot deflect under gravity"
        )
    return LumpedCompliance(joint=joint, name=name, basis=basis, reason=reason)


def lumped_joints(robot: RobotModel) -> Sequence[int]:
    """Joints (0-based) gravity can load: the lumped form has a non-empty base set."""
    return [k for k in range(robot.n_joints) if structural_basis(robot, k).keep]


def has_masses(robot: RobotModel) -> bool:
    """True when the robot model has link masses and centres of mass."""
    return robot.masses is not None and robot.coms is not None


def _propose_masses(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """The mass form of every joint whose gravity load the data vary (robots with masses)."""
    if not has_masses(robot):
        return []
    tau = gravity_torques(robot, meas.q)
    return [f"compliance:j{k + 1}" for k in range(robot.n_joints) if np.ptp(tau[:, k]) > 1e-6]


def _propose_lumped(robot: RobotModel, meas: Measurements, options: ProposalOptions) -> list[str]:
    """The lumped form of every joint gravity loads and the data move the load of: it
    estimates the moments themselves, so an unknown payload (a tracker's probe of 1–1.5 kg on
    a UR10) is in it, where the mass form knows the links only; and a robot without link
    masses still gets its gravity compliance tested."""
    out = []
    for k in lumped_joints(robot):
        keep = list(structural_basis(robot, k).keep)
        Y = gravity_regressor(robot, meas.q, k).reshape(meas.n_poses, -1)[:, keep]
        if np.ptp(Y, axis=0).max() > 1e-6:
            out.append(f"compliance:j{k + 1}:lumped")
    return out


def _check_names(robot: RobotModel) -> list[str]:
    """The quick check tests the mass form of every joint, on robots with masses."""
    return [f"compliance:j{k + 1}" for k in range(robot.n_joints)] if has_masses(robot) else []


@register(
    r"compliance:j(\d+)",
    "compliance:jK",
    propose=_propose_masses,
    check=("compliance", _check_names),
    twin=TwinSize("deg/(N·m)", np.pi / 180.0),
    example="compliance:j2=0.00143",
)
def _make(m: re.Match[str], robot: RobotModel) -> Compliance | LumpedCompliance:
    j = joint_index(m.group(1), robot, m.group(0))
    if not has_masses(robot):
        return lumped(
            robot,
            j,
            reason=f"asked for as {m.group(0)}; robot {robot.name!r} has no link masses and "
            "centres of mass",
        )
    return Compliance(joint=j, name=f"compliance:j{j + 1}")


@register(r"compliance:j(\d+):lumped", "compliance:jK:lumped", propose=_propose_lumped)
def _make_lumped(m: re.Match[str], robot: RobotModel) -> LumpedCompliance:
    j = joint_index(m.group(1), robot, m.group(0))
    return lumped(robot, j)
