"""A change between two fitted runs, tested along every physical fault and named by it.

Two fits of one robot (a baseline and a later run, at the same orders) differ by ``d``, the
change of their parameters, with covariance ``S = Σ_a + Σ_b`` (independent fits; each with
the scatter its fit estimated, docs/identify.md "Honest uncertainty").  A single fault ``f``
of size ``s`` changes the parameters by ``s g_f`` (its image through the gauge,
:func:`~.faults.fault_images`).  Its generalised-least-squares estimate and variance are

    s_f = g_fᵀ S⁻¹ d / g_fᵀ S⁻¹ g_f,        var s_f = 1 / g_fᵀ S⁻¹ g_f,

the test along the fault's own direction with every correlation between gauge coordinates
counted, not coordinate by coordinate (where ``j1.ey`` and ``base.ex`` are nearly collinear,
each alone has a large σ while the zero offset they carry together has a small one).
``z = s/σ`` and the two-sided ``p`` come from the same numbers, in every line.

The coordinates compared: every parameter free in both fits but the base's (the instrument
may be set up anew between runs: its pose is integrated out).  The target stays on the
flange, so the tool's coordinates are compared too, and "the target moved on the flange"
is a candidate of its own (:func:`~.faults.setup_faults`): a re-mounted target is named as
such, never as a fault of the robot, and a fault the tool would otherwise take up (on the
shared UR10, 81 % of a joint-5 zero offset) stays visible.

Naming is forward selection: the fault with the largest χ² drop (weighted by the prior
:data:`~.faults.PRIOR`: near ties go to the more common fault) is named; the next one is
tested conditional on it; up to ``max_faults`` while they are significant (each at
``alpha / n_faults``, Bonferroni).  The faults that explain the change nearly as well are
listed as alternatives with their share of the evidence.

The covariances: where a run's poses are at hand (the archive's runs), each fit's
covariance is the spread of its estimate over pose sets (:func:`robust_cov`, a cluster
jackknife sandwich): a fit's own covariance assumes its model is right, and a real robot's
unmodelled errors are sampled differently by every pose set.

The scale ``λ`` on ``S`` (a genomic control, :func:`fault_scale`): what the sandwich still
misses.  ``λ`` is the median over the faults *not* named of their conditional ``z²``,
divided by the median of χ²₁ (0.455), at least 1, pooled over every comparison of the
trend so far (causal): most faults did not change, so their spread measures the
understatement, and the named ones are left out so a real change does not inflate it.
Measured on 30 splits of the shared UR10 series (docs/monitoring.md): the faults' z² average
1.49 with the sandwich alone; divided by the λ pooled over the 30 comparisons, 1.01 (|z| >
1.96 in 5.7 %, > 2.58 in 1.8 %, > 3.29 in 0.11 %); divided by each comparison's own λ, 0.86
(conservative: a trend of two runs).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from .errormodel import MOTIONS
from .faults import Alternative, Fault, FaultImages, NamedChange

F = NDArray[np.float64]

#: Median of χ² with one degree of freedom.
CHI2_1_MEDIAN = 0.454936423119572


def two_sided_p(z: float) -> float:
    """``P(|N(0,1)| ≥ |z|)``, accurate far in the tail."""
    return float(math.erfc(abs(z) / math.sqrt(2.0)))


def _chi2_sf(x: float, k: int) -> float:
    from scipy.special import chdtrc  # the χ² tail, accurate far out

    return float(chdtrc(k, x)) if k > 0 else 1.0


def _z_of_p(p: float) -> float:
    """The |z| whose two-sided normal tail is ``p``."""
    from scipy.special import ndtri

    return float(-ndtri(max(p, 1e-300) / 2.0))


@dataclass(frozen=True)
class FaultTest:
    """The faults a change was tested along, the ones named, and what is left.

    ``named``: the faults selected one after another, significant ones first (sizes from
    their joint estimate), then the first one that was not significant (for information);
    ``residual_chi2`` on ``residual_dof``: what the significant faults leave of the change
    (``residual_p``); ``scale``: ``λ`` on the combined covariance; ``level``: the per-fault
    test level ``alpha / tested``.
    """

    named: tuple[NamedChange, ...]
    tested: int
    chi2: float
    dof: int
    residual_chi2: float
    residual_dof: int
    residual_p: float
    scale: float
    level: float
    null_z2: tuple[float, ...] = ()  # conditional z² of the faults not named (for λ)
    estimates: tuple[tuple[str, tuple[float, ...]], ...] = ()  # significant: key, sizes

    @property
    def significant(self) -> tuple[NamedChange, ...]:
        """The named changes that passed the test (robot faults and set-up alike)."""
        return tuple(c for c in self.named if c.significant)

    @property
    def robot(self) -> tuple[NamedChange, ...]:
        """Significant changes of the robot (no set-up change)."""
        return tuple(c for c in self.significant if c.kind != "setup")

    @property
    def setup(self) -> tuple[NamedChange, ...]:
        """Significant set-up changes (the target moved on the flange)."""
        return tuple(c for c in self.significant if c.kind == "setup")


def name_changes(
    d: F,
    S: F,
    blocks: Sequence[F],
    faults: Sequence[Fault],
    *,
    alpha: float = 1e-4,
    floors: Mapping[str, float] | None = None,
    tcp: Sequence[float] | None = None,
    scale: float = 1.0,
    max_faults: int = 3,
    source: str = "trend",
) -> FaultTest:
    """Test a change ``d`` along every fault's direction and name it (see the module doc).

    Parameters
    ----------
    d : ndarray, shape (m,)
        The change of the compared parameters (run minus baseline), SI.
    S : ndarray, shape (m, m)
        Its covariance (both fits' covariances added).
    blocks : sequence of ndarray, each (m, k_f)
        Each fault's image on the same parameters (``k_f`` = 1 but for multi-parameter
        effects, whose size is the amplitude ``|s|``).
    alpha : float
        Family-wise false-alarm probability: each fault is tested at ``alpha / n_faults``.
    floors : mapping of SI unit to float, optional
        Smallest size that counts, per unit (``{"m": 1e-5, "rad": 2e-5}``); a fault whose
        unit has none (a joint scale, dimensionless) counts when its TCP displacement
        (``tcp``) exceeds the length floor.
    tcp : sequence of float, optional
        TCP displacement per unit of each fault (m), reported with each change.
    scale : float
        ``λ``: factor on ``S``.
    max_faults : int
        At most this many faults are named.

    Returns
    -------
    FaultTest
    """
    floors = dict(floors or {})
    d = np.asarray(d, float)
    Linv = _whitener(np.asarray(S, float) * scale)
    e = Linv @ d
    A = [Linv @ np.asarray(b, float) for b in blocks]
    norms = np.array([float(np.sqrt(np.sum(a**2))) for a in A])
    idx = [k for k in range(len(A)) if norms[k] > 1e-12 * max(float(norms.max(initial=0)), 1e-300)]
    level = alpha / max(len(idx), 1)
    dof = int(Linv.shape[0])
    chosen: list[int] = []
    named: list[NamedChange] = []
    Q = np.zeros((dof, 0))
    r = e.copy()
    for _ in range(min(max_faults, len(idx))):
        drops, logw = {}, {}
        for k in idx:
            if k in chosen:
                continue
            Ar = A[k] - Q @ (Q.T @ A[k])
            if float(np.sum(Ar**2)) <= 1e-18 * norms[k] ** 2:
                continue
            u, sv, _ = np.linalg.svd(Ar, full_matrices=False)
            u = u[:, sv > 1e-9 * sv.max()]
            drop = float(np.sum((u.T @ r) ** 2))
            kf = u.shape[1]
            # a k-parameter fault's drop as the one-parameter drop of the same p-value
            d1 = drop if kf == 1 else _z_of_p(_chi2_sf(drop, kf)) ** 2
            drops[k] = (drop, kf, u)
            logw[k] = math.log(faults[k].prior) + 0.5 * d1
        if not logw:
            break
        keys = list(logw)
        lw = np.array([logw[k] for k in keys])
        w = np.exp(lw - lw.max())
        w /= w.sum()
        b = int(np.argmax(lw))
        k = keys[b]
        chosen.append(k)
        drop, kf, u = drops[k]
        c = _estimate(A, chosen, e, faults, tcp, level, floors, source, len(chosen) - 1)
        alts = tuple(
            Alternative(faults[keys[j]].key, faults[keys[j]].words, float(w[j]),
                        faults[keys[j]].prior)
            for j in np.argsort(-w)
            if j != b and w[j] >= 1e-3
        )  # fmt: skip
        c = replace(c, probability=float(w[b]), alternatives=alts)
        named.append(c)
        Q = np.column_stack([Q, u])
        r = e - Q @ (Q.T @ e)
        if not c.significant:
            break
    sig = [c for c in named if c.significant]
    estimates: list[tuple[str, tuple[float, ...]]] = []
    if sig:  # final sizes of the significant ones, estimated together
        Ac = np.concatenate([A[k] for k in chosen[: len(sig)]], axis=1)
        s_all = np.linalg.pinv(Ac.T @ Ac) @ (Ac.T @ e)
        pos = 0
        for k in chosen[: len(sig)]:
            kf = A[k].shape[1]
            estimates.append((faults[k].key, tuple(map(float, s_all[pos : pos + kf]))))
            pos += kf
        fixed = [
            replace(_estimate(A, chosen[: len(sig)], e, faults, tcp, level, floors, source, j),
                    probability=c.probability, alternatives=c.alternatives)
            for j, c in enumerate(sig)
        ]  # fmt: skip
        named = fixed + named[len(sig) :]
        Qs = np.linalg.qr(np.concatenate([A[k] for k in chosen[: len(sig)]], axis=1))[0]
        r = e - Qs @ (Qs.T @ e)
    else:
        r = e
    n_par = sum(A[k].shape[1] for k in chosen[: len(sig)])
    rdof = max(dof - n_par, 0)
    res = float(r @ r)
    # conditional z² of every fault not named: the null sample the scale is estimated from
    null = []
    if sig:
        Qs = np.linalg.qr(np.concatenate([A[k] for k in chosen[: len(sig)]], axis=1))[0]
    else:
        Qs = np.zeros((dof, 0))
    for k in idx:
        if k in chosen[: len(sig)] or A[k].shape[1] != 1:
            continue
        a = A[k][:, 0] - Qs @ (Qs.T @ A[k][:, 0])
        na = float(a @ a)
        if na > 1e-18 * norms[k] ** 2:
            null.append(float((a @ r) ** 2 / na))
    return FaultTest(
        named=tuple(named),
        tested=len(idx),
        chi2=float(e @ e),
        dof=dof,
        residual_chi2=res,
        residual_dof=rdof,
        residual_p=_chi2_sf(res, rdof),
        scale=scale,
        level=level,
        null_z2=tuple(null),
        estimates=tuple(estimates),
    )


def _estimate(A, chosen, e, faults, tcp, level, floors, source, j) -> NamedChange:  # type: ignore[no-untyped-def]
    """Fault ``chosen[j]``'s size in the joint estimate of the ``chosen`` faults."""
    Ac = np.concatenate([A[k] for k in chosen], axis=1)
    cov = np.linalg.pinv(Ac.T @ Ac)
    s = cov @ (Ac.T @ e)
    start = sum(A[k].shape[1] for k in chosen[:j])
    k = chosen[j]
    kf = A[k].shape[1]
    sl = slice(start, start + kf)
    f = faults[k]
    if kf == 1:
        size = float(s[start])
        sigma = float(math.sqrt(max(cov[start, start], 0.0)))
        z = size / sigma if sigma > 0 else math.inf
        p = two_sided_p(z)
    else:  # the amplitude of a multi-parameter fault, its χ² test on k dof
        sk, ck = s[sl], cov[sl, sl]
        size = float(np.linalg.norm(sk))
        u = sk / size if size > 0 else np.eye(kf)[0]
        sigma = float(math.sqrt(max(u @ ck @ u, 0.0)))
        p = _chi2_sf(float(sk @ np.linalg.solve(ck, sk)), kf)
        z = _z_of_p(p)
    t = float(tcp[k]) if tcp is not None else math.nan
    floor = floors.get(f.unit)
    if floor is not None:
        large = abs(size) > floor
    else:  # a unit without a floor of its own (a joint scale): its TCP displacement counts
        large = not math.isfinite(t) or abs(size) * t > floors.get("m", 0.0)
    return NamedChange(
        fault=f.key, kind=f.kind.value, joint=f.joint, words=f.words, size=size, sigma=sigma,
        unit=f.unit, z=z, p_value=p, significant=bool(p < level and large),
        probability=1.0, prior=f.prior, cause=f.cause, action=f.action,
        tcp=abs(size) * t if math.isfinite(t) else math.nan, source=source,
    )  # fmt: skip


def _whitener(S: F) -> F:
    """``L⁻¹`` with ``L Lᵀ = S`` on its numerical range (rows: the range's directions)."""
    S = 0.5 * (S + S.T)
    w, V = np.linalg.eigh(S)
    keep = w > 1e-12 * max(float(w.max(initial=0.0)), 1e-300)
    return (V[:, keep] / np.sqrt(w[keep])).T


# --------------------------------------------------------------------------- two runs


@dataclass(frozen=True, eq=False)
class RunChange:
    """The change between two fits on the parameters they share (see the module doc):
    ``labels``, ``d`` (run − baseline) and ``S`` (both covariances)."""

    labels: tuple[str, ...]
    d: F
    S: F


def run_change(base, run, images: FaultImages | None = None) -> RunChange:  # type: ignore[no-untyped-def]
    """``d`` and ``S`` of two :class:`~.fit.FittedModel` on every parameter the baseline
    estimated but the base's.

    The run's coefficients are first put where the baseline's are: its Chebyshev series on
    the baseline's joint ranges (an exact re-expansion of the same polynomials), its target
    relative to the baseline's start transform, and, with ``images`` (the baseline's), any
    parameter the baseline held in the baseline's gauge (``images.transfer``).

    Raises
    ------
    ValueError
        The two fits have different error-model orders (refit the run at the baseline's
        first: the archive does).
    """
    sa, sb = base.spec, run.spec
    if not np.array_equal(sa.orders, sb.orders):
        raise ValueError("the runs' error models differ in orders: refit the run alike first")
    pb = dict(zip(run.labels, range(len(run.labels)), strict=True))
    held = set(base.unidentifiable) | set(base.held)
    # the run's parameters in the baseline's layout (zero where the run has none)
    idx = np.array([pb.get(lb, -1) for lb in base.labels], dtype=np.int64)
    has = idx >= 0
    Tr = _range_map(sa, sb)  # (nc, nc) on the Chebyshev block
    nc = sa.n_params
    M = np.zeros((len(base.labels), len(run.labels)))
    M[np.flatnonzero(has), idx[has]] = 1.0
    M[:nc, :] = Tr @ M[:nc, :]
    p_run = np.asarray(run.params, float).copy()
    for m, v in zip(MOTIONS, _tool_in_frame_of(base, run), strict=True):
        if f"tool.{m}.c0" in pb:
            p_run[pb[f"tool.{m}.c0"]] = v
    out_run = set(run.unidentifiable) | set(run.held)
    live = np.array([lb not in out_run for lb in run.labels])
    p_run = np.where(live, p_run, 0.0)
    Cb = np.asarray(run.cov, float)
    if images is not None and images.transfer is not None:
        M = images.transfer @ M
    x = M @ p_run
    Sx = M @ Cb @ M.T
    keep = [i for i, lb in enumerate(base.labels)
            if has[i] and lb not in held and not lb.startswith("base.")]  # fmt: skip
    ia = np.array(keep, dtype=np.int64)
    d = x[ia] - np.asarray(base.params, float)[ia]
    S = np.asarray(base.cov, float)[np.ix_(ia, ia)] + Sx[np.ix_(ia, ia)]
    return RunChange(tuple(base.labels[i] for i in keep), d, S)


def _range_map(sa, sb) -> F:  # type: ignore[no-untyped-def]
    """Chebyshev coefficients on ``sb``'s joint ranges → the same polynomials on ``sa``'s
    (same orders), block by block; the identity where the ranges agree."""
    from .errormodel import chebyshev_basis, chebyshev_u

    T = np.eye(sa.n_params)
    idx = sa.index()
    for j in range(1, sa.n_joints + 1):
        if sa.q_lo[j - 1] == sb.q_lo[j - 1] and sa.q_hi[j - 1] == sb.q_hi[j - 1]:
            continue
        for m in range(6):
            rows = np.flatnonzero((idx[:, 0] == j) & (idx[:, 1] == m))
            k = rows.size - 1
            if k <= 0:
                continue
            ua = np.cos(np.pi * (np.arange(k + 1) + 0.5) / (k + 1))  # Chebyshev nodes
            q = sa.q_lo[j - 1] + (ua + 1.0) * 0.5 * (sa.q_hi[j - 1] - sa.q_lo[j - 1])
            ub = chebyshev_u(q, sb.q_lo[j - 1], sb.q_hi[j - 1])
            Ba, Bb = chebyshev_basis(ua, k), chebyshev_basis(ub, k)
            T[np.ix_(rows, rows)] = np.linalg.solve(Ba, Bb)
    return T


def _tool_in_frame_of(base, run) -> F:  # type: ignore[no-untyped-def]
    """The run's target on the flange as six tool motions relative to the *baseline's* start
    transform (each fit starts from its own: the coefficients alone are not comparable)."""
    from .errormodel import constant_motions
    from .transforms import inv_T, small_error_transform

    m = constant_motions(run.spec, run.coeffs, -1)
    E = inv_T(base.T_flange_target0) @ run.T_flange_target0 @ small_error_transform(m[:3], m[3:])
    R = E[:3, :3]
    ey = math.asin(max(-1.0, min(1.0, float(R[0, 2]))))
    ex = math.atan2(-float(R[1, 2]), float(R[2, 2]))
    ez = math.atan2(-float(R[0, 1]), float(R[0, 0]))
    return np.array([E[0, 3], E[1, 3], E[2, 3], ex, ey, ez])


def name_run_change(
    change: RunChange,
    images: FaultImages,
    *,
    alpha: float = 1e-4,
    floors: Mapping[str, float] | None = None,
    scale: float | None = None,
    max_faults: int = 3,
) -> FaultTest:
    """Name the change between two runs by the faults of ``images`` (the baseline's).

    ``scale`` None estimates ``λ`` from this comparison (:func:`fault_scale`): named at
    ``λ = 1``, ``λ`` from the faults left, named again at ``λ``.
    """
    keep = images.testable()
    faults = [images.faults[k] for k in keep]
    blocks = [images.block(k, change.labels) for k in keep]
    tcp = [float(images.tcp[k]) for k in keep]
    kw = {"alpha": alpha, "floors": floors, "tcp": tcp, "max_faults": max_faults}
    if scale is not None:
        return name_changes(change.d, change.S, blocks, faults, scale=scale, **kw)  # type: ignore[arg-type]
    first = name_changes(change.d, change.S, blocks, faults, **kw)  # type: ignore[arg-type]
    lam = fault_scale(first.null_z2)
    if lam == 1.0:
        return first
    return name_changes(change.d, change.S, blocks, faults, scale=lam, **kw)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class TrendFaults:
    """The fault tests of a trend: one per run (None for the baseline, earlier runs and runs
    without a model), the Chebyshev coefficients the named faults explain per run (to leave
    out of the curve test), and lines to warn with."""

    tests: tuple[FaultTest | None, ...]
    explained: tuple[F | None, ...]
    warnings: tuple[str, ...]
    covs: tuple[F | None, ...] = ()  # per run: its Chebyshev block of :func:`robust_cov`


def fault_tests_of(
    runs: Sequence,  # type: ignore[type-arg]
    baseline_index: int,
    *,
    alpha: float = 1e-4,
    floors: Mapping[str, float] | None = None,
) -> TrendFaults:
    """Every run after the baseline tested along the faults (see the module doc), with ``λ``
    pooled over the comparisons so far (causal: a run is judged on the runs up to it).

    ``runs`` are :class:`~.trend.RunState` values; a run takes part when it and the baseline
    have a ``model`` at the same orders and ranges (the archive refits a run at the
    baseline's orders).
    """
    n = len(runs)
    tests: list[FaultTest | None] = [None] * n
    explained: list[F | None] = [None] * n
    covs: list[F | None] = [None] * n
    warnings: list[str] = []
    base = runs[baseline_index]
    if base.model is None:
        return TrendFaults(tuple(tests), tuple(explained), (), tuple(covs))
    from .faults import evaluation_poses, fault_dictionary, fault_images

    bm = base.model
    poses = base.poses if base.poses is not None else evaluation_poses(bm)
    images = fault_images(bm, fault_dictionary(bm.robot, bm.effects, setup=True), poses)
    rc = None if base.poses is None else robust_cov(bm, base.poses)
    if rc is not None:  # the spread over pose sets, where the poses are at hand
        bm = replace(bm, cov=rc)
        covs[baseline_index] = rc[: bm.spec.n_params, : bm.spec.n_params]
    pooled: list[float] = []
    for i in range(baseline_index + 1, n):
        r = runs[i]
        if r.model is None:
            continue
        rc = None if r.poses is None else robust_cov(r.model, r.poses)
        rm = r.model if rc is None else replace(r.model, cov=rc)
        if rc is not None:
            covs[i] = rc[: rm.spec.n_params, : rm.spec.n_params]
        try:
            ch = run_change(bm, rm, images)
        except ValueError:
            warnings.append(
                f"run {r.run_id}: its model has other orders than the baseline's: its change "
                "is not named by fault (refit it at the baseline's orders)"
            )
            continue
        first = name_run_change(ch, images, alpha=alpha, floors=floors, scale=1.0)
        pooled.extend(first.null_z2)
        lam = fault_scale(pooled)
        t = first if lam == 1.0 else name_run_change(ch, images, alpha=alpha, floors=floors,
                                                      scale=lam)  # fmt: skip
        tests[i] = t
        explained[i] = _explained(images, t, r.model)
        warnings.extend(f"run {r.run_id}: {c.line()}" for c in t.setup)
    return TrendFaults(tuple(tests), tuple(explained), tuple(warnings), tuple(covs))


def _explained(images: FaultImages, test: FaultTest, model) -> F | None:  # type: ignore[no-untyped-def]
    """The Chebyshev coefficients (model's layout) the significant faults account for."""
    if not test.estimates:
        return None
    labels = model.spec.labels()
    keys = {f.key: k for k, f in enumerate(images.faults)}
    out = np.zeros(len(labels))
    for key, sizes in test.estimates:
        out += images.block(keys[key], labels) @ np.asarray(sizes, float)
    return out


#: Poses (clusters) per estimated parameter below which :func:`robust_cov` is not used.
ROBUST_MIN_CLUSTERS = 5


def robust_cov(fitted, meas) -> F | None:  # type: ignore[no-untyped-def]
    """The fit's covariance as the spread of its estimate over *pose sets*: the cluster
    jackknife sandwich ``H⁻¹ (Σ_g s_g s_gᵀ) H⁻¹`` (CR3, Bell and McCaffrey) of the whitened
    problem at the estimate, ``s_g = J_gᵀ (I − J_g H⁻¹ J_gᵀ)⁻¹ r_g`` over clusters ``g`` (the
    rows of one pose id; each row its own without ids).  None when there are fewer than
    :data:`ROBUST_MIN_CLUSTERS` clusters per estimated parameter: the sandwich is then too
    noisy (30 poses of an 80-parameter fit made some directions ten times too narrow), and the
    fit's own covariance is used.

    A fit's own covariance assumes the model is right; on a real robot what the model misses
    is sampled differently by every pose set, and two sessions' estimates differ by more than
    their covariances say (on 30 splits of the shared UR10 series the faults' z² averaged 1.65
    with the fits' covariances, 1.49 with this one).  Same shape as ``fitted.cov`` (zero rows
    for parameters held)."""
    from .fit import linearised

    lin = linearised(fitted, meas)
    labels = list(fitted.labels)
    held = set(fitted.unidentifiable) | set(fitted.held)
    free = np.array([lb not in held for lb in labels])
    n, d = meas.n_poses, lin.d
    J = lin.J[:, free].reshape(n, d, -1)
    r = lin.r.reshape(n, d)
    H = J.reshape(n * d, -1).T @ J.reshape(n * d, -1) + np.diag(lin.sigma_p[free] ** -2.0)
    Hi = np.linalg.inv(0.5 * (H + H.T))
    ids = meas.pose_id if meas.pose_id is not None else tuple(range(n))
    _, inv = np.unique(np.asarray(ids, dtype=object).astype(str), return_inverse=True)
    sizes = np.bincount(inv)
    if sizes.size < ROBUST_MIN_CLUSTERS * int(free.sum()):
        return None
    scores = np.zeros((sizes.size, J.shape[2]))
    for size in np.unique(sizes):  # clusters of one size at a time, vectorised
        groups = np.flatnonzero(sizes == size)
        rows = np.stack([np.flatnonzero(inv == g) for g in groups])  # (m, size)
        Jg = J[rows].reshape(len(groups), size * d, -1)
        rg = r[rows].reshape(len(groups), size * d)
        h = Jg @ Hi @ np.swapaxes(Jg, 1, 2)
        eye = np.eye(size * d)
        adj = np.linalg.solve(eye - h, rg[..., None])[..., 0]
        scores[groups] = np.einsum("gkp,gk->gp", Jg, adj)
    C = np.zeros((len(labels), len(labels)))
    C[np.ix_(free, free)] = Hi @ (scores.T @ scores) @ Hi
    return C


def fault_scale(null_z2: Sequence[float], min_faults: int = 6) -> float:
    """``λ = max(1, median z² / median χ²₁)`` over the faults not named (1 with fewer than
    ``min_faults`` of them: too few to estimate)."""
    z2 = [x for x in null_z2 if math.isfinite(x)]
    if len(z2) < min_faults:
        return 1.0
    return max(1.0, float(np.median(z2)) / CHI2_1_MEDIAN)


__all__ = [
    "CHI2_1_MEDIAN",
    "FaultTest",
    "RunChange",
    "TrendFaults",
    "fault_tests_of",
    "fault_scale",
    "name_changes",
    "run_change",
    "name_run_change",
    "two_sided_p",
]
