"""The loop model: one forward loop, its Jacobians and one noise model.

Every part of the assessment that needs the model pose, its derivatives or the measurement
covariance takes them from here: the fit (:mod:`.fit`), the order search (:mod:`.select`),
the diagnosis (:mod:`.diagnose`), the held-out comparison (:mod:`.compare`), the digital twin
(:mod:`.twin`) and the workspace map (:mod:`.workspace`).  Two copies of a loop or of a noise
model drift apart (they did: per-row angle sigmas were mapped through the Euler-angle rates
in the fit and used as a plain diagonal in the diagnosis).

The loop (README conventions, METHOD.md Eq. 4)::

    T_instr_target = T_instr_base0 · E0 · E(base_twist) · C0 · Π_i [Rz(θ_i + dq_i) · E_i(θ_i) · C_i]
                     · T_flange_target0 · Etool
    measured point = diag(1, 1, 1 + instr_scale_z) · position of T_instr_target

with ``C_i`` translations × (1 + link_scale).  Residuals are measured minus model: position
(m) and the rotation vector ``log(R_meas R_modelᵀ)`` (rad), both in the instrument frame.

The noise model (:func:`noise_covariance`): per-row ``sx, sy, sz`` or the instrument default
per axis; per-row ``spitch, syaw, sroll`` (uncertainties of the *angles*) mapped through the
roll-yaw-pitch rates, or the instrument default isotropic on the rotation vector; plus the
encoders' noise propagated through the loop (implicit-loop effective variance).  Rows marked ``Measurements.excluded`` get an
uninformative covariance (cross-validation keeps left-out poses for the execution order).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from .effects import Effect, EffectContext, Perturbation, effect_context
from .errormodel import (
    ErrorModelSpec,
    chebyshev_basis,
    chebyshev_u,
    constant_motions,
    joint_error_motions,
)
from .measurements import Measurements
from .robot import RobotModel
from .transforms import log_so3, rpy_to_R, small_error_transform

F = NDArray[np.float64]

_NO_PERTURBATION = Perturbation()

#: Standard uncertainty (m, rad) of an excluded row (``Measurements.excluded``): no information.
EXCLUDED_SIGMA = 1e3


@dataclass(frozen=True)
class InstrumentNoise:
    """Default standard uncertainties of a measured pose, used where the file has no ``s…`` columns.

    Attributes
    ----------
    sigma_pos : float, m
        Per axis of the measured point.
    sigma_rot : float, rad
        Per axis of the measured orientation's rotation vector (isotropic; per-row
        ``spitch, syaw, sroll`` columns are per-angle uncertainties instead).
    sigma_q : float, rad
        Joint encoder reading (propagated through the loop; 0 = exact readings).
    excess_pos : float, m
        Scatter of the residuals beyond the stated uncertainty, per axis, added in quadrature
        to every row's position uncertainty (per-row columns or the default): 0 = as stated.
        Estimated when the χ² check shows the stated uncertainty too small, or model error
        dominating (:func:`~quickhealth.identify.select.estimate_noise_scale`); every band,
        σ and test computed with this noise then includes it.
    excess_rot : float, rad
        The same for the orientation (per axis of the rotation vector).
    band_factor : float
        Widening of the measurement's part of a 95 % band (:func:`~quickhealth.identify.
        workspace.prediction_band`), at least 1: estimated with the excess from the tails of
        the residuals (heavier than a Gaussian's on real data), 1 where the stated noise holds.
    """

    sigma_pos: float = 3e-5
    sigma_rot: float = 1e-4
    sigma_q: float = 0.0
    excess_pos: float = 0.0
    excess_rot: float = 0.0
    band_factor: float = 1.0

    def scaled(self, factor: float) -> InstrumentNoise:
        """The same instrument with every uncertainty multiplied by ``factor``."""
        return replace(
            self,
            sigma_pos=self.sigma_pos * factor,
            sigma_rot=self.sigma_rot * factor,
            sigma_q=self.sigma_q * factor,
        )

    def stated(self) -> InstrumentNoise:
        """The instrument as stated: without the scatter estimated from a fit's residuals."""
        return replace(self, excess_pos=0.0, excess_rot=0.0, band_factor=1.0)

    @property
    def rescaled(self) -> bool:
        """True when an estimated excess scatter is added to the stated uncertainty."""
        return self.excess_pos > 0.0 or self.excess_rot > 0.0

    @property
    def sigma_pos_effective(self) -> float:
        """Position uncertainty per axis (m) where a row states none, excess included."""
        return float(np.hypot(self.sigma_pos, self.excess_pos))

    @property
    def sigma_rot_effective(self) -> float:
        """Orientation uncertainty per axis (rad) where a row states none, excess included."""
        return float(np.hypot(self.sigma_rot, self.excess_rot))


# --------------------------------------------------------------------------- the loop


def measurement_context(robot: RobotModel, meas: Measurements) -> EffectContext:
    """The effects' context of a measurement set (approach from the execution order)."""
    return effect_context(robot, meas.q, meas.approach_sign(), **meas.conditions())


def joint_motion_matrices(spec: ErrorModelSpec, coeffs: F, q: F) -> tuple[F, F]:
    """Motions (n, nf, 6) and error transforms E (n, nf, 4, 4) of all frames (base, joints, tool)."""
    n, nj = q.shape
    m = np.zeros((n, nj + 2, 6))
    m[:, 1:-1] = joint_error_motions(spec, coeffs, q)
    m[:, 0] = constant_motions(spec, coeffs, 0)
    m[:, -1] = constant_motions(spec, coeffs, -1)
    return m, small_error_transform(m[..., :3], m[..., 3:])


def forward(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: F,
    T_ib0: F,
    T_ft0: F,
    q: F,
    pert: Perturbation = _NO_PERTURBATION,
    frames: bool = True,
) -> tuple[F, F | None, F]:
    """Loop pose and, with ``frames``, the prefix transform ``A_f`` before every ``E_f``.

    Returns ``T`` (n, 4, 4) with the instrument's z scale applied to the translation,
    ``A`` (n, nf, 4, 4) or None, and the motions (n, nf, 6).  ``A[:, j + 1]`` is the frame
    right after ``Rz(θ_j)``: its z axis is joint j's axis.
    """
    q = np.atleast_2d(np.asarray(q, float))
    coeffs = np.asarray(coeffs, float)
    n, nj = q.shape
    mot, E = joint_motion_matrices(spec, coeffs, q)
    if pert.joint_motion is not None:  # the effects' error motions add to the joints' own
        mot = mot.copy()
        mot[:, 1:-1] += np.asarray(pert.joint_motion, float)
        E = E.copy()
        E[:, 1:-1] = small_error_transform(mot[:, 1:-1, :3], mot[:, 1:-1, 3:])
    theta = q + robot.q_offset
    if pert.dq is not None:
        theta = theta + pert.dq
    links = np.broadcast_to(robot.links, (n, nj + 1, 4, 4))
    if pert.link_scale is not None:
        links = links.copy()
        links[..., :3, 3] *= (1.0 + np.asarray(pert.link_scale, float))[:, None, None]
    c, s = np.cos(theta), np.sin(theta)
    Rz = np.zeros((n, nj, 4, 4))
    Rz[..., 0, 0] = c
    Rz[..., 0, 1] = -s
    Rz[..., 1, 0] = s
    Rz[..., 1, 1] = c
    Rz[..., 2, 2] = 1.0
    Rz[..., 3, 3] = 1.0
    A = np.empty((n, nj + 2, 4, 4)) if frames else None
    P = np.broadcast_to(np.asarray(T_ib0, float), (n, 4, 4))
    if A is not None:
        A[:, 0] = P
    P = P @ E[:, 0]
    if pert.base_twist is not None:
        bt = np.asarray(pert.base_twist, float)
        P = P @ small_error_transform(bt[:, :3], bt[:, 3:])
    P = P @ links[:, 0]
    for i in range(nj):
        P = P @ Rz[:, i]
        if A is not None:
            A[:, i + 1] = P
        P = P @ E[:, i + 1] @ links[:, i + 1]
    P = P @ np.asarray(T_ft0, float)
    if A is not None:
        A[:, nj + 1] = P
    T = P @ E[:, nj + 1]
    if pert.instr_scale_z is not None:
        T = T.copy()
        T[:, 2, 3] *= 1.0 + np.asarray(pert.instr_scale_z, float)
    return T, A, mot


def loop_pose(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: F,
    T_ib0: F,
    T_ft0: F,
    q: F,
    pert: Perturbation = _NO_PERTURBATION,
) -> F:
    """Model pose of the target in the instrument frame, ``T_instr_target`` (n, 4, 4)."""
    return forward(robot, spec, coeffs, T_ib0, T_ft0, q, pert, frames=False)[0]


def pose_residuals(meas: Measurements, T_model: F) -> F:
    """Measured minus model: ``(n, 6)`` = position (m), rotation vector (rad), instrument frame.

    Position-only data give ``(n, 3)``.  The rotation residual is ``log(R_meas · R_modelᵀ)``.
    """
    dp = meas.pos - T_model[:, :3, 3]
    if not meas.has_orientation:
        return dp
    dw = log_so3(meas.R @ np.swapaxes(T_model[:, :3, :3], -1, -2))
    return np.concatenate([dp, dw], axis=1)


# --------------------------------------------------------------------------- Jacobians


def motion_jacobian(T: F, A: F, mot: F, scale_z: F | None = None) -> F:
    """∂(position, rotation)/∂(six motions of every frame), shape (n, 6, nf, 6).

    With ``E = Trans(δ) · Rx(εx) Ry(εy) Rz(εz)`` after the prefix ``A`` and the rest ``B``:
    ``∂p/∂δ_k = A_R e_k``, ``∂p/∂ε_k = A_R (w_k × E_R b)``, ``∂ω/∂ε_k = A_R w_k`` with
    ``w_x = x̂``, ``w_y = Rx ŷ``, ``w_z = Rx Ry ẑ`` and ``b`` the target in the frame after E.
    """
    n, nf = A.shape[:2]
    AR = A[..., :3, :3]
    p = _geometric_point(T, scale_z)
    ex, ey = mot[..., 3], mot[..., 4]
    # rotation axes of Rx(εx) Ry(εy) Rz(εz) in the frame before E: x̂, Rx ŷ, Rx Ry ẑ
    cx, sx, cy, sy = np.cos(ex), np.sin(ex), np.cos(ey), np.sin(ey)
    W = np.zeros((n, nf, 3, 3))
    W[..., 0, 0] = 1.0
    W[..., 1, 1], W[..., 2, 1] = cx, sx
    W[..., 0, 2], W[..., 1, 2], W[..., 2, 2] = sy, -sx * cy, cx * cy
    Om = AR @ W  # (n, nf, 3, 3): the axes in the instrument frame, column k
    # A_R (w_k × E_R b) = (A_R w_k) × (p − A_t − A_R δ): the lever from E's rotation centre
    lever = p[:, None, :] - A[..., :3, 3] - np.einsum("nfij,nfj->nfi", AR, mot[..., :3])
    J = np.empty((n, 6, nf, 6))
    J[:, 3:, :, :3] = 0.0  # a translation does not turn the target
    J[:, :3, :, :3] = np.swapaxes(AR, 1, 2)
    J[:, 3:, :, 3:] = np.swapaxes(Om, 1, 2)
    Omc = np.swapaxes(Om, -1, -2)  # (n, nf, k, 3)
    J[:, :3, :, 3:] = np.moveaxis(np.cross(Omc, lever[:, :, None, :]), 3, 1)
    if scale_z is not None:
        J[:, 2] *= (1.0 + np.asarray(scale_z, float))[:, None, None]
    return J


def joint_angle_jacobian(T: F, A: F, scale_z: F | None = None) -> F:
    """∂(position, rotation)/∂θ_j of every joint, shape (n, nj, 6): ``[z × (p − o), z]``."""
    nj = A.shape[1] - 2
    z = A[:, 1 : nj + 1, :3, 2]
    o = A[:, 1 : nj + 1, :3, 3]
    p = _geometric_point(T, scale_z)[:, None, :]
    Jq = np.concatenate([np.cross(z, p - o), z], axis=-1)
    if scale_z is not None:
        Jq[:, :, 2] *= (1.0 + np.asarray(scale_z, float))[:, None]
    return Jq


def coefficient_columns(spec: ErrorModelSpec, q: F, Jmot: F) -> F:
    """∂model/∂(every Chebyshev coefficient), (n, d, spec.n_params), from the motion
    Jacobian ``Jmot`` (n, d, nf, 6) of :func:`motion_jacobian`."""
    idx = spec.index()
    u = chebyshev_u(q, spec.q_lo, spec.q_hi)
    kmax = int(max(spec.orders.max(), 0))
    B = chebyshev_basis(u, kmax)  # (n, nj, K)
    basis = np.ones((q.shape[0], idx.shape[0]))
    joint = (idx[:, 0] >= 1) & (idx[:, 0] <= spec.n_joints)
    ji = idx[joint]
    basis[:, joint] = B[:, ji[:, 0] - 1, ji[:, 2]]
    n, d, nf = Jmot.shape[:3]
    flat = np.ascontiguousarray(Jmot).reshape(n, d, nf * 6)  # a view for motion_jacobian's
    cols = np.take(flat, idx[:, 0] * 6 + idx[:, 1], axis=2)
    cols *= basis[:, None, :]
    return cols


def _geometric_point(T: F, scale_z: F | None) -> F:
    p = T[:, :3, 3]
    if scale_z is None:
        return p
    p = p.copy()
    p[:, 2] /= 1.0 + np.asarray(scale_z, float)
    return p


#: The channels of :class:`Sensitivities`: the four an effect can perturb, and the frames' motions.
CHANNELS = ("dq", "link_scale", "base_twist", "instr_scale_z", "frame_motion")


@dataclass(frozen=True, eq=False)
class Sensitivities:
    """Derivatives of the model pose ``(n, 6)`` (position m, rotation rad) at an estimate,
    per unit of every channel an effect can perturb.

    A channel left out of :func:`sensitivities`' ``channels`` is None.

    Attributes
    ----------
    dq : ndarray, shape (n, nj, 6)
        Per unit (rad) joint-angle perturbation (analytic).
    link_scale : ndarray, shape (n, 6)
        Per unit fractional link growth.
    base_twist : ndarray, shape (n, 6, 6)
        Per unit base motion component (δx δy δz εx εy εz).
    instr_scale_z : ndarray, shape (n, 6)
        Per unit instrument depth scale.
    frame_motion : ndarray, shape (n, nj + 2, 6, 6)
        Per unit constant error motion of each frame (base, joints, tool) (analytic).
    """

    dq: F
    link_scale: F | None
    base_twist: F | None
    instr_scale_z: F | None
    frame_motion: F | None


def sensitivities(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: F,
    T_ib0: F,
    T_ft0: F,
    q: F,
    pert: Perturbation = _NO_PERTURBATION,
    h: float = 1e-6,
    *,
    channels: Collection[str] = CHANNELS,
    loop: tuple[F, F, F] | None = None,
) -> Sensitivities:
    """Every channel's derivative of the loop at ``coeffs`` with the effects' ``pert`` applied.

    Joint angles and frame motions analytically (:func:`joint_angle_jacobian`,
    :func:`motion_jacobian`); the three effect-only channels (link growth, base motion,
    depth scale) by central differences of :func:`loop_pose` (8 channels, 16 loops).

    Parameters
    ----------
    channels : collection of str
        The channels to compute (default all, :data:`CHANNELS`); ``dq`` is always computed.
        The fit asks only for those its effects use (:func:`effect_channels`).
    loop : (T, A, motions), optional
        :func:`forward` at this estimate, when the caller has it already.
    """
    q = np.atleast_2d(np.asarray(q, float))
    n = q.shape[0]
    T, A, mot = loop if loop is not None else forward(robot, spec, coeffs, T_ib0, T_ft0, q, pert)
    assert A is not None
    S_fm = None
    if "frame_motion" in channels:
        Jm = motion_jacobian(T, A, mot, pert.instr_scale_z)  # (n, 6c, nf, 6m)
        S_fm = np.moveaxis(Jm, 1, 3)  # (n, nf, 6m, 6c)
    S_dq = joint_angle_jacobian(T, A, pert.instr_scale_z)

    def diff(make) -> F:  # type: ignore[no-untyped-def]
        Tp = loop_pose(robot, spec, coeffs, T_ib0, T_ft0, q, pert + make(h))
        Tm = loop_pose(robot, spec, coeffs, T_ib0, T_ft0, q, pert + make(-h))
        dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        dw = log_so3(Tp[:, :3, :3] @ np.swapaxes(Tm[:, :3, :3], -1, -2)) / (2 * h)
        return np.concatenate([dp, dw], axis=1)

    S_ls = S_bt = S_iz = None
    if "link_scale" in channels:
        S_ls = diff(lambda s: Perturbation(link_scale=np.full(n, s)))
    if "base_twist" in channels:
        S_bt = np.empty((n, 6, 6))
        for c in range(6):
            unit = np.zeros((n, 6))
            unit[:, c] = 1.0
            S_bt[:, c] = diff(lambda s, u=unit: Perturbation(base_twist=u * s))
    if "instr_scale_z" in channels:
        S_iz = diff(lambda s: Perturbation(instr_scale_z=np.full(n, s)))
    return Sensitivities(S_dq, S_ls, S_bt, S_iz, S_fm)


def _unit_perturbations(effect: Effect, ctx: EffectContext) -> list[Perturbation]:
    """The effect's perturbation per unit of each parameter (it is linear in them)."""
    return [effect.perturbation(ctx, np.eye(effect.n_params)[i]) for i in range(effect.n_params)]


def effect_channels(effects: Sequence[Effect], ctx: EffectContext) -> frozenset[str]:
    """The :class:`Sensitivities` channels that :func:`effect_jacobian` of ``effects`` needs."""
    used = {"dq"}
    for e in effects:
        for p in _unit_perturbations(e, ctx):
            used |= {c for c in CHANNELS[:4] if getattr(p, c) is not None}
            if p.joint_motion is not None:
                used.add("frame_motion")
    return frozenset(used)


def effect_jacobian(effect: Effect, ctx: EffectContext, sens: Sensitivities) -> F:
    """Derivative of the model pose with respect to the effect's parameters, ``(n, 6, k)``.

    Exact for the perturbation (an effect is linear in its parameters); the loop is
    linearised at the estimate through :class:`Sensitivities`.  The one effect Jacobian of
    the package: the fit, the diagnosis and the comparison all take it from here.
    """
    n = ctx.n_poses
    out = np.zeros((n, 6, effect.n_params))
    for i, p in enumerate(_unit_perturbations(effect, ctx)):
        col = np.zeros((n, 6))
        if p.dq is not None:
            col += np.einsum("nj,njc->nc", p.dq, sens.dq)
        if p.link_scale is not None:
            col += p.link_scale[:, None] * _channel(sens, "link_scale")
        if p.base_twist is not None:
            col += np.einsum("nk,nkc->nc", p.base_twist, _channel(sens, "base_twist"))
        if p.instr_scale_z is not None:
            col += p.instr_scale_z[:, None] * _channel(sens, "instr_scale_z")
        if p.joint_motion is not None:  # (n, nj, 6m) through each joint frame's motion columns
            fm = _channel(sens, "frame_motion")[:, 1:-1]  # (n, nj, 6m, 6c)
            col += np.einsum("njm,njmc->nc", p.joint_motion, fm)
        out[:, :, i] = col
    return out


def _channel(sens: Sensitivities, name: str) -> F:
    v = getattr(sens, name)
    if v is None:
        raise ValueError(f"sensitivities computed without the {name!r} channel")
    return v


# --------------------------------------------------------------------------- noise model


def rotation_noise_cov(meas: Measurements, sigma_rot: float) -> F:
    """Covariance (n, 3, 3) of the measured orientation as a rotation vector (instrument frame).

    Per-row ``srot`` (one angle, any axis) is isotropic, ``Σ = srot² I``.  Per-row
    ``spitch, syaw, sroll`` (CONTRACTS.md: uncertainties of the *angles*) are mapped
    through the roll-yaw-pitch rates, ``Σ = E diag(σ²) Eᵀ`` with
    ``ω = Rz(r)Ry(y) x̂ ṗ + Rz(r) ŷ ẏ + ẑ ṙ``.  The instrument default ``sigma_rot`` is the
    noise per axis of the rotation vector, ``Σ = σ² I``: an instrument's orientation noise
    does not know about Euler angles (mapping it as per-angle noise made the weights wrong by
    up to 3× at yaw ±75° and the reported covariance too small, χ²/dof 1.2 on pure noise).
    """
    n = meas.n_poses
    if meas.sigma_rot is not None:  # one angle per row: isotropic, no Euler singularity
        return np.asarray(meas.sigma_rot, float)[:, None, None] ** 2 * np.eye(3)
    if meas.sigma_rpy is None:
        return np.broadcast_to(np.eye(3) * sigma_rot**2, (n, 3, 3)).copy()
    rpy = meas.rpy
    assert rpy is not None
    sr = np.asarray(meas.sigma_rpy, float)
    Rzr = rpy_to_R(np.zeros(n), np.zeros(n), rpy[:, 2])
    Rzy = rpy_to_R(np.zeros(n), rpy[:, 1], rpy[:, 2])
    Emap = np.stack([Rzy[:, :, 0], Rzr[:, :, 1], np.tile([0.0, 0.0, 1.0], (n, 1))], -1)
    return Emap @ (sr[:, :, None] ** 2 * np.swapaxes(Emap, -1, -2))


def noise_covariance(meas: Measurements, noise: InstrumentNoise, Jq: F | None = None) -> F:
    """Covariance ``Σx,i`` (n, d, d) of every pose's residual, d = 6 (full pose) or 3.

    Instrument: per-row ``sx…`` columns or ``noise.sigma_pos``; orientation by
    :func:`rotation_noise_cov`; each block plus ``noise.excess_pos²`` / ``excess_rot²``.  Encoders: ``noise.sigma_q² Σ_j g_ij g_ijᵀ`` with ``Jq``
    (n, nj, ≥d) the pose's sensitivity to each joint angle (:func:`joint_angle_jacobian`).
    """
    n = meas.n_poses
    d = 6 if meas.has_orientation else 3
    cov = np.zeros((n, d, d))
    sp = meas.sigma_pos if meas.sigma_pos is not None else np.full((n, 3), noise.sigma_pos)
    cov[:, [0, 1, 2], [0, 1, 2]] = np.asarray(sp, float) ** 2 + noise.excess_pos**2
    if d == 6:
        cov[:, 3:, 3:] = rotation_noise_cov(meas, noise.sigma_rot) + noise.excess_rot**2 * np.eye(3)
    if noise.sigma_q > 0:
        if Jq is None:
            raise ValueError("noise_covariance: encoder noise needs the joint-angle Jacobian")
        g = Jq[..., :d]
        cov += noise.sigma_q**2 * np.einsum("nji,njk->nik", g, g)
    if meas.excluded is not None:  # rows kept only for the execution order
        cov[np.asarray(meas.excluded, bool)] = np.eye(d) * EXCLUDED_SIGMA**2
    return cov


@dataclass(frozen=True, eq=False)
class Whitening:
    """Per-pose whitening ``W_i = L_i⁻¹`` with ``L_i L_iᵀ = Σx,i`` (:func:`noise_covariance`)."""

    W: F  # (n, d, d)
    L: F  # (n, d, d)

    @classmethod
    def of(cls, cov: F) -> Whitening:
        """The whitening of covariances ``cov`` (n, d, d)."""
        L = np.linalg.cholesky(cov + np.eye(cov.shape[-1]) * 1e-30)
        return cls(W=np.linalg.inv(L), L=L)

    def white(self, x: F) -> F:
        """``W_i x_i`` for residual-like ``x`` (n, d) or Jacobian-like ``x`` (n, d, k)."""
        if x.ndim == 2:
            return np.einsum("nij,nj->ni", self.W, x)
        return np.einsum("nij,njk->nik", self.W, x)

    def unwhite(self, x: F) -> F:
        """``L_i x_i`` for ``x`` (n, d): back to SI units."""
        return np.einsum("nij,nj->ni", self.L, x)
