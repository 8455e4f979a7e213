"""Optimal experimental design: which poses to measure so the fitted model predicts best.

The fit (:mod:`.fit`, with the order search of :mod:`.select`) will choose the error model's
orders from the data; the design cannot know them.  It uses a *prior for the orders*
instead (:class:`DesignPrior`): stated, every error motion of every joint a Chebyshev series up
to order ``max_order`` whose coefficient ``k`` is a priori ``N(0, σ0² · decay^{2k})`` (``σ0``:
0.1 mm for the translations, 0.3 mrad for the rotations, the size of the geometric errors of a
UR-class arm; ``decay`` 0.5: higher orders are smaller), base and tool free (1 m, 1 rad); or
taken from a fitted baseline (:func:`prior_from_baseline`: its orders, the sizes of its
coefficients and effects, and the share of its residual scatter the model leaves unexplained).
With the instrument's noise (:class:`~.linearize.InstrumentNoise`) each pose adds the
information ``Jᵢᵀ Σ⁻¹ Jᵢ`` of its loop Jacobian at the nominal robot (the loop is nearly linear
in the coefficients), and the posterior covariance of the coefficients after poses ``S`` is
``P(S) = (Π⁻¹ + Σ_{i∈S} Jᵢᵀ Σ⁻¹ Jᵢ)⁻¹``.

Information criteria (Bayesian, so a handful of poses already has a finite value):

- **I-optimal** (default): the mean over the workspace of the predicted variance of the TCP
  position error that every health figure reports, ``tr(M P)`` with ``M = E_q[Gᵀ G]`` and
  ``G(q)`` the target position's derivative by the joint coefficients *after the best rigid
  registration of base and tool* (a change those take up is no TCP error).  This is "the
  predicted workspace TCP error band of the model fitted later" (squared, averaged).
- **D-optimal**: ``log det P`` (the volume of the coefficients' uncertainty).

**The guard against what the model does not know.**  A design optimal for the model it
assumes concentrates the poses where that model is most sensitive (the joints' extremes).  A
real robot has errors no model of the fit describes; a least-squares fit then returns the
model closest to the truth *on the poses measured*, and on concentrated poses that is not the
model closest to it over the workspace.  So the information criterion chooses only the first
``k`` poses; every later pose is chosen to make the set *representative* of the candidates:
the one that most lowers the maximum mean discrepancy between the chosen poses and all
candidates (kernel herding; Gaussian kernel in joint space, length ``spread_length`` times each
joint's standard deviation over the candidates), with the first ``k`` already in the set.
``k = ⌈saturation · r / d / s⌉``: ``r`` the number of coefficients the candidates can
identify, ``d`` the components a pose measures (6 or 3), so ``r / d`` poses saturate the
model; ``s`` the share of the residual variance the model leaves unexplained (a baseline's
estimated scatter ``τ`` against its instrument's ``σ``: ``τ² / (τ² + σ²)``; 0 when the
baseline's residuals are the instrument's noise: then every pose is chosen by the information
criterion; without a baseline 0.5 is assumed, between a model that explains everything and
the real arms measured, whose models leave 0.997 (UR10) and 0.999 (WAM) unexplained).
A plan of ``n ≤ k`` poses has no representative part; when the model is expected to miss part
of the errors (``s > 0``) its information greedy keeps each joint's range covered instead:
each step chooses among the candidates that fill a quarter of some joint's range holding fewer
than ``coverage / 4`` of the poses so far, when there are such quarters.
``saturation`` 1.3, ``spread_length`` 0.4, ``coverage`` 0.8 and the assumed 0.5 were tuned on
the digital twin and on the training part of the shared UR10 series only (docs/plan.md).

The workspace is the candidates themselves (they are where the robot can be measured).
Selection is greedy: each step takes the pose with the largest decrease of the criterion,
computed for all candidates at once by rank-``d`` updates of ``P`` (``O(m d² p)`` per step for
``m`` candidates and ``p`` coefficients); the representative steps cost ``O(m)`` each after
one ``O(m w)`` kernel mean.  Only joint angles are read: selection never sees measurements.

SYNOPSIS::

    from quickhealth.identify.design import select_poses, DesignSettings, prior_from_baseline
    res = select_poses(ur5(), q_candidates, 50, DesignSettings(orientation=False))
    res.indices, res.n_information, res.n_spread, res.band_mm, res.random_band_mm
    settings = DesignSettings(prior=prior_from_baseline(fitted_model))   # the next plan
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import Effect, effect_context
from .errormodel import ErrorModelSpec
from .errors import InputError
from .linearize import (
    InstrumentNoise,
    coefficient_columns,
    effect_channels,
    effect_jacobian,
    forward,
    motion_jacobian,
    sensitivities,
)
from .robot import RobotModel
from .transforms import make_T, skew

if TYPE_CHECKING:  # the type only: the fit's module loads scipy
    from .fit import FittedModel

F = NDArray[np.float64]


class Criterion(StrEnum):
    """What the selection minimises."""

    I_OPTIMAL = "I"  # mean predicted TCP error variance over the workspace
    D_OPTIMAL = "D"  # volume of the coefficients' uncertainty


@dataclass(frozen=True)
class DesignPrior:
    """The prior for the orders and sizes of the error model (SI).

    Stated (the defaults), or from a fitted baseline (:func:`prior_from_baseline`): then
    ``fitted_orders`` (``(nj + 2, 6)``) raises each motion's series to the baseline's order where
    that is higher than ``max_order``, ``fitted_sizes`` (coefficient label, size) sets a
    coefficient's prior to the larger of the stated one and the baseline's ``|estimate| ⊕ σ``,
    ``effects`` adds the baseline's effects (each with a prior standard deviation per
    parameter), and ``unexplained`` is the share of the residual variance the baseline's model
    did not explain (0: none; the stated prior assumes 0.5).
    """

    max_order: int = 3
    sigma_pos: float = 1e-4  # m, order 0 of a translation
    sigma_rot: float = 3e-4  # rad, order 0 of a rotation
    decay: float = 0.5  # factor per order
    setup: float = 1.0  # m and rad: base and tool (free)
    fitted_orders: tuple[tuple[int, ...], ...] | None = None
    fitted_sizes: tuple[tuple[str, float], ...] = ()
    effects: tuple[tuple[Effect, tuple[float, ...]], ...] = ()
    unexplained: float = 0.5
    source: str = "stated"

    def orders(self, n_joints: int) -> NDArray[np.int64]:
        """Order of every motion's series, ``(n_joints + 2, 6)`` (base and tool constant)."""
        o = np.full((n_joints + 2, 6), self.max_order, dtype=np.int64)
        if self.fitted_orders is not None:
            fo = np.asarray(self.fitted_orders, dtype=np.int64)
            if fo.shape != o.shape:
                raise InputError(
                    f"the baseline's model has {fo.shape[0] - 2} joints, the robot {n_joints}"
                )
            o = np.maximum(o, fo)
        o[0] = o[-1] = 0
        return o

    def sigmas(self, spec: ErrorModelSpec) -> F:
        """Prior standard deviation of every coefficient of ``spec``."""
        idx = spec.index()
        setup = (idx[:, 0] == 0) | (idx[:, 0] == spec.n_joints + 1)
        base = np.where(idx[:, 1] < 3, self.sigma_pos, self.sigma_rot) * self.decay ** idx[:, 2]
        base = np.where(idx[:, 2] <= self.max_order, base, 0.0)
        if self.fitted_sizes:
            fitted = dict(self.fitted_sizes)
            base = np.maximum(base, [fitted.get(lab, 0.0) for lab in spec.labels()])
        return np.where(setup, self.setup, base)


@dataclass(frozen=True)
class DesignSettings:
    """Criterion, instrument, prior and the guard against misspecification of a design.

    ``spread``: choose the poses after the first ``k`` to make the set representative (the
    module docstring); ``spread_length``: the kernel's length in each joint's standard
    deviation over the candidates; ``saturation``: ``k`` in poses that saturate the model;
    ``coverage``: when every pose is chosen by information although the model is expected to
    miss part of the errors (``k ≥ n``, unexplained share above 0), each quarter of every
    joint's range holds at least ``coverage / 4`` of the poses chosen so far.
    """

    criterion: Criterion = Criterion.I_OPTIMAL
    orientation: bool = True  # full pose (7D) or position only
    noise: InstrumentNoise = field(default_factory=InstrumentNoise)
    T_flange_target: F = field(default_factory=lambda: make_T(np.eye(3), [0.0, 0.0, 0.1]))
    prior: DesignPrior = field(default_factory=DesignPrior)
    workspace_samples: int = 1000
    registered: bool = True  # the health figures' TCP error (base and tool registered out)
    spread: bool = True
    spread_length: float = 0.4
    saturation: float = 1.3
    coverage: float = 0.8


@dataclass(frozen=True, eq=False)
class DesignResult:
    """The chosen poses and what the criterion says about them.

    ``indices``: rows of the candidates chosen (in the order they were taken: the first
    ``n_information`` by the information criterion, the ``n_spread`` after them to make the
    set representative); ``criterion``: the information criterion's value for them;
    ``band_mm``: the root mean square over the workspace of the predicted TCP error's standard
    deviation (mm), the I-criterion's square root; ``random_band_mm``: the same for ``n``
    candidates drawn at random (median of 20 draws); ``identifiable``: coefficients (and
    effect parameters) the candidates can identify (``r``); ``effects``: the baseline's
    effects in the design; ``left_out``: those not in it, with the reason.
    """

    indices: NDArray[np.int64]
    criterion: float
    band_mm: float
    random_band_mm: float
    n_candidates: int
    n_params: int
    n_information: int = 0
    n_spread: int = 0
    identifiable: int = 0
    prior_source: str = "stated"
    effects: tuple[str, ...] = ()
    left_out: tuple[str, ...] = ()


def design_spec(robot: RobotModel, q: F, prior: DesignPrior) -> ErrorModelSpec:
    """The prior's error model over the candidates' joint ranges."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    hi = np.where(hi - lo < 1e-6, lo + 1e-6, hi)
    return ErrorModelSpec(prior.orders(robot.n_joints), lo, hi)


def pose_information(
    robot: RobotModel, q: F, spec: ErrorModelSpec, settings: DesignSettings
) -> tuple[F, F]:
    """Whitened loop Jacobian of every candidate ``(n, d, P)`` at the nominal robot, and the
    registered TCP position Jacobian ``(n, 3, P)`` (zero columns for base and tool); ``P``:
    the coefficients of ``spec``, then the parameters of the prior's effects."""
    q = np.atleast_2d(np.asarray(q, float))
    coeffs = np.zeros(spec.n_params)
    T, A, mot = forward(robot, spec, coeffs, np.eye(4), settings.T_flange_target, q)
    assert A is not None
    d = 6 if settings.orientation else 3
    Jm = motion_jacobian(T, A, mot)
    Jfull = coefficient_columns(spec, q, Jm[:, :d])
    G = coefficient_columns(spec, q, Jm[:, :3])
    effects = [e for e, _ in settings.prior.effects]
    if effects:
        ctx = effect_context(robot, q, np.ones_like(q))
        sens = sensitivities(robot, spec, coeffs, np.eye(4), settings.T_flange_target, q,
                             channels=effect_channels(effects, ctx), loop=(T, A, mot))  # fmt: skip
        Je = np.concatenate([effect_jacobian(e, ctx, sens) for e in effects], axis=2)
        Jfull = np.concatenate([Jfull, Je[:, :d]], axis=2)
        G = np.concatenate([G, Je[:, :3]], axis=2)
    w = np.r_[[1.0 / settings.noise.sigma_pos_effective] * 3,
              [1.0 / settings.noise.sigma_rot_effective] * 3][:d]  # fmt: skip
    Jw = Jfull * w[None, :, None]
    if not settings.registered:  # the predicted measured point: base and tool count too
        return Jw, G
    idx = spec.index()
    setup = np.zeros(G.shape[-1], bool)
    setup[: spec.n_params] = (idx[:, 0] == 0) | (idx[:, 0] == spec.n_joints + 1)
    G[:, :, setup] = 0.0
    p = T[:, :3, 3]
    R = np.concatenate([-skew(p), np.broadcast_to(np.eye(3), (len(q), 3, 3)), T[:, :3, :3]], axis=2)
    return Jw, _register(G, R)


def _register(G: F, R: F) -> F:
    """``G`` with what base and tool take up projected out (least squares over all rows)."""
    Rf = R.reshape(-1, R.shape[-1])
    Gf = G.reshape(-1, G.shape[-1])
    return (Gf - Rf @ np.linalg.lstsq(Rf, Gf, rcond=None)[0]).reshape(G.shape)


def design_effects(
    robot: RobotModel, q: F, prior: DesignPrior
) -> tuple[DesignPrior, tuple[str, ...]]:
    """The prior with only the effects a design can weigh from joint angles alone, and the
    others with the reason: an effect that needs the run's time or temperature, or whose
    regressor depends on the direction each joint approached the pose from (the loop's order,
    decided after the selection), is left out of the information."""
    if not prior.effects:
        return prior, ()
    keep, out = [], []
    q = np.atleast_2d(q)
    up, down = effect_context(robot, q, np.ones_like(q)), effect_context(robot, q, -np.ones_like(q))
    for e, sd in prior.effects:
        if e.requires():
            out.append(f"{e.name} (needs the run's {', '.join(e.requires())})")
            continue
        k = np.eye(e.n_params)
        a = [e.perturbation(up, k[i]).dq for i in range(e.n_params)]
        b = [e.perturbation(down, k[i]).dq for i in range(e.n_params)]
        if any((x is None) != (y is None) or (x is not None and not np.allclose(x, y))
               for x, y in zip(a, b, strict=True)):  # fmt: skip
            out.append(f"{e.name} (depends on the loop's order)")
            continue
        keep.append((e, sd))
    return replace(prior, effects=tuple(keep)), tuple(out)


def prior_from_baseline(fitted: FittedModel, source: str = "baseline") -> DesignPrior:
    """The next plan's prior from a fitted baseline: its orders (a motion's series goes up to
    the baseline's order where that is above the stated ``max_order``), its coefficients' and
    effects' sizes (``|estimate| ⊕ σ``, never below the stated prior), and the share of the
    residual variance its model left unexplained: ``τ² / (τ² + σ²)`` with ``τ`` the scatter the
    fit estimated beyond the instrument's stated ``σ`` (0 when the residuals were the
    instrument's noise)."""
    spec = fitted.spec
    n = spec.n_params
    size = np.hypot(fitted.coeffs, fitted.sigma[:n])
    labels = spec.labels()
    idx = spec.index()
    joint = (idx[:, 0] > 0) & (idx[:, 0] <= spec.n_joints)
    sizes = tuple((labels[i], float(size[i])) for i in np.flatnonzero(joint) if size[i] > 0)
    effects, at = [], n
    for e, p in zip(fitted.effects, fitted.effect_params, strict=True):
        k = e.n_params
        sd = np.hypot(np.asarray(p, float), fitted.sigma[at : at + k])
        sd = np.maximum(sd, np.asarray(e.prior_sigma, float) * 1e-3)  # never a zero prior
        effects.append((e, tuple(float(v) for v in sd)))
        at += k
    tau, sigma = fitted.noise.excess_pos, fitted.noise.sigma_pos
    share = tau**2 / (tau**2 + sigma**2) if tau > 0 else 0.0
    orders = np.where(spec.orders < 0, 0, spec.orders)
    return DesignPrior(
        fitted_orders=tuple(tuple(int(v) for v in r) for r in orders),
        fitted_sizes=sizes,
        effects=tuple(effects),
        unexplained=float(share),
        source=source,
    )


def select_poses(
    robot: RobotModel,
    q_candidates: ArrayLike,
    n: int,
    settings: DesignSettings = DesignSettings(),
    *,
    allowed_groups: NDArray[np.int64] | None = None,
    seed: int = 0,
) -> DesignResult:
    """Choose ``n`` of the candidate joint configurations (rad, (m, nj)) by the criterion,
    the first ``k`` by information and the rest to make the set representative (module
    docstring; ``settings.spread`` False: all by information).

    Parameters
    ----------
    allowed_groups : ndarray of int (m,), optional
        A group label per candidate: at most one candidate of a group is chosen (the IK
        configurations of one target).
    seed : int
        For the workspace sample and the random comparison draws.

    Raises
    ------
    InputError
        ``n`` < 1 or more than the candidates (or groups); candidates of another arm.
    """
    q = np.atleast_2d(np.asarray(q_candidates, float))
    m = q.shape[0]
    groups = np.arange(m) if allowed_groups is None else np.asarray(allowed_groups)
    n_groups = len(np.unique(groups))
    if not 1 <= n <= n_groups:
        raise InputError(f"--n {n}: choose between 1 and {n_groups} of the {m} candidates")
    if q.shape[1] != robot.n_joints:
        raise InputError(f"candidates have {q.shape[1]} joints, {robot.name} has {robot.n_joints}")
    prior, left_out = design_effects(robot, q, settings.prior)
    settings = replace(settings, prior=prior)
    spec = design_spec(robot, q, prior)
    J, G = pose_information(robot, q, spec, settings)
    rng = np.random.default_rng(seed)
    ws = rng.choice(m, size=min(m, settings.workspace_samples), replace=False)
    Gw = G[ws].reshape(-1, G.shape[-1])
    M = Gw.T @ Gw / len(ws)
    P0 = np.diag(np.r_[prior.sigmas(spec), [v for _, sd in prior.effects for v in sd]] ** 2)
    live = np.diag(P0) > 0  # coefficients the prior leaves out (above its orders) drop
    J, M, P0 = J[:, :, live], M[np.ix_(live, live)], P0[np.ix_(live, live)]
    r = identifiable(J[ws])
    k = n if not settings.spread else information_poses(n, r, J.shape[1], prior, settings)
    cover = settings.spread and k == n and prior.unexplained > 0.0 and settings.coverage > 0.0
    strata = (_quarters(q), settings.coverage) if cover else None
    chosen = _greedy(J, M, P0, k, groups, settings.criterion, strata)
    if k < n:
        chosen = _spread(q, n, groups, chosen, ws, settings.spread_length)
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
        n_params=int(live.sum()),
        n_information=k,
        n_spread=n - k,
        identifiable=r,
        prior_source=prior.source,
        effects=tuple(e.name for e, _ in prior.effects),
        left_out=left_out,
    )


def identifiable(J: F) -> int:
    """How many parameters the candidates' stacked Jacobian ``(m, d, p)`` identifies (the
    rank of its column-normalised Gram matrix, relative tolerance 1e-10)."""
    A = np.einsum("mdp,mdq->pq", J, J)
    s = np.sqrt(np.clip(np.diag(A), 1e-300, None))
    ev = np.linalg.eigvalsh(A / np.outer(s, s))
    return int(np.sum(ev > ev[-1] * 1e-10))


def information_poses(
    n: int, identifiable: int, d: int, prior: DesignPrior, settings: DesignSettings
) -> int:
    """``k``: how many of ``n`` poses the information criterion chooses,
    ``⌈saturation · r / d / s⌉`` (module docstring), at least 1 and at most ``n``."""
    if prior.unexplained <= 0.0:
        return n
    k = math.ceil(settings.saturation * identifiable / d / min(prior.unexplained, 1.0))
    return int(min(n, max(k, 1)))


def _spread(
    q: F, n: int, groups: NDArray[np.int64], start: list[int], ws: NDArray[np.int64], length: float
) -> list[int]:
    """``start`` extended to ``n`` poses by kernel herding: each step the candidate that most
    lowers the maximum mean discrepancy between the chosen poses and the candidates (sampled
    at ``ws``), Gaussian kernel of ``length`` times each joint's standard deviation."""
    sd = q.std(axis=0)
    z = np.where(sd > 1e-9, q / (length * np.where(sd > 1e-9, sd, 1.0)), 0.0)
    zz = np.sum(z * z, axis=1)
    zw = z[ws]
    mu = np.empty(len(q))
    for a in range(0, len(q), 2048):  # the kernel mean over the workspace, in blocks
        d2 = zz[a : a + 2048, None] + zz[ws][None, :] - 2.0 * z[a : a + 2048] @ zw.T
        mu[a : a + 2048] = np.exp(-0.5 * np.clip(d2, 0.0, None)).mean(axis=1)
    ksum = np.zeros(len(q))
    allowed = np.ones(len(q), dtype=bool)
    chosen: list[int] = []

    def take(j: int) -> None:
        chosen.append(j)
        allowed[groups == groups[j]] = False
        ksum[:] += np.exp(-0.5 * np.clip(zz + zz[j] - 2.0 * z @ z[j], 0.0, None))

    for j in start:
        take(j)
    while len(chosen) < n:
        score = np.where(allowed, (len(chosen) + 1) * mu - ksum, -np.inf)
        take(int(np.argmax(score)))
    return chosen


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


def _quarters(q: F, bins: int = 4) -> NDArray[np.int64]:
    """Which quarter of each joint's range (over the candidates) every candidate is in."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    b = np.floor((q - lo) / np.where(hi - lo > 1e-9, hi - lo, 1.0) * bins).astype(np.int64)
    return np.clip(b, 0, bins - 1)


def _greedy(
    J: F, M: F, P0: F, n: int, groups: NDArray[np.int64], crit: Criterion,
    strata: tuple[NDArray[np.int64], float] | None = None,
) -> list[int]:  # fmt: skip
    """Each step the candidate whose rank-d update lowers the criterion most; with ``strata``
    (each candidate's bin of every joint's range, and the minimum share), among those that
    fill a bin holding fewer than its share of the poses when any does."""
    m, d, _ = J.shape
    if strata is not None:
        bins, share = strata
        nj, nb = bins.shape[1], int(bins.max()) + 1
        counts = np.zeros((nj, nb))
        joint = np.arange(nj)[None, :]
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
        if strata is not None:
            short = counts < np.floor(share * (len(chosen) + 1) / nb)  # (nj, nb)
            fills = short[joint, bins].any(axis=1) & allowed
            if fills.any():
                gain[~fills] = -np.inf
        j = int(np.argmax(gain))
        chosen.append(j)
        allowed &= groups != groups[j]
        if strata is not None:
            counts[np.arange(nj), bins[j]] += 1
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
    "design_effects",
    "design_spec",
    "identifiable",
    "information_poses",
    "pose_information",
    "prior_from_baseline",
    "select_poses",
]
