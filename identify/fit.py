"""Implicit-loop maximum-likelihood fit of the error model (METHOD.md Eq. 5–8).

The loop base → robot → target → instrument → base closes on every measured pose.  With the
measured target pose ``M_i`` and the model ``T_i(q_i, p)`` the loop residual is the small
motion ``M_i · T_i⁻¹``: its translation part (``x̃`` of the measured point, m) and its rotation
vector (rad, instrument frame).  Its covariance ``Σx,i`` is built from the instrument's
uncertainty (per-row ``sx…`` columns or instrument defaults) and the encoders' uncertainty
propagated through the loop (the implicit-loop "effective variance": joint readings are
measured quantities too).  The estimate minimises Eq. 8,

    χ² = Σ_i r_iᵀ Σx,i⁻¹ r_i + p̃ᵀ Σp⁻¹ p̃,

by Levenberg–Marquardt on analytic Jacobians (effect parameters by central differences:
they are few and linear).  SYNOPSIS::

    from quickhealth.identify.fit import fit_model, InstrumentNoise
    fitted = fit_model(robot, meas, spec, noise=InstrumentNoise(sigma_pos=3e-5, sigma_rot=1e-4))
    print("\\n".join(fitted.summary()))
    T = fitted.predict(q_new)            # (n, 4, 4) target pose in the instrument frame
    err = fitted.tcp_error(q_new)        # (n,) m, model minus nominal kinematics

Robust start: the instrument may be metres away and rotated.  A Kabsch fit of the nominal
flange positions to the measured points, then alternating least squares for tool point, base
pose and (7D) tool rotation, gives ``T_instr_base0`` and ``T_flange_target0``; the fit then
only identifies small corrections ``E0``, ``Etool``.

Rank deficiency: some coefficients cannot be told apart from others (a constant ``εz`` of
joint 1 is a rotation of the base; every constant of the last joint is a tool offset; tool
rotations are invisible to position-only data).  A sequential Gram–Schmidt selection over the
column-normalised whitened Jacobian, taken in a fixed priority order (base, tool, joint
constants, then higher orders, then effects), finds the columns that add less than
``rank_tol`` of new direction to the columns kept before them (a rejected column removes no
direction from later ones); those are held at zero and reported in
``FittedModel.unidentifiable``.  Their prior keeps
the remaining weakly determined combinations from amplifying noise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import (
    CONDITIONS,
    Effect,
    EffectContext,
    Perturbation,
    effect_context,
    missing_channels,
    reference_conditions,
    total_perturbation,
)
from .errormodel import MOTIONS, ErrorModelSpec, chebyshev_u, constant_motions
from .errors import InputError
from .linearize import (
    InstrumentNoise,
    Whitening,
    coefficient_columns,
    effect_channels,
    effect_jacobian,
    forward,
    joint_angle_jacobian,
    loop_pose,
    motion_jacobian,
    noise_covariance,
    pose_residuals,
    rotation_noise_cov,
    sensitivities,
)
from .measurements import Measurements
from .robot import RobotModel
from .transforms import exp_so3, kabsch, log_so3, make_T, skew, small_error_transform

__all__ = [
    "FittedModel",
    "InstrumentNoise",
    "ParameterPrior",
    "Perturbation",
    "bic_value",
    "fit_model",
    "initial_setup",
    "parameter_labels",
    "linearised",
    "rotation_noise_cov",
    "whitened_problem",
]

F = NDArray[np.float64]

#: Largest flange rotation (rad) between poses below which data count as one orientation
#: (the start then puts the target at the flange: its offset is not in the data).
ONE_ORIENTATION = 0.01
#: A set-up parameter held because base and tool could trade it (one flange orientation) is
#: estimated after all when the data fix it to this share of its prior σ (1 m, 1 rad).
WEAK_SETUP_SHARE = 0.01
#: Joint commands the base-and-tool registration of the health figures is computed over.
REGISTRATION_SAMPLES = 1000
#: The gauge's priority among the joints' constant motions, by motion (dx dy dz ex ey ez):
#: the zero offset (εz) first, then the DH-like offset along the axis (δz), length (δx) and
#: twist (εx), then the tilt about y and the shift along y: a constant another kept one
#: duplicates is held, so a joint's zero offset is kept and the previous joint's tilt about y
#: that carries the same rotation is held (docs/identify.md, "the gauge").
CONSTANT_PRIORITY = (2, 5, 1, 3, 4, 0)


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class ParameterPrior:
    """Prior standard deviations ``Σp`` of the parameter deviations (Eq. 8), nominal = 0.

    ``joint_*`` applies to every Chebyshev coefficient of a joint's error motions,
    ``setup_*`` to the base and tool corrections (the instrument set-up, nearly free).
    Effects use their own ``prior_sigma``.
    """

    joint_pos: float = 0.01  # m
    joint_rot: float = 0.01  # rad
    setup_pos: float = 1.0  # m
    setup_rot: float = 1.0  # rad

    def sigmas(self, spec: ErrorModelSpec) -> F:
        """Prior sigma of every Chebyshev coefficient, in the spec's layout."""
        idx = spec.index()
        setup = (idx[:, 0] == 0) | (idx[:, 0] == spec.n_joints + 1)
        rot = idx[:, 1] >= 3
        return np.where(
            setup,
            np.where(rot, self.setup_rot, self.setup_pos),
            np.where(rot, self.joint_rot, self.joint_pos),
        )


# --------------------------------------------------------------------------- result


@dataclass(frozen=True, eq=False)
class FittedModel:
    """An identified error model: estimate, covariance, residuals and fit statistics (SI).

    Attributes
    ----------
    coeffs : ndarray, shape (spec.n_params,)
        Chebyshev coefficients (m, rad) in ``spec.index()`` order.
    cov : ndarray, shape (n_all, n_all)
        Covariance of all parameters: Chebyshev coefficients, then each effect's parameters.
        Rows/columns of unidentifiable parameters are zero (they are held at zero).
    effect_params : list of ndarray
        One parameter vector per effect.
    residual_pos : ndarray, shape (n, 3), m
        Measured minus model position of every pose (instrument frame).
    residual_rot : ndarray, shape (n, 3), rad, or None
        Measured minus model orientation as a rotation vector ``log(R_meas R_modelᵀ)``.
    chi2 : float
        Eq. 8 at the estimate (data part plus prior part).
    chi2_data : float
        Data part only; compare with ``dof``.
    dof : int
        Number of residual components minus number of estimated parameters.
    bic : float
        Eq. 9 with whitened residuals.
    unidentifiable : tuple of str
        Labels of parameters held at zero because the data cannot determine them.
    """

    robot: RobotModel
    spec: ErrorModelSpec
    coeffs: F
    cov: F
    effects: tuple[Effect, ...]
    effect_params: list[F]
    T_instr_base0: F
    T_flange_target0: F
    residual_pos: F
    residual_rot: F | None
    chi2: float
    chi2_data: float
    dof: int
    bic: float
    rms_pos: float
    rms_rot: float | None
    n_iter: int
    converged: bool
    unidentifiable: tuple[str, ...]
    noise: InstrumentNoise = field(default_factory=InstrumentNoise)
    prior: ParameterPrior = field(default_factory=ParameterPrior)
    n_poses: int = 0
    held: tuple[str, ...] = ()  # labels held at their start value (e.g. a known base)
    reference_time: float | None = None  # s, ``time`` of the last pose fitted (drift's "now")

    # ---- parameter bookkeeping
    @property
    def labels(self) -> list[str]:
        """Names of all parameters, in the order of :attr:`cov`."""
        return parameter_labels(self.spec, self.effects)

    @property
    def params(self) -> F:
        """All parameters in one vector (Chebyshev, then effects)."""
        return np.concatenate([self.coeffs, *[np.asarray(p, float) for p in self.effect_params]])

    @property
    def sigma(self) -> F:
        """Standard uncertainty of every parameter."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def n_free(self) -> int:
        """Number of estimated (identifiable) parameters."""
        return int(self.params.size - len(self.unidentifiable) - len(self.held))

    @property
    def has_orientation(self) -> bool:
        """True if fitted to full-pose (7D) data."""
        return self.residual_rot is not None

    # ---- model evaluation
    def context(
        self,
        q: ArrayLike,
        *,
        approach: ArrayLike | None = None,
        **conditions: ArrayLike | None,
    ) -> EffectContext:
        """Effect context for joint commands ``q`` (approach from the sequence if not given)
        at ``conditions`` (``time``, ``temp``, ``joint_temp``, ``joint_torque``: the
        channels of :data:`~quickhealth.identify.effects.CONDITIONS`)."""
        q = np.atleast_2d(np.asarray(q, float))
        return _context(self.robot, q, approach, conditions)

    def predict(
        self,
        q: ArrayLike,
        *,
        approach: ArrayLike | None = None,
        **conditions: ArrayLike | None,
    ) -> F:
        """Model pose of the target in the instrument frame, ``T_instr_target``, shape (n, 4, 4).

        ``q`` in rad, shape (n, nj); ``approach`` (+1/−1 per joint) defaults to the direction
        each joint moved from the previous row (the first row counts as from below);
        ``conditions`` as :meth:`context` (``time=``, ``temp=`` …; ``**meas.conditions()``).
        """
        q = np.atleast_2d(np.asarray(q, float))
        pert = self._perturbation(q, approach, conditions)
        T = loop_pose(
            self.robot, self.spec, self.coeffs, self.T_instr_base0, self.T_flange_target0, q, pert
        )
        return T

    def tcp_error(self, q: ArrayLike, **kwargs: ArrayLike | None) -> F:
        """Predicted TCP position error (m), shape (n,): the robot's model minus its nominal
        kinematics after the best rigid registration of base and tool (:attr:`registration`).

        Gauge-free: error that base, tool and the joints' constant terms can trade between
        them does not change it.  Instrument-side effects (depth scale, drift) are not robot
        errors and are left out.
        """
        return np.linalg.norm(self.tcp_error_vector(q, **kwargs), axis=-1)

    def tcp_error_vector(self, q: ArrayLike, **kwargs: ArrayLike | None) -> F:
        """Model minus registered nominal target position (m, instrument frame), shape (n, 3)."""
        q = np.atleast_2d(np.asarray(q, float))
        T = self.robot_pose(q, **kwargs)
        return T[:, :3, 3] - self.nominal_pose(q)[:, :3, 3]

    def tcp_rotation_error(self, q: ArrayLike, **kwargs: ArrayLike | None) -> F:
        """Model minus registered nominal target orientation, rotation vectors (rad), (n, 3)."""
        q = np.atleast_2d(np.asarray(q, float))
        T = self.robot_pose(q, **kwargs)
        N = self.nominal_pose(q)
        return log_so3(T[:, :3, :3] @ np.swapaxes(N[:, :3, :3], -1, -2))

    def robot_pose(
        self,
        q: ArrayLike,
        *,
        approach: ArrayLike | None = None,
        **conditions: ArrayLike | None,
    ) -> F:
        """The model pose with the robot's own effects only (no depth scale, no drift),
        ``T_instr_target`` (n, 4, 4)."""
        q = np.atleast_2d(np.asarray(q, float))
        pert = self._perturbation(q, approach, conditions)
        robot_pert = pert.robot_only()
        return loop_pose(
            self.robot,
            self.spec,
            self.coeffs,
            self.T_instr_base0,
            self.T_flange_target0,
            q,
            robot_pert,
        )

    def nominal_pose(self, q: ArrayLike) -> F:
        """Nominal kinematics with the registered base and tool, ``T_instr_target`` (n, 4, 4)."""
        q = np.atleast_2d(np.asarray(q, float))
        T_ib, T_ft = self.registration
        return T_ib @ self.robot.fk(q).reshape(-1, 4, 4) @ T_ft

    @cached_property
    def registration(self) -> tuple[F, F]:
        """Base and tool ``(T_instr_base, T_flange_target)`` that bring the nominal robot
        closest to this model over its identified joint ranges.

        Least squares of the target positions at :data:`REGISTRATION_SAMPLES` joint commands
        drawn uniformly over ``spec``'s ranges (fixed seed), of the nominal robot against the
        model's robot (its error motions and robot effects: a backlash at the middle of its
        play, approach 0; thermal at 20 °C; the instrument's depth scale and drift left
        out); then the tool rotation that best matches the model's orientations.  Every
        health figure is the model against this nominal robot, so it does not depend on how
        the fit split error between base, tool and joint constants, nor on whether an
        effect's mean was fitted as an effect or as Chebyshev terms.
        """
        rng = np.random.default_rng(0)
        spec = self.spec
        q = rng.uniform(spec.q_lo, spec.q_hi, (REGISTRATION_SAMPLES, spec.n_joints))
        return self.registration_over(q)

    def registration_over(self, q: ArrayLike) -> tuple[F, F]:
        """:attr:`registration` over the joint commands ``q`` (n, nj) instead of the uniform
        samples of the identified ranges (a fixed evaluation set, e.g. a baseline's poses)."""
        q = np.atleast_2d(np.asarray(q, float))
        spec = self.spec
        needs = {col for e in self.effects for col in e.requires()}
        T = self.robot_pose(
            q,
            approach=np.zeros_like(q),
            **reference_conditions(needs, self.robot, q, self.reference_time),
        )
        T_bf = self.robot.fk(q).reshape(-1, 4, 4)
        Rf, pf = T_bf[:, :3, :3], T_bf[:, :3, 3]
        start_b = self.T_instr_base0 @ small_error_transform(
            *np.split(constant_motions(spec, self.coeffs, 0), 2)
        )
        start_t = self.T_flange_target0 @ small_error_transform(
            *np.split(constant_motions(spec, self.coeffs, -1), 2)
        )
        Rb, pb, t = _polish_positions(
            Rf, pf, T[:, :3, 3], start_b[:3, :3], start_b[:3, 3], start_t[:3, 3], n_iter=20
        )
        M = (np.swapaxes(Rf, -1, -2) @ Rb.T[None] @ T[:, :3, :3]).mean(0)
        return make_T(Rb, pb), make_T(_nearest_rotation(M), t)

    def _perturbation(
        self, q: F, approach: ArrayLike | None, conditions: Mapping[str, ArrayLike | None]
    ) -> Perturbation:
        if not self.effects:
            return Perturbation()
        ctx = _context(self.robot, q, approach, conditions)
        return total_perturbation(self.effects, self.effect_params, ctx)

    def summary(self) -> list[str]:
        """The lines the CLI, the TUI and report.json show."""
        n = self.n_poses
        lines = [
            f"poses: {n} ({'full pose' if self.has_orientation else 'position only'}), "
            f"parameters: {self.n_free} estimated of {self.params.size}",
            f"rms position residual: {self.rms_pos * 1e3:.4f} mm"
            + (
                f", rms rotation residual: {self.rms_rot * 1e3:.4f} mrad ({np.degrees(self.rms_rot):.5f} deg)"
                if self.rms_rot is not None
                else ""
            ),
            f"chi2 (data): {self.chi2_data:.1f} for {self.dof} degrees of freedom "
            f"(ratio {self.chi2_data / max(self.dof, 1):.2f}); BIC {self.bic:.1f}",
            f"converged: {'yes' if self.converged else 'NO'} after {self.n_iter} iterations",
        ]
        if self.effects:
            lines.append("effects: " + ", ".join(e.name for e in self.effects))
            for e in self.effects:  # an effect may say which form it took and what it identified
                lines += e.describe_fit(self)
        if self.held:
            lines.append(f"held at their known values: {len(self.held)} parameters")
        if self.unidentifiable:
            shown = ", ".join(self.unidentifiable[:12])
            more = len(self.unidentifiable) - 12
            lines.append(
                f"not identifiable from this data (held at 0): {shown}"
                + (f" and {more} more" if more > 0 else "")
            )
        return lines


# --------------------------------------------------------------------------- public functions


def fit_model(
    robot: RobotModel,
    meas: Measurements,
    spec: ErrorModelSpec,
    effects: Sequence[Effect] = (),
    noise: InstrumentNoise = InstrumentNoise(),
    prior: ParameterPrior = ParameterPrior(),
    *,
    init: FittedModel | None = None,
    setup: tuple[ArrayLike, ArrayLike] | None = None,
    hold: Sequence[str] = (),
    rank_tol: float = 1e-3,
    max_iter: int = 50,
    tol: float = 1e-9,
) -> FittedModel:
    """Maximum-likelihood estimate of the error model and effect parameters (Eq. 8).

    Parameters
    ----------
    robot : RobotModel
    meas : Measurements
        Position-only or full-pose measurements in execution order.
    spec : ErrorModelSpec
        Orders of every error motion and the joint ranges of the Chebyshev mapping.
    effects : sequence of Effect
        Physical effects added to the Chebyshev model (fitted with their ``prior_sigma``).
    noise : InstrumentNoise
        Instrument defaults, used where ``meas`` has no per-row uncertainties.
    prior : ParameterPrior
        Prior standard deviations of the coefficients.
    init : FittedModel, optional
        Warm start: base/tool and every coefficient with the same label are taken from it.
    setup : (T_instr_base0, T_flange_target0), optional
        Known base and tool start transforms instead of the robust start (e.g. a camera
        pose measured independently).
    hold : sequence of str
        Labels of parameters held at their start value (0, or ``init``'s), e.g. all
        ``base.*`` labels when the base is known: joint-1 constants that would otherwise be
        a base motion (``j1.ez.c0``, the encoder zero offset) then become identifiable.
    rank_tol : float
        Relative size below which a column of the normalised Jacobian counts as not adding
        a new direction (unidentifiable).

    Returns
    -------
    FittedModel

    Raises
    ------
    InputError
        Joint count mismatch, or fewer measured components than identifiable parameters.
    """
    effects = tuple(effects)
    if meas.n_joints != robot.n_joints:
        raise InputError(
            f"measurements have {meas.n_joints} joints, robot {robot.name!r} has {robot.n_joints}"
        )
    if spec.n_joints != robot.n_joints:
        raise InputError(f"error model has {spec.n_joints} joints, robot has {robot.n_joints}")
    for e in effects:
        for col in missing_channels(e, meas):
            raise InputError(f"effect {e.name!r} needs the {col!r} column in the measurements")
    labels = parameter_labels(spec, effects)
    unknown = sorted(set(hold) - set(labels))
    if unknown:
        raise InputError(f"cannot hold unknown parameters: {', '.join(unknown)}")
    prob = _Problem.build(robot, meas, spec, effects, noise, prior, init, setup)
    prob.held = prob._held() | np.array([lb in set(hold) for lb in labels], dtype=bool)
    return prob.solve(rank_tol=rank_tol, max_iter=max_iter, tol=tol)


@dataclass(frozen=True, eq=False)
class Linearisation:
    """The whitened problem of a fitted model on data, linearised at its estimate.

    Attributes
    ----------
    r : ndarray, shape (n·d,)
        Whitened residual ``Σx^{-1/2} (measured − model)``, pose by pose.
    J : ndarray, shape (n·d, n_all)
        Jacobian of the whitened *model* w.r.t. every parameter of ``fitted.labels`` (SI).
    J_motion : ndarray, shape (n, d, nj, 6)
        Whitened model Jacobian of every joint's six error motions (for the order search).
    u : ndarray, shape (n, nj)
        Chebyshev argument of every joint reading.
    sigma_p : ndarray, shape (n_all,)
        Prior standard deviations of the parameters.
    d : int
        Residual components per pose (6 full pose, 3 position only).
    W : ndarray, shape (n, d, d)
        The whitening ``Σx,i^{-1/2}`` of every pose (:func:`~.linearize.noise_covariance`).
    """

    r: F
    J: F
    J_motion: F
    u: F
    sigma_p: F
    d: int
    W: F

    @property
    def cov(self) -> F:
        """The measurement covariance ``Σx,i`` (n, d, d) the fit weights every pose with."""
        L = np.linalg.inv(self.W)
        return L @ np.swapaxes(L, -1, -2)


def linearised(fitted: FittedModel, meas: Measurements) -> Linearisation:
    """The fit's own whitened residual and Jacobians of ``fitted`` on ``meas`` (same noise model,
    same loop), for the order search and anything else that scores changes of the model."""
    prob = _Problem.build(
        fitted.robot, meas, fitted.spec, fitted.effects, fitted.noise, fitted.prior, fitted
    )
    r, J, Jw, u = prob.linearisation(fitted.params)
    assert prob.W is not None
    return Linearisation(r, J, Jw, u, prob.sigma_p, prob.d, prob.W)


def whitened_problem(fitted: FittedModel, meas: Measurements) -> tuple[F, F, list[str]]:
    """Whitened residuals and their Jacobian w.r.t. all parameters at the estimate.

    Returns
    -------
    r : ndarray, shape (m,)
        ``Σx^{-1/2} (measured − model)`` stacked pose by pose (3 or 6 components each).
    J : ndarray, shape (m, n_all)
        ``∂r/∂p`` for every parameter of ``fitted.labels`` (SI units), data rows only
        (the prior rows of Eq. 8 are not included).
    labels : list of str
    """
    prob = _Problem.build(
        fitted.robot,
        meas,
        fitted.spec,
        fitted.effects,
        fitted.noise,
        fitted.prior,
        fitted,
    )
    r, Jm = prob.residual_and_jacobian(fitted.params)
    return r, -Jm, fitted.labels


def initial_setup(robot: RobotModel, meas: Measurements, n_iter: int = 30) -> tuple[F, F]:
    """Robust start for base and tool from the data alone: ``(T_instr_base0, T_flange_target0)``.

    Closed form first, so no start guess is needed however far and turned the instrument is:

    - full pose: hand-eye registration ``R_meas,i = R_B R_flange,i R_X`` as one homogeneous
      linear system in the 18 entries of ``R_B`` and ``R_Xᵀ`` (its null vector, projected on
      SO(3)), then base and tool translations by linear least squares;
    - position only: ``p_i = R_B (R_flange,i t + p_flange,i) + p_B`` is linear in ``R_B``,
      ``p_B`` and the nine products ``R_B e_j t_k``: one 13-column least-squares problem per
      coordinate; ``R_B`` projected on SO(3), ``t`` read from the products.

    Then a few Gauss-Newton steps on the positions polish base and tool point with the
    nominal kinematics.  Data too poor for the closed form (every flange orientation nearly
    the same) fall back to Kabsch of the flange positions with alternating least squares.
    """
    T_bf = robot.fk(meas.q)
    if T_bf.ndim == 2:
        T_bf = T_bf[None]
    Rf, pf = T_bf[:, :3, :3], T_bf[:, :3, 3]
    P = meas.pos
    spread = float(np.max(np.linalg.norm(log_so3(np.swapaxes(Rf[:1], -1, -2) @ Rf), axis=-1)))
    if spread < ONE_ORIENTATION:
        # one flange orientation throughout (an ISO 9283 cube): the target's offset on the
        # flange moves every measured point alike, as the base's position does, so the data
        # cannot tell them apart.  The start puts the target at the flange (its offset 0:
        # least wrong of all, where a least-squares split gave 2 m) and the fit estimates the
        # offset from what the robot's errors turn (:meth:`_Problem.solve`, second pass)
        T_ib = kabsch(pf, P)
        Rb, pb, t = T_ib[:3, :3], T_ib[:3, 3], np.zeros(3)
    else:
        closed = (
            _hand_eye(Rf, pf, meas.R, P) if meas.has_orientation else _point_hand_eye(Rf, pf, P)
        )
        if closed is None:
            Rb, pb, t = _kabsch_alternating(Rf, pf, P, n_iter)
        else:
            Rb, pb, t = closed
        Rb, pb, t = _polish_positions(Rf, pf, P, Rb, pb, t)
    Rt = np.eye(3)
    if meas.has_orientation:  # tool rotation: polar decomposition of the mean R_fᵀ R_bᵀ R_meas
        M = (np.swapaxes(Rf, -1, -2) @ Rb.T[None] @ meas.R).mean(0)
        Rt = _nearest_rotation(M)
    return make_T(Rb, pb), make_T(Rt, t)


def _nearest_rotation(M: F) -> F:
    """The rotation closest to ``M`` in the Frobenius norm (polar decomposition)."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def _hand_eye(Rf: F, pf: F, Rm: F, P: F) -> tuple[F, F, F] | None:
    """Closed-form ``R_m,i = R_B R_f,i R_X`` and ``p_i = R_B (R_f,i t + p_f,i) + p_B``."""
    n = Rf.shape[0]
    # R_m R_Xᵀ − R_B R_f = 0, column-major vec: (I ⊗ R_m) vec(R_Xᵀ) − (R_fᵀ ⊗ I) vec(R_B) = 0
    A = np.concatenate(
        [
            np.einsum("ab,nij->naibj", np.eye(3), Rm).reshape(n, 9, 9),
            -np.einsum("nji,ab->niajb", Rf, np.eye(3)).reshape(n, 9, 9),
        ],
        axis=2,
    )
    G = np.einsum("nki,nkj->ij", A, A)
    w, V = np.linalg.eigh(G)
    if not w[1] > 1e-8 * max(w[-1], 1e-300):  # a two-dimensional null space: not determined
        return None
    v = V[:, 0]
    Rxt = v[:9].reshape(3, 3, order="F")
    Rb = v[9:].reshape(3, 3, order="F")
    sign = np.sign(np.linalg.det(Rb)) or 1.0
    Rb = _nearest_rotation(sign * Rb)
    Rx = _nearest_rotation(sign * Rxt).T
    del Rx  # the rotation is refined from the mean after the translations (initial_setup)
    X = np.concatenate([Rb[None] @ Rf, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)
    sol = np.linalg.lstsq(X.reshape(-1, 6), (P - pf @ Rb.T).reshape(-1), rcond=None)[0]
    return Rb, sol[3:], sol[:3]


def _point_hand_eye(Rf: F, pf: F, P: F) -> tuple[F, F, F] | None:
    """Closed-form base and tool point from positions: linear in ``R_B``, ``p_B``, ``R_B e_j t_k``."""
    n = Rf.shape[0]
    X = np.concatenate([pf, np.ones((n, 1)), Rf.reshape(n, 9)], axis=1)  # (n, 13)
    sv = np.linalg.svd(X, compute_uv=False)
    if n < 13 or not sv[-1] > 1e-6 * sv[0]:  # flange orientations too alike
        return None
    theta = np.linalg.lstsq(X, P, rcond=None)[0]  # (13, 3): column a = row a of the model
    Rb = _nearest_rotation(theta[:3].T)
    pb = theta[3]
    K = theta[4:].reshape(3, 3, 3)  # K[j, k] = R_B e_j t_k
    t = np.einsum("aj,jka->k", Rb, K) / 3.0
    return Rb, pb, t


def _kabsch_alternating(Rf: F, pf: F, P: F, n_iter: int) -> tuple[F, F, F]:
    """Fallback start: Kabsch of the flange positions, then alternating least squares."""
    T_ib = kabsch(pf, P)
    t = np.zeros(3)
    for _ in range(n_iter):
        Rb, pb = T_ib[:3, :3], T_ib[:3, 3]
        A = (Rb[None] @ Rf).reshape(-1, 3)
        b = (P - pb - pf @ Rb.T).reshape(-1)
        t_new = np.linalg.lstsq(A, b, rcond=None)[0]
        T_ib = kabsch(pf + (Rf @ t_new), P)
        done = np.linalg.norm(t_new - t) < 1e-9
        t = t_new
        if done:
            break
    return T_ib[:3, :3], T_ib[:3, 3], t


def _polish_positions(Rf: F, pf: F, P: F, Rb: F, pb: F, t: F, n_iter: int = 6) -> tuple[F, F, F]:
    """Gauss-Newton on ``p_i = R_B (R_f,i t + p_f,i) + p_B`` (base rotation, base and tool
    translation), from a close start; a step that does not lower the residual ends it."""
    n = Rf.shape[0]

    def resid(Rb_: F, pb_: F, t_: F) -> F:
        return P - ((Rf @ t_ + pf) @ Rb_.T + pb_)

    r = resid(Rb, pb, t)
    cost = float(np.sum(r * r))
    for _ in range(n_iter):
        y = (Rf @ t + pf) @ Rb.T  # R_B y_i
        J = np.concatenate(
            [-skew(y), np.broadcast_to(np.eye(3), (n, 3, 3)), Rb[None] @ Rf], axis=2
        ).reshape(-1, 9)
        step = np.linalg.lstsq(J, r.reshape(-1), rcond=None)[0]
        Rb2 = exp_so3(step[:3]) @ Rb
        pb2, t2 = pb + step[3:6], t + step[6:]
        r2 = resid(Rb2, pb2, t2)
        c2 = float(np.sum(r2 * r2))
        if not c2 < cost:
            break
        Rb, pb, t, r, cost = Rb2, pb2, t2, r2, c2
        if np.linalg.norm(step) < 1e-12:
            break
    return Rb, pb, t


# --------------------------------------------------------------------------- internals


def parameter_labels(spec: ErrorModelSpec, effects: Sequence[Effect]) -> list[str]:
    """Names of all parameters: the Chebyshev coefficients, then each effect's ``name.param``."""
    out = spec.labels()
    for e in effects:
        out += [f"{e.name}.{n}" for n in e.param_names]
    return out


def _context(
    robot: RobotModel,
    q: F,
    approach: ArrayLike | None,
    conditions: Mapping[str, ArrayLike | None],
) -> EffectContext:
    unknown = set(conditions) - set(CONDITIONS)
    if unknown:
        raise TypeError(f"unknown conditions {sorted(unknown)}; known: {', '.join(CONDITIONS)}")
    return effect_context(robot, q, approach, **conditions)  # type: ignore[arg-type]


@dataclass(eq=False)
class _Problem:
    """The stacked, whitened least-squares problem of one fit (scratch, not a result)."""

    robot: RobotModel
    meas: Measurements
    spec: ErrorModelSpec
    effects: tuple[Effect, ...]
    noise: InstrumentNoise
    prior: ParameterPrior
    T_ib0: F
    T_ft0: F
    p0: F
    sigma_p: F
    ctx: EffectContext | None
    d: int
    Rm: F | None
    W: F | None = None  # (n, d, d) whitening matrices
    held: NDArray[np.bool_] | None = None  # parameters held at their start value
    W_diag: F | bool | None = None  # (n, d) when every W_i is diagonal, False if not

    @classmethod
    def build(
        cls,
        robot: RobotModel,
        meas: Measurements,
        spec: ErrorModelSpec,
        effects: tuple[Effect, ...],
        noise: InstrumentNoise,
        prior: ParameterPrior,
        init: FittedModel | None,
        setup: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> _Problem:
        labels = parameter_labels(spec, effects)
        p0 = np.zeros(len(labels))
        held = np.zeros(len(labels), dtype=bool)
        if init is not None:
            T_ib0, T_ft0 = init.T_instr_base0, init.T_flange_target0
            old = dict(zip(init.labels, init.params, strict=True))
            p0 = np.array([old.get(lb, 0.0) for lb in labels])
            held = np.array([lb in set(init.held) for lb in labels], dtype=bool)
        elif setup is not None:
            T_ib0, T_ft0 = (np.asarray(t, float) for t in setup)
        else:
            T_ib0, T_ft0 = initial_setup(robot, meas)
        sig = [prior.sigmas(spec)] + [np.asarray(e.prior_sigma, float) for e in effects]
        ctx = _context(robot, meas.q, meas.approach_sign(), meas.conditions()) if effects else None
        d = 6 if meas.has_orientation else 3
        prob = cls(
            robot=robot,
            meas=meas,
            spec=spec,
            effects=effects,
            noise=noise,
            prior=prior,
            T_ib0=np.asarray(T_ib0, float),
            T_ft0=np.asarray(T_ft0, float),
            p0=p0,
            sigma_p=np.concatenate(sig),
            ctx=ctx,
            d=d,
            Rm=meas.R if meas.has_orientation else None,
            held=held,
        )
        return prob

    # ---- model pieces
    def _split(self, p: F) -> tuple[F, list[F]]:
        nc = self.spec.n_params
        out, pos = [], nc
        for e in self.effects:
            out.append(p[pos : pos + e.n_params])
            pos += e.n_params
        return p[:nc], out

    def _pert(self, eparams: list[F]) -> Perturbation:
        if not self.effects:
            return Perturbation()
        assert self.ctx is not None
        return total_perturbation(self.effects, eparams, self.ctx)

    def _raw_residual(self, T: F) -> F:
        """Measured minus model, (n, d): position (m) then rotation vector (rad)."""
        return pose_residuals(self.meas, T)

    def _whitening(self, T: F, A: F, scale_z: F | None) -> F:
        """Per-pose ``L⁻¹`` with ``L Lᵀ = Σx,i`` (:func:`~.linearize.noise_covariance`)."""
        Jq = joint_angle_jacobian(T, A, scale_z) if self.noise.sigma_q > 0 else None
        return Whitening.of(noise_covariance(self.meas, self.noise, Jq)).W

    def _white(self, X: F, *, in_place: bool = False) -> F:
        """``W_i X_i`` for every pose; ``X`` (n, d, ...).  Elementwise when every ``W_i`` is
        diagonal (no encoder noise, isotropic or per-axis instrument noise): 20× faster.
        ``in_place``: ``X`` is a temporary of the caller's and is overwritten where the
        whitening is elementwise (a new array of its size costs more in page faults than the
        product itself at thousands of poses)."""
        assert self.W is not None
        if self.W_diag is None:
            off = self.W - np.einsum("nii->ni", self.W)[..., None] * np.eye(self.d)
            self.W_diag = np.einsum("nii->ni", self.W) if not np.any(off) else False
        if self.W_diag is False:
            if X.ndim == 2:
                return np.matmul(self.W, X[..., None])[..., 0]
            flat = X.reshape(X.shape[0], X.shape[1], -1)
            return np.matmul(self.W, flat).reshape(X.shape)
        w = self.W_diag.reshape(self.W_diag.shape + (1,) * (X.ndim - 2))
        if in_place:
            X *= w
            return X
        return X * w

    def _loop(self, p: F) -> tuple[F, list[F], Perturbation, F, F, F, F]:
        """One forward pass at ``p``: coefficients, effect parameters, perturbation, ``T``,
        ``A``, motions and the raw residual; the whitening is made on the first call."""
        coeffs, ep = self._split(p)
        pert = self._pert(ep)
        T, A, mot = forward(
            self.robot, self.spec, coeffs, self.T_ib0, self.T_ft0, self.meas.q, pert
        )
        assert A is not None and mot is not None
        if self.W is None:
            self.W = self._whitening(T, A, pert.instr_scale_z)
        return coeffs, ep, pert, T, A, mot, self._raw_residual(T)

    def residual_and_jacobian(self, p: F) -> tuple[F, F]:
        """Whitened residual (m,) and Jacobian of the whitened *model* (m, n_all), SI units."""
        return self._residual_and_jacobian(self._loop(p))

    def _residual_and_jacobian(
        self, loop: tuple[F, list[F], Perturbation, F, F, F, F]
    ) -> tuple[F, F]:
        coeffs, _, pert, T, A, mot, raw = loop
        n, d = self.meas.n_poses, self.d
        r = self._white(raw).reshape(-1)
        Jmot = motion_jacobian(T, A, mot, pert.instr_scale_z)[:, :d]  # (n, d, nf, 6)
        Jc = self._coeff_columns(Jmot)  # (n, d, nc)
        cols = [Jc]
        if self.effects:
            cols.append(self._effect_columns(coeffs, pert, (T, A, mot)))
        Jraw = np.concatenate(cols, axis=-1) if len(cols) > 1 else Jc
        if d == 6:  # ∂ log(R_meas R_modelᵀ) = −J_r⁻¹(w) ω with J_r⁻¹(w) ≈ I + ½[w]×
            Jraw[:, 3:] = (np.eye(3) + 0.5 * skew(raw[:, 3:])) @ Jraw[:, 3:]
        J = self._white(Jraw, in_place=True).reshape(n * d, -1)
        return r, J

    def linearisation(self, p: F) -> tuple[F, F, F, F]:
        """Whitened residual (m,) and model Jacobian (m, n_all), the whitened Jacobian of the
        joint motions (n, d, nj, 6) and Chebyshev ``u`` of every joint (n, nj): one pass."""
        loop = self._loop(p)
        r, J = self._residual_and_jacobian(loop)
        _, _, pert, T, A, mot, _ = loop
        Jmot = motion_jacobian(T, A, mot, pert.instr_scale_z)[:, : self.d, 1:-1]
        u = chebyshev_u(self.meas.q, self.spec.q_lo, self.spec.q_hi)
        return r, J, self._white(Jmot), u

    def _coeff_columns(self, Jmot: F) -> F:
        return coefficient_columns(self.spec, self.meas.q, Jmot)

    def _effect_columns(self, coeffs: F, pert: Perturbation, loop: tuple[F, F, F]) -> F:
        """∂model/∂(every effect parameter), (n, d, k): :func:`~.linearize.effect_jacobian`
        through the loop's sensitivities to the channels the effects use."""
        assert self.ctx is not None
        sens = sensitivities(
            self.robot,
            self.spec,
            coeffs,
            self.T_ib0,
            self.T_ft0,
            self.meas.q,
            pert,
            channels=effect_channels(self.effects, self.ctx),
            loop=loop,
        )
        cols = [effect_jacobian(e, self.ctx, sens)[:, : self.d] for e in self.effects]
        return np.concatenate(cols, axis=-1)

    # ---- identifiability
    def identifiable(self, J: F, rank_tol: float) -> NDArray[np.bool_]:
        """Mask of parameters that add a new direction, in the priority order of the module doc."""
        spec = self.spec
        idx = spec.index()
        nc = spec.n_params
        nall = J.shape[1]
        setup_rank = np.where(idx[:, 0] == 0, 0, np.where(idx[:, 0] == spec.n_joints + 1, 1, 2))
        # joint constants motion by motion in CONSTANT_PRIORITY (every zero offset before any
        # tilt that duplicates one), higher orders frame by frame
        const = (setup_rank == 2) & (idx[:, 2] == 0)
        mrank = np.asarray(CONSTANT_PRIORITY)[idx[:, 1]]
        key = np.zeros((nall, 5))
        key[:nc] = np.stack(
            [setup_rank, idx[:, 2], np.where(const, mrank, 0), idx[:, 0], idx[:, 1]], 1
        )
        key[nc:] = [3, 0, 0, 0, 0]
        order = np.lexsort((np.arange(nall), key[:, 4], key[:, 3], key[:, 2], key[:, 1], key[:, 0]))
        # on the Gram matrix, permuted and scaled: a permuted, normalised copy of the tall
        # J cost more than the product itself
        G = (J.T @ J)[np.ix_(order, order)]
        norms = np.sqrt(np.diag(G))
        scale = np.where(norms > 0, norms, 1.0)
        ok_sorted = sequential_independent_gram(G / np.outer(scale, scale), rank_tol) & (norms > 0)
        ok = np.zeros(nall, bool)
        ok[order] = ok_sorted
        return ok

    def _held(self) -> NDArray[np.bool_]:
        return self.held if self.held is not None else np.zeros(self.p0.size, bool)

    # ---- solve
    def structural(self, p: F) -> F:
        """``p`` with every joint coefficient and effect parameter at zero (base and tool kept):
        the nominal robot the identifiable set is judged at."""
        idx = self.spec.index()
        setup = (idx[:, 0] == 0) | (idx[:, 0] == self.spec.n_joints + 1)
        out = np.zeros_like(p)
        out[: self.spec.n_params][setup] = p[: self.spec.n_params][setup]
        return out

    def solve(self, rank_tol: float, max_iter: int, tol: float) -> FittedModel:
        p = self.p0.copy()
        # Which parameters the data can identify is a property of the structure (the nominal
        # robot, the poses, the noise), judged at the nominal robot, not at an estimate: at
        # an estimate the parallel axes of a UR are slightly tilted, so exact dependencies
        # (a zero offset of joint 4 beside those of joints 2 and 3) pass the test by 1e-3
        # there, and a warm start then crawled along them for 50 iterations.
        p_nom = self.structural(p)
        r, J = self.residual_and_jacobian(p_nom)
        held = self.held if self.held is not None else np.zeros(p.size, bool)
        Jq = J.copy()
        Jq[:, held] = 0.0  # held columns add no direction; they are not reported
        free = self.identifiable(Jq, rank_tol) & ~held
        labels = parameter_labels(self.spec, self.effects)
        n_comp = r.size
        n_free = int(free.sum())
        need = n_free + max(2 * self.d, n_free // 4)
        if n_comp < need:
            raise InputError(
                f"{self.meas.n_poses} poses give {n_comp} measured components, too few for a "
                f"model with {n_free} identifiable parameters (needs at least "
                f"{-(-need // self.d)} poses): measure more poses or lower the orders"
            )
        p[~free & ~held] = 0.0
        if np.any(p != p_nom):  # a warm start: linearise at the start point
            r, J = self.residual_and_jacobian(p)
        p, r, J, it, converged = self._iterate(p, r, J, free, max_iter, tol)
        weak = self._weak_setup(J, free, held)
        if np.any(weak):  # second pass: the set-up directions the data fix after all
            free = free | weak
            p, r, J, it2, converged = self._iterate(p, r, J, free, max_iter, tol)
            it += it2
        D = self.sigma_p[free]
        # covariance at the estimate
        Jf = J[:, free] * D
        H = Jf.T @ Jf
        H[np.diag_indices_from(H)] += 1.0
        Hinv = _spd_solve(H, np.eye(H.shape[0]))
        cov = np.zeros((p.size, p.size))
        cov[np.ix_(free, free)] = D[:, None] * Hinv * D[None, :]
        return self._result(p, r, cov, free, labels, it, converged)

    def _iterate(
        self, p: F, r: F, J: F, free: NDArray[np.bool_], max_iter: int, tol: float
    ) -> tuple[F, F, F, int, bool]:
        """Levenberg–Marquardt on the ``free`` parameters from ``p`` (its residual ``r`` and
        Jacobian ``J``); returns the estimate, its residual and Jacobian, the iterations and
        whether it converged."""
        D = self.sigma_p[free]
        lam = 0.0  # Gauss-Newton first (the loop is nearly linear); damp only on failure
        converged = False
        it = 0

        def cost(r_: F, p_: F) -> float:
            return float(r_ @ r_ + np.sum((p_ / self.sigma_p)[free] ** 2))

        c = cost(r, p)
        for it in range(1, max_iter + 1):  # noqa: B007
            Jf = J[:, free] * D  # normalised columns z = p / σp
            z = p[free] / D
            H = Jf.T @ Jf
            g = Jf.T @ r - z
            H[np.diag_indices_from(H)] += 1.0
            accepted = False
            at_minimum = False
            for _ in range(14):
                Hd = H.copy()
                Hd[np.diag_indices_from(Hd)] += lam * np.diag(H)
                dz = _spd_solve(Hd, g)
                # the quadratic model's decrease: when even the Gauss-Newton step promises
                # nothing, this is the minimum (trying it only met rounding: 14 evaluations
                # of a rejected step ended every fit of real data)
                if lam == 0.0 and 2.0 * g @ dz - dz @ (H @ dz) <= tol * c:
                    at_minimum = True
                    break
                p_try = p.copy()
                p_try[free] += dz * D
                loop = self._loop(p_try)  # the Jacobian only for a step that is taken
                r_try = self._white(loop[-1]).reshape(-1)
                c_try = cost(r_try, p_try)
                if c_try <= c:
                    accepted = True
                    r_try, J_try = self._residual_and_jacobian(loop)
                    break
                lam = max(lam * 10.0, 1e-6)
            if at_minimum or not accepted:
                converged = True  # no descent direction left: at the minimum to precision
                break
            rel = (c - c_try) / max(c, 1e-300)
            p, r, J, c = p_try, r_try, J_try, c_try
            lam = lam / 10.0 if lam > 1e-9 else 0.0
            if rel < tol or np.linalg.norm(dz) < 1e-10 * (1 + np.linalg.norm(z)):
                converged = True
                break
        return p, r, J, it, converged

    def _weak_setup(
        self, J: F, free: NDArray[np.bool_], held: NDArray[np.bool_]
    ) -> NDArray[np.bool_]:
        """Set-up parameters (base, tool) held because, at the nominal robot, another set-up
        parameter moves every pose alike (one flange orientation: the target's offset and the
        base's position), but which the data fix at the estimate through what the robot's
        errors turn: their σ given the free parameters below :data:`WEAK_SETUP_SHARE` of the
        prior's.  A direction the data cannot see at all (a tool rotation seen by positions
        only) stays held."""
        idx = self.spec.index()
        nc = self.spec.n_params
        setup = np.zeros(J.shape[1], bool)
        setup[:nc] = (idx[:, 0] == 0) | (idx[:, 0] == self.spec.n_joints + 1)
        cand = np.flatnonzero(setup & ~free & ~held)
        if cand.size == 0:
            return np.zeros(J.shape[1], bool)
        Jf = J[:, free]
        proj = np.linalg.lstsq(Jf, J[:, cand], rcond=None)[0]
        rest = J[:, cand] - Jf @ proj
        info = np.sum(rest**2, axis=0) + self.sigma_p[cand] ** -2.0
        out = np.zeros(J.shape[1], bool)
        out[cand] = 1.0 / np.sqrt(info) < WEAK_SETUP_SHARE * self.sigma_p[cand]
        return out

    def _result(
        self,
        p: F,
        r: F,
        cov: F,
        free: NDArray[np.bool_],
        labels: list[str],
        n_iter: int,
        converged: bool,
    ) -> FittedModel:
        coeffs, ep = self._split(p)
        T = loop_pose(
            self.robot, self.spec, coeffs, self.T_ib0, self.T_ft0, self.meas.q, self._pert(ep)
        )
        raw = self._raw_residual(T)
        n, d = self.meas.n_poses, self.d
        Rw = r.reshape(n, d)
        chi2_data = float(r @ r)
        chi2 = chi2_data + float(np.sum((p / self.sigma_p)[free] ** 2))
        n_free = int(free.sum())
        return FittedModel(
            robot=self.robot,
            spec=self.spec,
            coeffs=coeffs.copy(),
            cov=cov,
            effects=self.effects,
            effect_params=[x.copy() for x in ep],
            T_instr_base0=self.T_ib0,
            T_flange_target0=self.T_ft0,
            residual_pos=raw[:, :3],
            residual_rot=raw[:, 3:] if d == 6 else None,
            chi2=chi2,
            chi2_data=chi2_data,
            dof=int(r.size - n_free),
            bic=bic_value(Rw, n_free, float(np.sum(raw**2))),
            rms_pos=float(np.sqrt(np.mean(np.sum(raw[:, :3] ** 2, axis=1)))),
            rms_rot=float(np.sqrt(np.mean(np.sum(raw[:, 3:] ** 2, axis=1)))) if d == 6 else None,
            n_iter=n_iter,
            converged=converged,
            unidentifiable=tuple(
                lb for lb, f, h in zip(labels, free, self._held(), strict=True) if not f and not h
            ),
            held=tuple(lb for lb, h in zip(labels, self._held(), strict=True) if h),
            noise=self.noise,
            prior=self.prior,
            n_poses=n,
            reference_time=None if self.meas.time is None else float(self.meas.time[-1]),
        )


def _spd_solve(H: F, b: F) -> F:
    """``H⁻¹ b`` for a symmetric positive definite ``H`` by Cholesky (numpy only: scipy.linalg
    costs 0.3–0.7 s to import, more than a fit)."""
    L = np.linalg.cholesky(H)
    return np.linalg.solve(L.T, np.linalg.solve(L, b))


def sequential_independent(J: F, rank_tol: float) -> NDArray[np.bool_]:
    """Greedy column selection in the given order: column ``k`` is kept if the part of it
    outside the span of the columns *kept* before it has a norm above ``rank_tol``.

    Unlike one QR over all columns, a column judged dependent takes nothing away from the
    later ones: its small remainder (e.g. ``j1.dz.c0`` beside ``base.dz.c0`` while a drift
    rotates the base) is not projected out of them.  Equivalent to Gram–Schmidt that skips
    dependent columns, computed on the Gram matrix ``JᵀJ`` as an incremental Cholesky
    factorisation (one BLAS-3 product, then ``O(p²)`` vector work per kept column).  ``J``
    should have unit-norm columns (``rank_tol`` is relative to the column norm).
    """
    return sequential_independent_gram(J.T @ J, rank_tol)


def sequential_independent_gram(G: F, rank_tol: float) -> NDArray[np.bool_]:
    """:func:`sequential_independent` of the columns whose Gram matrix is ``G`` (JᵀJ)."""
    p = G.shape[0]
    resid = np.diag(G).copy()  # squared norm of each column outside the kept span
    L = np.zeros((p, p))  # L[:, k]: coordinates of all columns on the k-th kept direction
    keep = np.zeros(p, bool)
    tol2 = rank_tol * rank_tol
    k = 0
    for j in range(p):
        if resid[j] <= tol2:
            continue
        keep[j] = True
        col = (G[j:, j] - L[j:, :k] @ L[j, :k]) / np.sqrt(resid[j])
        L[j:, k] = col
        resid[j:] -= col * col
        k += 1
    return keep


def bic_value(R: F, n_params: int, rss_si: float = 0.0) -> float:
    """Eq. 9: ``BIC = n/2 · log det Cov(R) + RSS/2 + K/2 · log n``, ``K = n_params + d``.

    ``R`` (n, d): per-pose *whitened* residual vectors, ``Cov(R) = RᵀR / n``.  Whitening makes
    per-row uncertainties count and the unit choice irrelevant; with uniform uncertainties
    it equals the SI determinant plus a constant.  ``rss_si``: sum of squared residual
    components in SI units (m², rad²) as the paper writes it; it is tiny beside the
    determinant term, so the criterion is the Gaussian BIC with an estimated residual
    covariance and does not depend on the instrument uncertainty being right.
    """
    n, d = R.shape
    C = R.T @ R / n
    sign, logdet = np.linalg.slogdet(C + np.eye(d) * 1e-300)
    return float(n / 2 * logdet + rss_si / 2 + (n_params + d) / 2 * np.log(n))


def motion_labels(spec: ErrorModelSpec) -> list[str]:
    """``frame.motion`` names of every error motion, e.g. ``j1.ez``."""
    return [f"{spec.frame_name(f)}.{m}" for f in range(spec.orders.shape[0]) for m in MOTIONS]
