"""Optimal experimental design: which poses to measure so the fitted model predicts best.

The fit (:mod:`.fit`, with the order search of :mod:`.select`) will choose the error model's
orders from the data; the design cannot know them.  It uses a *stated prior for the orders*
instead (:class:`DesignPrior`): every error motion of every joint is a Chebyshev series up to
order ``max_order`` whose coefficient ``k`` is a priori ``N(0, σ0² · decay^{2k})`` (``σ0``: 0.1 mm
for the translations, 0.3 mrad for the rotations, the size of the geometric errors of a
UR-class arm; ``decay`` 0.5: higher orders are smaller), base and tool are free (1 m, 1 rad).
With the instrument's noise (:class:`~.linearize.InstrumentNoise`) each pose adds the
information ``Jᵢᵀ Σ⁻¹ Jᵢ`` of its loop Jacobian at the nominal robot (the loop is nearly
linear in the coefficients), and the posterior covariance of the coefficients after poses
``S`` is ``P(S) = (Π⁻¹ + Σ_{i∈S} Jᵢᵀ Σ⁻¹ Jᵢ)⁻¹``.

Criteria (Bayesian, so a handful of poses already has a finite value):

- **I-optimal** (default): the mean over the workspace of the predicted variance of the TCP
  position error that every health figure reports, ``tr(M P)`` with ``M = E_q[Gᵀ G]`` and
  ``G(q)`` the target position's derivative by the joint coefficients *after the best rigid
  registration of base and tool* (a change those take up is no TCP error).  This is "the
  predicted workspace TCP error band of the model fitted later" (squared, averaged).
- **D-optimal**: ``log det P`` (the volume of the coefficients' uncertainty).

The workspace is the candidates themselves (they are where the robot can be measured).
Selection is greedy: each step takes the pose with the largest decrease of the criterion,
computed for all candidates at once by rank-``d`` updates of ``P`` (``O(m d² p)`` per step for
``m`` candidates and ``p`` coefficients).  Fedorov exchange passes after it were tried and
dropped: on the twin they lowered the criterion by 1–3 % and the held-out error not at all,
at 5–10 times the time.  Only joint angles are read: selection never sees measurements.

SYNOPSIS::

    from quickhealth.identify.design import select_poses, DesignSettings
    res = select_poses(ur5(), q_candidates, 50, DesignSettings(orientation=False))
    res.indices, res.criterion, res.random_criterion
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errormodel import ErrorModelSpec
from .errors import InputError
from .linearize import InstrumentNoise, coefficient_columns, forward, motion_jacobian
from .robot import RobotModel
from .transforms import make_T, skew

F = NDArray[np.float64]


class Criterion(StrEnum):
    """What the selection minimises."""

    I_OPTIMAL = "I"  # mean predicted TCP error variance over the workspace
    D_OPTIMAL = "D"  # volume of the coefficients' uncertainty


@dataclass(frozen=True)
class DesignPrior:
    """The stated prior for the orders and sizes of the error model (SI)."""

    max_order: int = 3
    sigma_pos: float = 1e-4  # m, order 0 of a translation
    sigma_rot: float = 3e-4  # rad, order 0 of a rotation
    decay: float = 0.5  # factor per order
    setup: float = 1.0  # m and rad: base and tool (free)

    def sigmas(self, spec: ErrorModelSpec) -> F:
        """Prior standard deviation of every coefficient of ``spec``."""
        idx = spec.index()
        setup = (idx[:, 0] == 0) | (idx[:, 0] == spec.n_joints + 1)
        base = np.where(idx[:, 1] < 3, self.sigma_pos, self.sigma_rot) * self.decay ** idx[:, 2]
        return np.where(setup, self.setup, base)


@dataclass(frozen=True)
class DesignSettings:
    """Criterion, instrument and the measured point of a design."""

    criterion: Criterion = Criterion.I_OPTIMAL
    orientation: bool = True  # full pose (7D) or position only
    noise: InstrumentNoise = field(default_factory=InstrumentNoise)
    T_flange_target: F = field(default_factory=lambda: make_T(np.eye(3), [0.0, 0.0, 0.1]))
    prior: DesignPrior = field(default_factory=DesignPrior)
    workspace_samples: int = 1000
    registered: bool = True  # the health figures' TCP error (base and tool registered out)


@dataclass(frozen=True, eq=False)
class DesignResult:
    """The chosen poses and what the criterion says about them.

    ``indices``: rows of the candidates chosen (in the order the greedy step took them);
    ``criterion``: the criterion's value for them; ``band_mm``: the root mean square over the
    workspace of the predicted TCP error's standard deviation (mm), the I-criterion's square
    root; ``random_band_mm``: the same for ``n`` candidates drawn at random (median of 20
    draws), for comparison.
    """

    indices: NDArray[np.int64]
    criterion: float
    band_mm: float
    random_band_mm: float
    n_candidates: int
    n_params: int


def design_spec(robot: RobotModel, q: F, prior: DesignPrior) -> ErrorModelSpec:
    """The prior's error model over the candidates' joint ranges."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    hi = np.where(hi - lo < 1e-6, lo + 1e-6, hi)
    return ErrorModelSpec.uniform(robot.n_joints, prior.max_order, lo, hi)


def pose_information(
    robot: RobotModel, q: F, spec: ErrorModelSpec, settings: DesignSettings
) -> tuple[F, F]:
    """Whitened loop Jacobian of every candidate ``(n, d, P)`` at the nominal robot, and the
    registered TCP position Jacobian ``(n, 3, P)`` (zero columns for base and tool)."""
    q = np.atleast_2d(np.asarray(q, float))
    coeffs = np.zeros(spec.n_params)
    T, A, mot = forward(robot, spec, coeffs, np.eye(4), settings.T_flange_target, q)
    assert A is not None
    d = 6 if settings.orientation else 3
    Jm = motion_jacobian(T, A, mot)[:, :d]
    J = coefficient_columns(spec, q, Jm)
    w = np.r_[[1.0 / settings.noise.sigma_pos_effective] * 3,
              [1.0 / settings.noise.sigma_rot_effective] * 3][:d]  # fmt: skip
    Jw = J * w[None, :, None]
    G = coefficient_columns(spec, q, motion_jacobian(T, A, mot)[:, :3])
    if not settings.registered:  # the predicted measured point: base and tool count too
        return Jw, G
    idx = spec.index()
    setup = (idx[:, 0] == 0) | (idx[:, 0] == spec.n_joints + 1)
    G[:, :, setup] = 0.0
    p = T[:, :3, 3]
    R = np.concatenate([-skew(p), np.broadcast_to(np.eye(3), (len(q), 3, 3)), T[:, :3, :3]], axis=2)
    return Jw, _register(G, R)


def _register(G: F, R: F) -> F:
    """``G`` with what base and tool take up projected out (least squares over all rows)."""
    Rf = R.reshape(-1, R.shape[-1])
    Gf = G.reshape(-1, G.shape[-1])
    return (Gf - Rf @ np.linalg.lstsq(Rf, Gf, rcond=None)[0]).reshape(G.shape)


def select_poses(
    robot: RobotModel,
    q_candidates: ArrayLike,
    n: int,
    settings: DesignSettings = DesignSettings(),
    *,
    allowed_groups: NDArray[np.int64] | None = None,
    seed: int = 0,
) -> DesignResult:
    """Choose ``n`` of the candidate joint configurations (rad, (m, nj)) by the criterion.

    Parameters
    ----------
    allowed_groups : ndarray of int (m,), optional
        A group label per candidate: at most one candidate of a group is chosen (the IK
        configurations of one target).
    seed : int
        For the random comparison draws.

    Raises
    ------
    InputError
        ``n`` < 1 or more than the candidates (or groups).
    """
    q = np.atleast_2d(np.asarray(q_candidates, float))
    m = q.shape[0]
    groups = np.arange(m) if allowed_groups is None else np.asarray(allowed_groups)
    n_groups = len(np.unique(groups))
    if not 1 <= n <= n_groups:
        raise InputError(f"--n {n}: choose between 1 and {n_groups} of the {m} candidates")
    if q.shape[1] != robot.n_joints:
        raise InputError(f"candidates have {q.shape[1]} joints, {robot.name} has {robot.n_joints}")
    spec = design_spec(robot, q, settings.prior)
    J, G = pose_information(robot, q, spec, settings)
    rng = np.random.default_rng(seed)
    ws = rng.choice(m, size=min(m, settings.workspace_samples), replace=False)
    Gw = G[ws].reshape(-1, G.shape[-1])
    M = Gw.T @ Gw / len(ws)
    P0 = np.diag(settings.prior.sigmas(spec) ** 2)
    chosen = _greedy(J, M, P0, n, groups, settings.criterion)
    crit = _criterion(J, M, P0, chosen, settings.criterion)
    rand = [
        _criterion(J, M, P0, _random_groups(groups, n, rng), Criterion.I_OPTIMAL) for _ in range(20)
    ]
    band = _criterion(J, M, P0, chosen, Criterion.I_OPTIMAL)
    return DesignResult(
        indices=np.asarray(chosen, dtype=np.int64),
        criterion=crit,
        band_mm=float(np.sqrt(max(band, 0.0))) * 1e3,
        random_band_mm=float(np.sqrt(max(np.median(rand), 0.0))) * 1e3,
        n_candidates=m,
        n_params=spec.n_params,
    )


def _random_groups(groups: NDArray[np.int64], n: int, rng: np.random.Generator) -> list[int]:
    out, seen = [], set()
    for i in rng.permutation(len(groups)):
        if groups[i] not in seen:
            seen.add(groups[i])
            out.append(int(i))
            if len(out) == n:
                break
    return out


def _posterior(J: F, P0: F, rows: list[int]) -> F:
    A = J[rows].reshape(-1, J.shape[-1])
    H = np.linalg.inv(P0) + A.T @ A
    L = np.linalg.cholesky(0.5 * (H + H.T))
    Li = np.linalg.inv(L)
    return Li.T @ Li


def _criterion(J: F, M: F, P0: F, rows: list[int], crit: Criterion) -> float:
    P = _posterior(J, P0, rows)
    if crit is Criterion.I_OPTIMAL:
        return float(np.trace(M @ P))
    return float(np.linalg.slogdet(P)[1])  # log det of the posterior covariance: lower is better


def _greedy(J: F, M: F, P0: F, n: int, groups: NDArray[np.int64], crit: Criterion) -> list[int]:
    """Each step the candidate whose rank-d update lowers the criterion most."""
    m, d, _ = J.shape
    P = P0.copy()
    Gp = J @ P  # (m, d, p): J_c P
    Hm = Gp @ M if crit is Criterion.I_OPTIMAL else None  # J_c P M
    allowed = np.ones(m, dtype=bool)
    chosen: list[int] = []
    eye = np.eye(d)
    for _ in range(n):
        S = eye + Gp @ np.swapaxes(J, 1, 2)  # (m, d, d)
        if crit is Criterion.I_OPTIMAL:
            assert Hm is not None
            X = np.linalg.solve(S, Hm @ np.swapaxes(Gp, 1, 2))  # S⁻¹ J P M P Jᵀ
            gain = np.einsum("cii->c", X)
        else:
            gain = np.linalg.slogdet(S)[1]
        gain[~allowed] = -np.inf
        j = int(np.argmax(gain))
        chosen.append(j)
        allowed &= groups != groups[j]
        Aj = J[j]  # (d, p)
        Gj = Gp[j]  # A_j P
        Sj = S[j]
        W = np.linalg.solve(Sj, Gj)  # S⁻¹ A_j P
        C = Gp @ Aj.T  # (m, d, d): J_c P A_jᵀ
        Gp = Gp - C @ W
        if Hm is not None:
            Hm = Hm - C @ (W @ M)
        P = P - Gj.T @ W
    return chosen


__all__ = [
    "Criterion",
    "DesignPrior",
    "DesignResult",
    "DesignSettings",
    "design_spec",
    "pose_information",
    "select_poses",
]
