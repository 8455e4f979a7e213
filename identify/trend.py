"""Degradation over time: what changed since the baseline, is it real, and where is it heading.

A pure library (no files, clocks or databases): runs come in as :class:`RunState` values, in
time order, and the answers go out as frozen dataclasses.  Four questions, one function each:

1. ``compare_curves``  which joint error curve changed against the baseline, judged against
   the *combined* uncertainty of both fits (a change inside it is not a degradation);
2. ``control_chart``   an upper EWMA control chart on each main figure (workspace mean, std
   and max TCP error) with limits from the runs' own scatter;
3. ``prognosis``       a straight-line trend of each figure, extrapolated to the user's
   tolerance: an estimated crossing time with a 95 % band, or "no trend";
4. ``assess_trend``    all of the above for one robot, with root-cause hints in words
   ("joint 2 tilt about x grew by 0.30 mrad since baseline") and the comparability warnings
   (plan, cell, calibration, software differing from the baseline).

SYNOPSIS::

    runs = [RunState(run_id, t_s, figures_mm={"mean": .., "std": .., "max": ..},
                     spec=spec, coeffs=c, cov=S, meta={"plan_hash": ..}), ...]
    result = assess_trend(runs, baseline_index=0, threshold_mm=0.5)
    result.flagged, result.hints, result.latest_alarms

Statistics
----------
*Curve change.*  Each motion ``m`` of joint ``j`` is ``B(u) c`` (Chebyshev, METHOD.md Eq. 3).
Both runs' curves are evaluated on a common grid of the joint range they share; the difference
``d`` has covariance ``Ba Σa Baᵀ + Bb Σb Bbᵀ`` (independent fits).  ``χ² = dᵀ C⁺ d`` on the
covariance's numerical range with ``dof = rank C`` gives a p-value; a change is significant
when ``p < alpha / n_curves`` (Bonferroni over all curves compared) *and* its largest size
over the range exceeds a practical minimum (``min_change_m`` / ``min_change_rad``).  Fits
tend to understate their own scatter (measured: the coefficients of 40 repeated 30-pose fits
of the same twin varied 1.2 times more in variance than reported, median, up to 4.8 times),
so χ² is divided by a genomic-control factor estimated across the curves (see
:func:`compare_curves`, ``inflate``).  What the
test leaves out: the covariances measure sampling noise of each fit, not model error; a motion
one fit could not identify (zero variance) only counts where it was estimated.

*Control chart.*  EWMA ``z_t = λ x_t + (1 − λ) z_{t−1}`` started at the in-control mean
``μ0`` (mean of the baseline and the next ``n_phase1 − 1`` runs, as far as they exist), with
``σ`` the larger of the moving-range estimate ``MR̄ / 1.128`` over the runs since the baseline
(insensitive to slow drift) and the runs' own reported uncertainty.  Alarm when ``z_t > μ0 +
L σ √(λ/(2−λ) (1 − (1−λ)^{2t}) + 1/m)`` (``m`` runs in ``μ0``).  Every verdict uses only the
runs up to it.  Only upward: a robot getting better is no alarm.

*Prognosis.*  Ordinary least squares ``x = a + b t`` over the runs since the baseline.  "No
trend" unless ``b > 0`` with one-sided ``p < 0.01``.  The crossing time solves ``a + b t =
tolerance``; its band is where the 95 % confidence band of the fitted line meets the tolerance
(the late end may be "beyond the horizon").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import special, stats

from .errormodel import MOTION_WORDS, MOTIONS, ErrorModelSpec, chebyshev_basis, chebyshev_u
from .errors import InputError
from .fault_test import FaultTest, fault_tests_of
from .faults import NamedChange

if TYPE_CHECKING:
    from .fit import FittedModel
    from .measurements import Measurements

F = NDArray[np.float64]
FIGURES: tuple[str, ...] = ("mean", "std", "max")
FIGURE_WORDS: dict[str, str] = {
    "mean": "workspace mean TCP error",
    "std": "workspace std of TCP error",
    "max": "workspace max TCP error",
}
COMPARABILITY_KEYS: tuple[str, ...] = ("plan_hash", "cell", "calibration_id", "software_version")
DAY_S = 86400.0


@dataclass(frozen=True, eq=False)
class RunState:
    """One assessment of one robot, as the trend needs it (SI).

    Attributes
    ----------
    run_id : str
    t_s : float, s
        Time of the run (any fixed epoch, e.g. Unix time).
    figures_mm : mapping of str to float, mm
        Main figures, keys from :data:`FIGURES` (``mean``, ``std``, ``max``); missing keys allowed.
    spec, coeffs, cov : the identified error model; ``cov`` shape (n_params, n_params) or None
    q_measured : (ndarray, ndarray), rad, optional
        Lowest and highest reading of each joint in the run: curves are compared only where
        both runs measured (outside it a series is an extrapolation).
    figure_sigma_mm : mapping of str to float, mm
        Standard uncertainty of each figure as the run itself reports it (optional).
    meta : mapping of str to str
        ``plan_hash``, ``cell``, ``calibration_id``, ``software_version`` …
    model : FittedModel, optional
        The whole fitted model (at the baseline's orders): changes are then tested along
        every physical fault and named by it (:mod:`.fault_test`).
    poses : Measurements, optional
        The run's measured poses (execution order); the baseline's are the evaluation set
        the faults are mapped through the gauge on.
    """

    run_id: str
    t_s: float
    figures_mm: Mapping[str, float] = field(default_factory=dict)
    spec: ErrorModelSpec | None = None
    coeffs: F | None = None
    cov: F | None = None
    figure_sigma_mm: Mapping[str, float] = field(default_factory=dict)
    meta: Mapping[str, str] = field(default_factory=dict)
    q_measured: tuple[F, F] | None = None  # (lo, hi) rad per joint: the range the run covered
    model: FittedModel | None = None
    poses: Measurements | None = None


@dataclass(frozen=True)
class CurveChange:
    """Change of one joint's error motion between the baseline and a run.

    ``max_change`` and ``rms_change`` are in m (``dx dy dz``) or rad (``ex ey ez``);
    ``peak_baseline`` / ``peak_run`` are the largest absolute values of the two curves.
    """

    joint: int  # 1-based
    motion: str  # one of MOTIONS
    chi2: float
    dof: int
    p_value: float
    z_max: float  # largest |difference| / its standard deviation over the grid
    max_change: float
    rms_change: float
    peak_baseline: float
    peak_run: float
    significant: bool
    inflation: float = 1.0  # factor applied to the combined covariance (see compare_curves)

    @property
    def is_angle(self) -> bool:
        """True for the rotations εx, εy, εz."""
        return self.motion.startswith("e")

    def hint(self) -> str:
        """The change in words, e.g. "joint 2 tilt about x grew by 0.30 mrad since baseline
        (χ² = 52.3 on 2 dof, p = 4.4e-12)": the χ² and its p, which agree (the largest
        pointwise z over the range, ``z_max``, is no test of its own and is not shown)."""
        size = (
            f"{self.max_change * 1e3:.2f} mrad"
            if self.is_angle
            else f"{self.max_change * 1e3:.3f} mm"
        )
        verb = "grew" if self.peak_run > self.peak_baseline else "changed"
        p = f"p = {self.p_value:.1e}" if self.p_value > 1e-300 else "p < 1e-300"
        return (
            f"joint {self.joint} {MOTION_WORDS[self.motion]} {verb} by {size} since baseline "
            f"(χ² = {self.chi2:.1f} on {self.dof} dof, {p})"
        )


@dataclass(frozen=True)
class ControlChart:
    """Upper EWMA chart of one figure over the runs since the baseline (mm)."""

    figure: str
    values_mm: tuple[float, ...]
    ewma_mm: tuple[float, ...]
    ucl_mm: tuple[float, ...]
    mu0_mm: float
    sigma_mm: float
    alarms: tuple[bool, ...]
    first_alarm: int | None  # index into values (0 = the baseline run)


@dataclass(frozen=True)
class Prognosis:
    """Straight-line extrapolation of one figure to the tolerance."""

    figure: str
    trend: bool
    slope_mm_per_day: float
    p_value: float
    tolerance_mm: float | None
    crossing_t_s: float | None  # estimated time the line reaches the tolerance
    crossing_early_t_s: float | None  # 95 % band, early end
    crossing_late_t_s: float | None  # 95 % band, late end; None = beyond the horizon
    already_above: bool
    last_t_s: float | None = None  # time of the last run the line was fitted to
    n_runs: int = 0  # runs the line was fitted to (0: too few for a trend)

    def days_from_last(self, t: float | None) -> float | None:
        """Days from the last run to ``t`` (None stays None)."""
        if t is None or self.last_t_s is None:
            return None
        return (t - self.last_t_s) / DAY_S

    def words(self) -> str:
        """One line for people."""
        name = FIGURE_WORDS.get(self.figure, self.figure)
        if self.already_above:
            return f"{name} is already above the tolerance of {self.tolerance_mm:g} mm"
        if not self.trend and self.n_runs == 0:
            return f"{name}: no trend (too few runs since the baseline for a trend)"
        if not self.trend:
            return f"{name}: no trend (slope p = {self.p_value:.2f})"
        s = f"{name} rises by {self.slope_mm_per_day * 30:.3f} mm per 30 days"
        if self.tolerance_mm is None or self.crossing_t_s is None:
            return s
        d = self.days_from_last(self.crossing_t_s)
        e = self.days_from_last(self.crossing_early_t_s)
        late = self.days_from_last(self.crossing_late_t_s)
        band = f"{e:.0f} to " + ("beyond the horizon" if late is None else f"{late:.0f} days")
        return s + f", reaching {self.tolerance_mm:g} mm in about {d:.0f} days ({band})"


@dataclass(frozen=True)
class TrendResult:
    """Everything ``quickhealth trend`` shows for one robot."""

    run_ids: tuple[str, ...]
    t_s: tuple[float, ...]
    baseline_index: int
    figures_mm: dict[str, tuple[float, ...]]  # figure -> value per run (NaN if absent)
    curve_changes: tuple[tuple[CurveChange, ...], ...]  # per run (empty for the baseline)
    charts: dict[str, ControlChart]
    prognoses: dict[str, Prognosis]
    threshold_mm: float | None
    threshold_figure: str
    breaches: tuple[bool, ...]  # per run: figure above the threshold
    warnings: tuple[str, ...]
    fault_tests: tuple[FaultTest | None, ...] = ()  # per run: the change named by faults

    @property
    def latest(self) -> int:
        """Index of the latest run."""
        return len(self.run_ids) - 1

    def significant_changes(self, index: int | None = None) -> list[CurveChange]:
        """Significant curve changes of a run (default the latest), largest z first."""
        i = self.latest if index is None else index
        ch = [c for c in self.curve_changes[i] if c.significant]
        return sorted(ch, key=lambda c: -c.z_max)

    def named_changes(self, index: int | None = None) -> list[NamedChange]:
        """The run's changes named by the physical fault that explains each (robot faults
        that passed the test; :mod:`.fault_test`), most evident first."""
        i = self.latest if index is None else index
        t = self.fault_tests[i] if i < len(self.fault_tests) else None
        return [] if t is None else list(t.robot)

    def setup_changes(self, index: int | None = None) -> list[NamedChange]:
        """Set-up changes the test found (the target moved on the flange): no fault of the
        robot, reported as warnings."""
        i = self.latest if index is None else index
        t = self.fault_tests[i] if i < len(self.fault_tests) else None
        return [] if t is None else list(t.setup)

    def alarms(self, index: int | None = None) -> list[str]:
        """Control-chart figures in alarm at a run (default the latest)."""
        i = (self.latest if index is None else index) - self.baseline_index
        if i < 0:
            return []
        return [f for f, c in self.charts.items() if i < len(c.alarms) and c.alarms[i]]

    def flags(self, index: int | None = None) -> list[str]:
        """Reasons a run is flagged, in words: the threshold breached, then
        :meth:`change_flags`; empty = healthy."""
        i = self.latest if index is None else index
        out = []
        if self.breaches[i]:
            v = self.figures_mm[self.threshold_figure][i]
            out.append(
                f"{FIGURE_WORDS[self.threshold_figure]} {v:.3f} mm is above the threshold "
                f"{self.threshold_mm:g} mm"
            )
        return out + self.change_flags(i)

    def change_flags(self, index: int | None = None) -> list[str]:
        """How a run changed since the baseline, in words: control-chart alarms, then error
        curves that changed (largest first).  Always empty for the baseline run itself: a run
        is never flagged against itself."""
        i = self.latest if index is None else index
        out: list[str] = []
        if i == self.baseline_index:
            return out
        for f in self.alarms(i):
            c = self.charts[f]
            k = i - self.baseline_index
            out.append(
                f"{FIGURE_WORDS[f]} EWMA {c.ewma_mm[k]:.3f} mm is above its control limit "
                f"{c.ucl_mm[k]:.3f} mm"
            )
        out.extend(c.line() for c in self.named_changes(i))
        out.extend(c.hint() for c in self.significant_changes(i))
        return out

    @property
    def flagged(self) -> bool:
        """Whether the latest run is flagged."""
        return bool(self.flags())

    @property
    def hints(self) -> list[str]:
        """Root-cause hints for the latest run: the named faults, then curve changes no
        fault explains (in words)."""
        return [c.line() for c in self.named_changes()] + [
            c.hint() for c in self.significant_changes()
        ]


# ---------------------------------------------------------------------------- curves


@dataclass(frozen=True, eq=False)
class JointCurves:
    """Every joint's six error curves with standard deviations on a grid over its range.

    ``q`` shape (n_grid, nj) rad; ``value`` and ``std`` shape (nj, 6, n_grid) in m / rad.
    """

    q: F
    value: F
    std: F


def _block(spec: ErrorModelSpec, j: int, m: int) -> slice:
    """Slice of the coefficient vector holding joint ``j`` (1-based) motion ``m``."""
    sizes = (spec.orders + 1).ravel()
    start = int(sizes[: j * 6 + m].sum())
    return slice(start, start + int(sizes[j * 6 + m]))


def _cov_or_zero(spec: ErrorModelSpec, cov: F | None) -> F:
    if cov is None:
        return np.zeros((spec.n_params, spec.n_params))
    c = np.asarray(cov, dtype=float)
    if c.shape != (spec.n_params, spec.n_params):
        raise ValueError(f"cov must be ({spec.n_params}, {spec.n_params}), got {c.shape}")
    return np.where(np.isfinite(c), c, 0.0)


def joint_curves(
    spec: ErrorModelSpec, coeffs: F, cov: F | None = None, n_grid: int = 101
) -> JointCurves:
    """Evaluate each joint's six error motions and their standard deviations over its range.

    Parameters
    ----------
    spec : ErrorModelSpec
    coeffs : ndarray, shape (n_params,)
    cov : ndarray, shape (n_params, n_params), optional
    n_grid : int

    Returns
    -------
    JointCurves
    """
    coeffs = np.asarray(coeffs, dtype=float)
    C = _cov_or_zero(spec, cov)
    nj = spec.n_joints
    q = np.linspace(spec.q_lo, spec.q_hi, n_grid)  # (n_grid, nj)
    value = np.zeros((nj, 6, n_grid))
    std = np.zeros((nj, 6, n_grid))
    for j in range(1, nj + 1):
        for m in range(6):
            s = _block(spec, j, m)
            k = s.stop - s.start
            if k == 0:
                continue
            B = chebyshev_basis(chebyshev_u(q[:, j - 1], spec.q_lo[j - 1], spec.q_hi[j - 1]), k - 1)
            value[j - 1, m] = B @ coeffs[s]
            std[j - 1, m] = np.sqrt(np.maximum(np.einsum("ik,kl,il->i", B, C[s, s], B), 0.0))
    return JointCurves(q=q, value=value, std=std)


def _curve_on(spec: ErrorModelSpec, coeffs: F, C: F, j: int, m: int, q: F) -> tuple[F, F]:
    """Curve values (n,) of joint j motion m at readings q, and a factor ``G`` (n, k) of their
    covariance ``G Gᵀ`` (k = number of coefficients: cheap where the grid is long)."""
    s = _block(spec, j, m)
    k = s.stop - s.start
    if k == 0:
        return np.zeros(q.size), np.zeros((q.size, 0))
    B = chebyshev_basis(chebyshev_u(q, spec.q_lo[j - 1], spec.q_hi[j - 1]), k - 1)
    w, Q = np.linalg.eigh(C[s, s])
    return B @ coeffs[s], B @ (Q * np.sqrt(np.maximum(w, 0.0)))


def compare_curves(
    base: RunState,
    run: RunState,
    *,
    alpha: float = 1e-4,
    min_change_m: float = 10e-6,
    min_change_rad: float = 20e-6,
    n_grid: int = 41,
    inflate: float | None = None,
) -> tuple[CurveChange, ...]:
    """Change of every joint error curve from ``base`` to ``run``, with its significance.

    Parameters
    ----------
    base, run : RunState
        Both need ``spec`` and ``coeffs``; ``cov`` None counts as exactly known.
    alpha : float
        Family-wise false-alarm probability per comparison (Bonferroni over the curves).
    min_change_m, min_change_rad : float
        Smallest change (largest over the range) worth calling a degradation.
    n_grid : int
        Grid points over the joint range both models share and both runs measured.
    inflate : float, optional
        Factor on the combined covariance.  None (default) estimates it from the comparison
        itself, as genomic control does: the median over all curves of ``χ² / median(χ²_dof)``,
        at least 1.  Most curves do not change between two runs, so the median measures how far
        the fits' covariances understate their real run-to-run scatter, and a few degraded
        curves do not move it.  1 trusts the covariances as they are.

    Returns
    -------
    tuple of CurveChange, one per (joint, motion) present in either model.
    """
    if base.spec is None or run.spec is None or base.coeffs is None or run.coeffs is None:
        return ()
    sa, sb = base.spec, run.spec
    if sa.n_joints != sb.n_joints:
        raise InputError(f"runs have {sa.n_joints} and {sb.n_joints} joints: not comparable")
    ca, cb = np.asarray(base.coeffs, float), np.asarray(run.coeffs, float)
    Ca, Cb = _cov_or_zero(sa, base.cov), _cov_or_zero(sb, run.cov)
    lo = np.maximum(sa.q_lo, sb.q_lo)
    hi = np.minimum(sa.q_hi, sb.q_hi)
    for r in (base, run):
        if r.q_measured is not None:
            lo = np.maximum(lo, np.asarray(r.q_measured[0], float))
            hi = np.minimum(hi, np.asarray(r.q_measured[1], float))
    present = [
        (j, m)
        for j in range(1, sa.n_joints + 1)
        for m in range(6)
        if sa.orders[j, m] >= 0 or sb.orders[j, m] >= 0
    ]
    n_tests = max(len(present), 1)
    raw = []
    for j, m in present:
        q = np.linspace(lo[j - 1], hi[j - 1], n_grid) if hi[j - 1] > lo[j - 1] else lo[[j - 1]]
        ya, Ga = _curve_on(sa, ca, Ca, j, m, q)
        yb, Gb = _curve_on(sb, cb, Cb, j, m, q)
        d = yb - ya
        G = np.hstack([Ga, Gb])  # covariance of d: G Gᵀ (independent fits)
        if G.shape[1]:
            U, S, _ = np.linalg.svd(G, full_matrices=False)
        else:
            U, S = np.zeros((q.size, 0)), np.zeros(0)
        keep = S > max(float(S.max(initial=0.0)) * math.sqrt(1e-9), 1e-15)
        dof = int(keep.sum())
        sd = np.sqrt(np.sum(G**2, axis=1))
        if dof == 0:  # both curves exactly known: any difference is certain
            chi2 = math.inf if np.any(np.abs(d) > 0) else 0.0
            z = math.inf if chi2 else 0.0
        else:
            proj = U[:, keep].T @ d
            chi2 = float(np.sum((proj / S[keep]) ** 2))
            with np.errstate(divide="ignore", invalid="ignore"):
                zz = np.where(sd > 0, np.abs(d) / np.where(sd > 0, sd, 1.0), 0.0)
            z = float(zz.max(initial=0.0))
        raw.append((j, m, d, ya, yb, chi2, dof, z))
    lam = 1.0
    if inflate is not None:
        lam = max(float(inflate), 1e-12)
    else:
        ratios = [c / _chi2_median(k) for *_, c, k, _ in raw if k > 0 and math.isfinite(c)]
        if len(ratios) >= 6:
            lam = max(1.0, float(np.median(ratios)))
    out = []
    for j, m, d, ya, yb, chi2, dof, z in raw:
        chi2 = chi2 / lam
        z = z / math.sqrt(lam)
        p = _chi2_sf(chi2, dof)
        max_change = float(np.abs(d).max(initial=0.0))
        floor = min_change_rad if MOTIONS[m].startswith("e") else min_change_m
        out.append(
            CurveChange(
                joint=j,
                motion=MOTIONS[m],
                chi2=chi2,
                dof=dof,
                p_value=p,
                z_max=z,
                max_change=max_change,
                rms_change=float(np.sqrt(np.mean(d**2))),
                peak_baseline=float(np.abs(ya).max(initial=0.0)),
                peak_run=float(np.abs(yb).max(initial=0.0)),
                significant=bool(p < alpha / n_tests and max_change > floor),
                inflation=lam,
            )
        )
    return tuple(out)


@lru_cache(maxsize=256)
def _chi2_median(dof: int) -> float:
    return float(stats.chi2.ppf(0.5, dof))


def _chi2_sf(chi2: float, dof: int) -> float:
    """Upper tail of χ²(dof) (scipy.special directly: the stats wrapper is slow)."""
    if dof <= 0:
        return 0.0 if chi2 else 1.0
    if not math.isfinite(chi2):
        return 0.0
    return float(special.chdtrc(dof, chi2))


def _null_ratios(changes: Sequence[CurveChange]) -> list[float]:
    """``χ²_raw / median(χ²_dof)`` of each curve: ≈ 1 in the median when covariances are right."""
    return [
        c.chi2 * c.inflation / _chi2_median(c.dof)
        for c in changes
        if c.dof > 0 and math.isfinite(c.chi2)
    ]


def rejudge(
    changes: Sequence[CurveChange],
    inflation: float,
    *,
    alpha: float = 1e-4,
    min_change_m: float = 10e-6,
    min_change_rad: float = 20e-6,
) -> tuple[CurveChange, ...]:
    """The same curve changes judged with another covariance inflation factor."""
    n_tests = max(len(changes), 1)
    out = []
    for c in changes:
        raw = c.chi2 * c.inflation
        chi2 = raw / inflation
        p = _chi2_sf(chi2, c.dof)
        floor = min_change_rad if c.is_angle else min_change_m
        out.append(
            replace(
                c,
                chi2=chi2,
                p_value=p,
                z_max=c.z_max * math.sqrt(c.inflation / inflation),
                significant=bool(p < alpha / n_tests and c.max_change > floor),
                inflation=inflation,
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------- control chart


def control_chart(
    values_mm: Sequence[float],
    *,
    figure: str = "",
    lam: float = 0.2,
    L: float = 4.5,
    n_phase1: int = 8,
    sigma_floor_mm: float = 0.0,
    min_runs: int = 6,
) -> ControlChart:
    """Upper EWMA control chart of one figure; ``values_mm[0]`` is the baseline run.

    Parameters
    ----------
    values_mm : sequence of float, mm
        The figure at the baseline and every later run, in time order (NaN = missing).
    lam, L : float
        EWMA weight and limit width in standard deviations.  λ = 0.2, L = 4.5 (with
        ``n_phase1 = 8``) gave 2 false alarms in 3000 simulated healthy 30-run histories, and
        caught a rise of 0.3 σ per run after 15 runs (median; 23 at most) in 300.
    n_phase1 : int
        Runs from the baseline on that define the in-control mean.
    sigma_floor_mm : float
        Smallest σ to use (e.g. the runs' own reported uncertainty of the figure).
    min_runs : int
        With fewer runs (and no ``sigma_floor_mm``) no alarm is raised: σ is not yet known.

    Returns
    -------
    ControlChart
    """
    x = np.asarray(values_mm, dtype=float)
    n = x.size
    z = np.full(n, math.nan)
    ucl = np.full(n, math.nan)
    alarms = np.zeros(n, dtype=bool)
    mu0 = sigma = math.nan
    prev = math.nan
    seen: list[float] = []
    for i in range(n):  # causal: run i is judged on runs 0..i only, as it was at the time
        if not math.isfinite(x[i]):
            z[i] = prev
            continue
        seen.append(float(x[i]))
        m = min(len(seen), n_phase1)
        mu0 = float(np.mean(seen[:m]))
        mr = np.abs(np.diff(seen))
        sigma = max(float(mr.mean() / 1.128) if mr.size else 0.0, float(sigma_floor_mm))
        # EWMA from the baseline on, restarted from the current in-control mean
        zz = mu0
        for v in seen[1:]:
            zz = lam * v + (1.0 - lam) * zz
        prev = zz
        t = len(seen) - 1
        width = lam / (2.0 - lam) * (1.0 - (1.0 - lam) ** (2 * t)) + 1.0 / m
        z[i] = zz
        ucl[i] = mu0 + L * sigma * math.sqrt(width)
        enough = sigma > 0 and (len(seen) >= min_runs or sigma_floor_mm > 0)
        alarms[i] = bool(enough and t > 0 and zz > ucl[i])
    first = int(np.argmax(alarms)) if alarms.any() else None
    return ControlChart(
        figure=figure,
        values_mm=tuple(map(float, x)),
        ewma_mm=tuple(map(float, z)),
        ucl_mm=tuple(map(float, ucl)),
        mu0_mm=mu0,
        sigma_mm=sigma,
        alarms=tuple(map(bool, alarms)),
        first_alarm=first,
    )


# ---------------------------------------------------------------------------- prognosis


def prognosis(
    t_s: Sequence[float],
    values_mm: Sequence[float],
    tolerance_mm: float | None,
    *,
    figure: str = "",
    p_max: float = 0.01,
    min_runs: int = 4,
    horizon_factor: float = 20.0,
) -> Prognosis:
    """Extrapolate a figure linearly in time to the tolerance.

    Parameters
    ----------
    t_s : sequence of float, s
    values_mm : sequence of float, mm
    tolerance_mm : float or None
    p_max : float
        One-sided p-value below which a rising slope counts as a trend.
    min_runs : int
        Fewer runs give "no trend".
    horizon_factor : float
        The band's late end is searched up to this many history spans after the last run.

    Returns
    -------
    Prognosis (times in the same epoch as ``t_s``).
    """
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(values_mm, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    above = bool(tolerance_mm is not None and y.size and y[-1] >= tolerance_mm)
    none = Prognosis(figure, False, 0.0, 1.0, tolerance_mm, None, None, None, above)
    if y.size < min_runs or np.ptp(t) <= 0:
        return none
    td = (t - t[0]) / DAY_S
    res = stats.linregress(td, y)
    n = y.size
    dof = n - 2
    resid = y - (res.intercept + res.slope * td)
    s2 = float(resid @ resid) / dof if dof > 0 else 0.0
    sxx = float(np.sum((td - td.mean()) ** 2))
    se_b = math.sqrt(s2 / sxx) if sxx > 0 else math.inf
    if se_b == 0.0:
        p = 0.0 if res.slope > 0 else 1.0
    else:
        p = float(stats.t.sf(res.slope / se_b, dof))
    if not (res.slope > 0 and p < p_max):
        return Prognosis(
            figure,
            False,
            float(res.slope),
            p,
            tolerance_mm,
            None,
            None,
            None,
            above,
            float(t[-1]),
            n,
        )
    if tolerance_mm is None or above:
        return Prognosis(
            figure,
            True,
            float(res.slope),
            p,
            tolerance_mm,
            None,
            None,
            None,
            above,
            float(t[-1]),
            n,
        )
    t_cross_d = (tolerance_mm - res.intercept) / res.slope
    span = max(td[-1] - td[0], 1.0)
    grid = np.linspace(td[-1], td[-1] + horizon_factor * span, 4001)
    tq = stats.t.ppf(0.975, dof) if dof > 0 else 0.0
    half = tq * np.sqrt(s2 * (1.0 / n + (grid - td.mean()) ** 2 / sxx))
    line = res.intercept + res.slope * grid
    hi_hit = np.nonzero(line + half >= tolerance_mm)[0]
    lo_hit = np.nonzero(line - half >= tolerance_mm)[0]
    early = grid[hi_hit[0]] if hi_hit.size else None
    late = grid[lo_hit[0]] if lo_hit.size else None

    def to_s(d: float | None) -> float | None:
        return None if d is None else float(t[0] + d * DAY_S)

    return Prognosis(
        figure,
        True,
        float(res.slope),
        p,
        tolerance_mm,
        to_s(float(t_cross_d)),
        to_s(None if early is None else float(early)),
        to_s(None if late is None else float(late)),
        above,
        float(t[-1]),
        n,
    )


# ------------------------------------------------------------------------------ assess


def comparability_warnings(
    runs: Sequence[RunState], baseline_index: int, keys: Sequence[str] = COMPARABILITY_KEYS
) -> tuple[str, ...]:
    """Warnings for runs whose plan, cell, calibration or software differ from the baseline."""
    base = runs[baseline_index].meta
    out = []
    for r in runs[baseline_index + 1 :]:
        for k in keys:
            a, b = base.get(k), r.meta.get(k)
            if a != b:
                out.append(
                    f"run {r.run_id}: {k.replace('_', ' ')} {b or '(unknown)'} differs from the "
                    f"baseline's {a or '(unknown)'}; the comparison may not be like for like"
                )
    return tuple(out)


def _same_poses(a: Measurements, b: Measurements) -> bool:
    """True when two runs measured the same poses (one plan): the same pose ids, or the same
    joint readings to a milliradian, row by row."""
    if a.pose_id is not None and b.pose_id is not None:
        return set(a.pose_id) == set(b.pose_id)
    return a.q.shape == b.q.shape and bool(np.all(np.abs(a.q - b.q) < 1e-3))


def _evaluation_figures(
    runs: Sequence[RunState], baseline_index: int, figs: dict[str, tuple[float, ...]]
) -> tuple[dict[str, tuple[float, ...]], tuple[str, ...]]:
    """The figures over the baseline's measured poses when the runs measured different poses
    (each model's workspace figure is over its own identified ranges and moves with the pose
    set: :func:`~.workspace.figures_over`); the runs' own figures otherwise.  A run's figures
    are over the baseline's poses inside its identified joint ranges."""
    from .workspace import figures_over

    base = runs[baseline_index]
    if base.model is None or base.poses is None:
        return figs, ()
    others = [r for r in runs[baseline_index + 1 :] if r.poses is not None]
    if not others or all(_same_poses(base.poses, r.poses) for r in others):
        return figs, ()
    q = base.poses.q
    out = {f: [math.nan] * len(runs) for f in FIGURES}
    narrow = []
    for i, r in enumerate(runs):
        if r.model is None:
            continue
        sp = r.model.spec
        inside = np.all((q >= sp.q_lo - 1e-9) & (q <= sp.q_hi + 1e-9), axis=1)
        if not inside.any():
            continue
        if not inside.all():
            narrow.append(f"{r.run_id} ({int(inside.sum())})")
        for f, v in figures_over(r.model, q[inside]).items():
            out[f][i] = v * 1e3
    words = (
        f"the runs measured different poses: the figures are over the baseline's {len(q)} "
        "measured poses (a fixed evaluation set), the error curves over the joint region both "
        "runs of a comparison measured"
        + (
            f"; runs over a narrower region use the poses inside it: {', '.join(narrow)}"
            if narrow
            else ""
        ),  # fmt: skip
    )
    return {f: tuple(v) for f, v in out.items()}, words


def assess_trend(
    runs: Sequence[RunState],
    baseline_index: int = 0,
    *,
    threshold_mm: float | None = None,
    threshold_figure: str = "max",
    tolerance_mm: float | None = None,
    alpha: float = 1e-4,
    min_change_m: float = 10e-6,
    min_change_rad: float = 20e-6,
    lam: float = 0.2,
    L: float = 4.5,
) -> TrendResult:
    """The whole trend of one robot: curve changes, control charts, prognosis, warnings.

    Parameters
    ----------
    runs : sequence of RunState, in time order
    baseline_index : int
        Index of the baseline run in ``runs``; earlier runs are shown but not compared.
    threshold_mm : float, optional
        A run whose ``threshold_figure`` exceeds it is a breach.
    threshold_figure : {"mean", "std", "max"}
    tolerance_mm : float, optional
        Level the prognosis extrapolates to (default: ``threshold_mm``).
    alpha, min_change_m, min_change_rad : see :func:`compare_curves`
    lam, L : see :func:`control_chart`

    Returns
    -------
    TrendResult
    """
    if not runs:
        raise ValueError("no runs to assess")
    if not 0 <= baseline_index < len(runs):
        raise ValueError(f"baseline index {baseline_index} outside 0..{len(runs) - 1}")
    if threshold_figure not in FIGURES:
        raise ValueError(f"threshold figure must be one of {FIGURES}, got {threshold_figure!r}")
    runs = list(runs)
    tol = threshold_mm if tolerance_mm is None else tolerance_mm
    figs = {f: tuple(float(r.figures_mm.get(f, math.nan)) for r in runs) for f in FIGURES}
    figs, eval_words = _evaluation_figures(runs, baseline_index, figs)
    base = runs[baseline_index]
    kw = {"alpha": alpha, "min_change_m": min_change_m, "min_change_rad": min_change_rad}
    named = fault_tests_of(
        runs, baseline_index, alpha=alpha, floors={"m": min_change_m, "rad": min_change_rad}
    )
    # the curves are judged on what the named faults leave (a zero offset is one change,
    # not one per gauge coordinate it moves)
    left = [
        r if e is None or r.coeffs is None else replace(r, coeffs=np.asarray(r.coeffs) - e)
        for r, e in zip(runs, named.explained, strict=True)
    ]
    # ... with the spread of each fit over pose sets where the poses are at hand
    covs = named.covs or (None,) * len(runs)
    left = [r if c is None else replace(r, cov=c) for r, c in zip(left, covs, strict=True)]
    raw = [
        () if i <= baseline_index else compare_curves(base, r, inflate=1.0, **kw)
        for i, r in enumerate(left)
    ]
    # genomic control pooled over every comparison so far (causal): steadier than one run's
    changes_l: list[tuple[CurveChange, ...]] = []
    pooled: list[float] = []
    for i, ch in enumerate(raw):
        if not ch:
            changes_l.append(())
            continue
        pooled.extend(_null_ratios(ch))
        # the genomic-control inflation factor; not ``lam``, the EWMA weight of the charts
        gc = max(1.0, float(np.median(pooled))) if len(pooled) >= 6 else 1.0
        judged = rejudge(ch, gc, **kw)
        t = named.tests[i]
        if t is not None and not t.residual_p < alpha:
            # the named faults explain the change (their residual is no change at the
            # trend's level): a curve alone is no flag.  On real data a high-order curve's
            # shape moves with the pose set by more than any covariance says (4 of 30 pairs
            # of sessions of the shared UR10 flagged joint 6's angular positioning curve)
            judged = tuple(replace(c, significant=False) for c in judged)
        changes_l.append(judged)
    changes = tuple(changes_l)
    charts, progs = {}, {}
    since = runs[baseline_index:]
    t_since = [r.t_s for r in since]
    for f in FIGURES:
        vals = figs[f][baseline_index:]
        if not np.any(np.isfinite(vals)):
            continue
        sig = [r.figure_sigma_mm.get(f, math.nan) for r in since]
        floor = float(np.nanmedian(sig)) if np.any(np.isfinite(sig)) else 0.0
        charts[f] = control_chart(vals, figure=f, lam=lam, L=L, sigma_floor_mm=floor)
        progs[f] = prognosis(t_since, vals, tol, figure=f)
    thr_vals = figs[threshold_figure]
    breaches = tuple(
        bool(threshold_mm is not None and math.isfinite(v) and v > threshold_mm) for v in thr_vals
    )
    return TrendResult(
        run_ids=tuple(r.run_id for r in runs),
        t_s=tuple(float(r.t_s) for r in runs),
        baseline_index=baseline_index,
        figures_mm=figs,
        curve_changes=changes,
        charts=charts,
        prognoses=progs,
        threshold_mm=threshold_mm,
        threshold_figure=threshold_figure,
        breaches=breaches,
        warnings=comparability_warnings(runs, baseline_index) + eval_words + named.warnings,
        fault_tests=named.tests,
    )
