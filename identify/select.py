"""Model-order selection by BIC (METHOD.md Eq. 9), with the paper's pruning rules and χ² check.

The search (a greedy descent over the order vector that may *jump*):

1. Start from the constant (geometric) model, every joint motion at order 0, and fit it.
2. Score every move from the current orders, linearised at the current estimate:
   raising any joint motion to **any** order up to ``max_order`` (not only +1: a
   position-dependent error often shows as one higher-order term whose lower orders do not
   lower the BIC), and lowering any motion to any lower order.  A move's new residual is the
   current one with the new columns' component projected out (ridge-regularised by their
   prior), so all ``nj·6·max_order`` moves cost one QR and a few matrix products.
3. Refit the best moves by the full ML fit (warm start) until one is accepted: a raise must
   lower the exact BIC by more than ``margin``, a lower is accepted unless it raises the BIC
   by more than ``margin`` (the same evidence bar for a term whichever side the search comes
   from); then apply the pruning rules; stop when no move is accepted.
4. Pruning (paper): the highest coefficient of a series is dropped (the order lowered) while
   it is below ``prune_fraction`` (8 %) of the largest non-constant coefficient of its
   series, or below its own standard uncertainty; kept only if the exact BIC does not rise.
5. χ² check: if χ² is above ``chi2_factor`` (5) times its median under the noise model,
   either the instrument is worse than assumed or the prior is too tight.  Parameters pushed
   beyond 3 prior sigmas point to the prior; otherwise to the instrument.  With
   ``auto_rescale`` the search reruns once with the suspected uncertainty raised.

``margin`` guards against the multiple comparisons a jump search makes: with M moves per
step, the best of M noise-only moves lowers the BIC by about ``ln M`` by chance (half the
largest of M χ² variates); the default margin is that value, so noise-only data stays at the
constant model.

Cost: one ML fit per accepted move plus one per rejected refit (typically 5–15 fits in all),
and one linearised scoring of all moves per step (milliseconds).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from .distributions import chi2_cdf, chi2_median, chi2_ppf
from .effects import Effect
from .errormodel import MOTIONS, ErrorModelSpec, chebyshev_basis
from .fit import (
    FittedModel,
    InstrumentNoise,
    ParameterPrior,
    bic_value,
    fit_model,
    linearised,
    parameter_labels,
    rotation_noise_cov,
)
from .measurements import Measurements
from .robot import RobotModel

F = NDArray[np.float64]


class StepKind(StrEnum):
    """What a step of the search did (report.json's ``search.steps[].kind``)."""

    START = "start"  # the fit at the starting orders
    RAISE = "raise"  # one motion's order up
    LOWER = "lower"  # one motion's order down
    PRUNE = "prune"  # the paper's pruning of a series' top coefficients
    RESCALE = "rescale"  # the χ² check failed: noise or prior rescaled, search run again


@dataclass(frozen=True)
class SearchStep:
    """One move the search tried."""

    kind: StepKind
    motion: str  # e.g. "j1.ez" ("" for start/rescale)
    from_order: int
    to_order: int
    bic_linear: float  # linearised prediction (nan where not applicable)
    bic: float  # exact BIC after refit (nan if not refitted)
    accepted: bool


@dataclass(frozen=True)
class Chi2Check:
    """The χ² check after convergence and its diagnosis."""

    chi2: float
    dof: int
    median: float
    ratio_to_median: float
    verdict: str  # "ok", "instrument", "prior", "overfit"
    message: str


@dataclass(frozen=True)
class NoiseScale:
    """How far the residuals scatter beyond the stated instrument uncertainty.

    ``excess_pos`` (m, per axis) and ``excess_rot`` (rad, per axis; None for position-only
    data) are added in quadrature to every row's stated uncertainty (model error, or an
    instrument worse than stated).  Estimated by :func:`estimate_noise_scale`; ``applied``
    when the χ² check showed the stated uncertainty too small, and then every band, σ and
    test uses it.
    """

    excess_pos: float
    excess_rot: float | None
    n_outliers: int
    n_poses: int
    chi2_ratio: float  # χ²/dof with the stated uncertainty
    stated_pos: float  # m, median stated per-axis uncertainty
    stated_rot: float | None  # rad
    band_factor: float = 1.0  # widening of the measurement part of the 95 % bands (tails)
    applied: bool = False

    @property
    def factor_pos(self) -> float:
        """Effective over stated position uncertainty (median row)."""
        return float(np.hypot(self.stated_pos, self.excess_pos) / self.stated_pos)

    @property
    def factor_rot(self) -> float | None:
        """Effective over stated orientation uncertainty (median row)."""
        if self.excess_rot is None or self.stated_rot is None:
            return None
        return float(np.hypot(self.stated_rot, self.excess_rot) / self.stated_rot)

    def describe(self) -> str:
        """One sentence for the CLI, report.json and the report's verdict line."""
        parts = [f"{self.excess_pos * 1e3:.3g} mm in position (x{self.factor_pos:.1f})"]
        if self.excess_rot is not None and self.factor_rot is not None:
            parts.append(
                f"{np.degrees(self.excess_rot):.3g} deg in orientation (x{self.factor_rot:.1f})"
            )
        what = " and ".join(parts)
        if not self.applied:
            return f"residual scatter beyond the stated uncertainty: {what} (not applied)"
        return (
            f"uncertainty estimated from the residuals: the stated instrument uncertainty is too "
            f"small for them (chi2/dof {self.chi2_ratio:.1f}), so every band, sigma and test adds "
            f"an estimated scatter of {what} (robust estimate, {self.n_outliers} of "
            f"{self.n_poses} poses set aside as outliers"
            + (
                f"; the residuals' tails widen the 95 % bands x{self.band_factor:.2f}"
                if self.band_factor > 1.0
                else ""
            )
            + ")"
        )

    def as_dict(self) -> dict[str, object]:
        """For report.json (mm, deg)."""
        return {
            "applied": self.applied,
            "excess_pos_mm": self.excess_pos * 1e3,
            "excess_rot_deg": None
            if self.excess_rot is None
            else float(np.degrees(self.excess_rot)),
            "factor_pos": self.factor_pos,
            "factor_rot": self.factor_rot,
            "n_outliers": self.n_outliers,
            "band_factor": self.band_factor,
            "chi2_ratio_stated": self.chi2_ratio,
            "estimator": SCALE_ESTIMATOR,
            "text": self.describe(),
        }


#: The documented estimator (docs/identify.md, "Honest uncertainty").
SCALE_ESTIMATOR = (
    "per block (position, orientation): each pose's squared Mahalanobis norm c_i(tau) of its "
    "residual under the stated covariance plus tau^2 I; tau0 makes median(c) the chi2_k "
    "median; poses with c_i(tau0) above the chi2_k 99.9 % point are outliers; tau makes the "
    "mean of c over the rest E[chi2_k | chi2_k <= that point] x (1 - n_parameters/n_components). "
    "Band factor: the ratio (at least 1, at most 3) of the 95 % quantile of the poses' position "
    "norms c_i(tau) to the chi2_3 95 % point, square-rooted: real residuals have heavier tails "
    "than a Gaussian, and the 95 % bands are widened by it to cover 95 % of the fitted poses"
)

#: Bounds of the band factor (tails of the residuals, :data:`SCALE_ESTIMATOR`).
BAND_FACTOR_MAX = 3.0


def estimate_noise_scale(fitted: FittedModel, meas: Measurements) -> NoiseScale:
    """Robust estimate of the residual scatter beyond the *stated* instrument uncertainty.

    The residual of pose ``i`` is modelled as ``N(0, Σ_i + τ² I)`` with ``Σ_i`` the stated
    covariance of its block (position or orientation) and ``τ`` one excess standard
    deviation per axis: model error and unstated instrument error do not shrink where the
    instrument's repeat spread is small, so they add, they do not scale.  A reweighted median
    estimator (:data:`SCALE_ESTIMATOR`): the median sets a first ``τ`` that a few outliers
    cannot move; poses beyond the 99.9 % point are set aside; the rest fix ``τ`` so that
    their mean matches the truncated χ² mean, corrected for the fitted parameters.
    """
    stated = fitted.noise.stated()
    n = meas.n_poses
    keep = np.ones(n, bool) if meas.excluded is None else ~np.asarray(meas.excluded, bool)
    sp = meas.sigma_pos if meas.sigma_pos is not None else np.full((n, 3), stated.sigma_pos)
    n_comp = max(int(keep.sum()), 1) * (6 if fitted.has_orientation else 3)
    shrink = max(1.0 - fitted.n_free / n_comp, 0.05)
    v_pos = np.asarray(sp, float)[keep] ** 2
    tau_pos, out = _excess_scatter(fitted.residual_pos[keep], v_pos, shrink)
    c_pos = np.sum(fitted.residual_pos[keep] ** 2 / (v_pos + tau_pos**2), axis=1)
    q95 = float(np.quantile(c_pos, 0.95)) if c_pos.size else 0.0
    band = float(np.clip(np.sqrt(q95 / (chi2_ppf(0.95, 3) * shrink)), 1.0, BAND_FACTOR_MAX))
    tau_rot = stated_rot = None
    if fitted.residual_rot is not None:
        lam, U = np.linalg.eigh(rotation_noise_cov(meas, stated.sigma_rot)[keep])
        r = np.einsum("nji,nj->ni", U, fitted.residual_rot[keep])  # in the eigenbasis
        tau_rot, out_rot = _excess_scatter(r, lam, shrink)
        out = out | out_rot
        stated_rot = float(np.median(np.sqrt(lam)))
    return NoiseScale(
        excess_pos=tau_pos,
        excess_rot=tau_rot,
        n_outliers=int(out.sum()),
        n_poses=int(keep.sum()),
        chi2_ratio=float(fitted.chi2_data / max(fitted.dof, 1)),
        stated_pos=float(np.median(np.sqrt(v_pos))),
        stated_rot=stated_rot,
        band_factor=band,
    )


def _excess_scatter(r: F, v: F, shrink: float) -> tuple[float, NDArray[np.bool_]]:
    """``τ`` with ``Σ_a r_ia² / (v_ia + τ²) ~ χ²_k`` (see :data:`SCALE_ESTIMATOR`) and the
    outlier mask; ``r``, ``v`` (n, k) in a basis where the stated covariance is diagonal."""
    k = r.shape[1]
    r2 = r * r

    def c(t2: float) -> F:
        return np.sum(r2 / (v + t2), axis=1)

    def solve(stat: Callable[[F], float], target: float) -> float:
        if stat(c(0.0)) <= target:
            return 0.0
        lo, hi = 0.0, float(np.max(r2)) * 10.0 + 1e-30
        for _ in range(200):  # bisection on the monotone statistic
            mid = 0.5 * (lo + hi)
            if stat(c(mid)) > target:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * hi:
                break
        return 0.5 * (lo + hi)

    if r.shape[0] == 0:
        return 0.0, np.zeros(0, bool)
    t2 = solve(lambda x: float(np.median(x)), chi2_median(k) * shrink)
    cut = chi2_ppf(0.999, k)
    out = c(t2) > cut
    inl = ~out
    trunc_mean = k * chi2_cdf(cut, k + 2) / chi2_cdf(cut, k)  # E[χ²_k | χ²_k ≤ cut]
    if inl.any():
        t2 = solve(lambda x: float(np.mean(x[inl])), trunc_mean * shrink)
    return float(np.sqrt(t2)), out


@dataclass(frozen=True, eq=False)
class Selection:
    """Result of the BIC search."""

    fitted: FittedModel
    trace: tuple[SearchStep, ...]
    chi2_check: Chi2Check
    n_fits: int
    n_scored: int
    margin: float
    noise: InstrumentNoise
    prior: ParameterPrior
    rescaled: tuple[str, ...] = field(default=())
    noise_scale: NoiseScale | None = None

    @property
    def orders(self) -> NDArray[np.int64]:
        """Selected orders, shape (nj + 2, 6)."""
        return self.fitted.spec.orders

    def summary(self) -> list[str]:
        """Lines for the CLI and report.json."""
        spec = self.fitted.spec
        raised = [
            f"{spec.frame_name(f)}.{MOTIONS[m]}={spec.orders[f, m]}"
            for f in range(1, spec.n_joints + 1)
            for m in range(6)
            if spec.orders[f, m] > 0
        ]
        lines = [
            "orders above 0: " + (", ".join(raised) if raised else "none (constant model)"),
            f"search: {self.n_fits} ML fits, {self.n_scored} linearised moves scored, "
            f"BIC margin {self.margin:.1f}",
            self.chi2_check.message,
        ]
        if self.noise_scale is not None and self.noise_scale.applied:
            lines.append(self.noise_scale.describe())
        elif self.rescaled:
            lines += [f"rerun with raised uncertainty: {r}" for r in self.rescaled]
        return lines


def data_spec(
    robot: RobotModel, meas: Measurements, order: int = 0, pad: float = 0.02
) -> ErrorModelSpec:
    """Constant model whose Chebyshev ranges span the measured joint range (padded by ``pad``).

    The series are only trusted where data was taken; predictions outside are extrapolations.
    """
    qmin, qmax = meas.q.min(0), meas.q.max(0)
    span = np.maximum(qmax - qmin, 1e-3)
    # padded, inside the robot's limits, but always covering every measured reading
    lo = np.minimum(np.maximum(qmin - pad * span, robot.q_min), qmin)
    hi = np.maximum(np.minimum(qmax + pad * span, robot.q_max), qmax)
    hi = np.where(hi <= lo, lo + 1e-3, hi)
    return ErrorModelSpec.uniform(robot.n_joints, order, lo, hi)


def select_orders(
    robot: RobotModel,
    meas: Measurements,
    effects: Sequence[Effect] = (),
    *,
    noise: InstrumentNoise = InstrumentNoise(),
    prior: ParameterPrior = ParameterPrior(),
    max_order: int = 6,
    start: ErrorModelSpec | None = None,
    margin: float | None = None,
    prune_fraction: float = 0.08,
    max_steps: int = 60,
    refits_per_step: int = 3,
    chi2_factor: float = 5.0,
    auto_rescale: bool = False,
    rescale: bool = True,
    progress: Callable[[str], None] | None = None,
    setup: tuple[F, F] | None = None,
    hold: Sequence[str] = (),
) -> Selection:
    """Choose the Chebyshev orders by BIC and return the final fit with the search trace.

    Parameters
    ----------
    max_order : int
        Cap of every joint motion's order (the search can jump to any order up to it).
    start : ErrorModelSpec, optional
        Initial orders and ranges; default :func:`data_spec` (constant model).
    margin : float, optional
        BIC drop a raise must achieve; default ``ln M`` for M moves per step.
    auto_rescale : bool
        Rerun once with the joint prior loosened when the χ² check blames the prior.
    rescale : bool
        When the χ² check shows the stated instrument uncertainty too small (above its
        99.9 % point, the prior not to blame), estimate the scale from the residuals
        (:func:`estimate_noise_scale`) and search again with it (default).  ``False`` keeps
        the stated uncertainty, and the check only reports.
    progress : callable, optional
        Receives one line per accepted move.
    setup, hold :
        Passed to the first :func:`~quickhealth.identify.fit.fit_model` (known base/tool,
        parameters held at their start values); later fits inherit them.
    """
    say = progress or (lambda s: None)
    if start is None and meas.n_poses > LARGE_DATA and not _needs_order(effects):
        return _staged(robot, meas, tuple(effects), noise, prior, max_order, margin,
                       prune_fraction, max_steps, refits_per_step, chi2_factor, auto_rescale,
                       rescale, say, setup, tuple(hold))  # fmt: skip
    spec0 = start if start is not None else data_spec(robot, meas)

    def search(
        noise_: InstrumentNoise,
        prior_: ParameterPrior,
        spec_: ErrorModelSpec,
        setup_: tuple[F, F] | None,
    ) -> Selection:
        """The search with everything but the uncertainties fixed (the χ² rerun changes them)."""
        return _search(
            robot,
            meas,
            tuple(effects),
            noise_,
            prior_,
            spec_,
            max_order,
            margin,
            prune_fraction,
            max_steps,
            refits_per_step,
            chi2_factor,
            say,
            setup_,
            tuple(hold),
        )

    if rescale:
        start = fit_model(robot, meas, spec0, tuple(effects), noise, prior, setup=setup,
                          hold=tuple(hold))  # fmt: skip
        if start.chi2_data > GROSS_SCATTER * max(start.dof, 1):
            # the stated uncertainty is far below the data's scatter (a tracker's repeat
            # spread): searching with it weights every pose hundreds of times above the
            # prior, raises spurious terms and drives the fits into their weak directions
            # (on a 9,529-row UR10 series 79 fits, six of them crawling 50 iterations).
            # Search with a provisional scale from the start model, then as before.
            est0 = estimate_noise_scale(start, meas)
            say(
                f"chi2 check: the start model's residuals scatter {est0.excess_pos * 1e3:.3g} "
                "mm beyond the stated position uncertainty; searching with that first"
            )
            sel0 = search(_with_scale(noise, meas, est0), prior, spec0, setup)
            return _rescaled(sel0, meas, noise, prior, search, setup, say, stated=noise)
    sel = search(noise, prior, spec0, setup)
    fitted = sel.fitted
    too_big = fitted.chi2_data > chi2_ppf(0.999, max(fitted.dof, 1))
    if rescale and too_big and sel.chi2_check.verdict != "prior":
        return _rescaled(sel, meas, noise, prior, search, setup, say)
    if auto_rescale and sel.chi2_check.verdict == "prior":
        prior2 = _loosen(prior)
        note = "joint prior sigmas × 10"
        say(f"χ² check failed ({sel.chi2_check.verdict}); rerunning with {note}")
        sel2 = search(noise, prior2, spec0, setup)
        return replace(
            sel2,
            trace=sel.trace
            + (SearchStep(StepKind.RESCALE, "", 0, 0, np.nan, np.nan, True),)
            + sel2.trace,
            n_fits=sel.n_fits + sel2.n_fits,
            n_scored=sel.n_scored + sel2.n_scored,
            rescaled=(f"{note} (first pass: {sel.chi2_check.message})",),
        )
    return sel


def _rescaled(
    sel: Selection,
    meas: Measurements,
    noise: InstrumentNoise,
    prior: ParameterPrior,
    search: Callable[
        [InstrumentNoise, ParameterPrior, ErrorModelSpec, tuple[F, F] | None], Selection
    ],
    setup: tuple[F, F] | None,
    say: Callable[[str], None],
    stated: InstrumentNoise | None = None,
) -> Selection:
    """The search again with the estimated uncertainty scale, from the orders found.

    ``stated``: the first search ran with a provisional scale, not with this stated
    uncertainty; its χ²/dof with the stated one is then evaluated at that search's result.

    The stated uncertainty weighted the data hundreds of times above the prior and the
    pruning's own-uncertainty rule; with the honest scale both work as intended.  One
    fixed-order refit follows when the scale moved by more than 10 % in the second pass.
    """
    est = estimate_noise_scale(sel.fitted, meas)
    noise2 = _with_scale(noise, meas, est)
    say(
        f"chi2 check: residuals scatter {est.excess_pos * 1e3:.3g} mm beyond the stated "
        "position uncertainty"
        + (
            f", {np.degrees(est.excess_rot):.3g} deg orientation"
            if est.excess_rot is not None
            else ""
        )
        + "; searching again with that uncertainty"
    )
    f = sel.fitted
    sel2 = search(noise2, prior, f.spec, setup or (f.T_instr_base0, f.T_flange_target0))
    n_fits = sel.n_fits + sel2.n_fits
    est2 = estimate_noise_scale(sel2.fitted, meas)
    moved = abs(est2.excess_pos / max(est.excess_pos, 1e-300) - 1) > 0.1 or (
        est.excess_rot is not None
        and est2.excess_rot is not None
        and abs(est2.excess_rot / max(est.excess_rot, 1e-300) - 1) > 0.1
    )
    fitted, check = sel2.fitted, sel2.chi2_check
    if moved:
        noise2 = _with_scale(noise, meas, est2)
        fitted = fit_model(
            fitted.robot, meas, fitted.spec, fitted.effects, noise2, prior, init=fitted
        )
        check = chi2_check(fitted)
        n_fits += 1
        est = est2
    # the bands' tail factor of the final model's own residuals (it changes no estimate)
    band = estimate_noise_scale(fitted, meas).band_factor
    noise2 = replace(noise2, band_factor=band)
    fitted = replace(fitted, noise=noise2)
    ratio = float(sel.fitted.chi2_data / max(sel.fitted.dof, 1))
    if stated is not None:
        lin = linearised(replace(sel.fitted, noise=stated), meas)
        ratio = float(lin.r @ lin.r) / max(sel.fitted.dof, 1)
    final = replace(est, band_factor=band, chi2_ratio=ratio, applied=True)
    say(final.describe())
    return Selection(
        fitted=fitted,
        trace=sel.trace
        + (SearchStep(StepKind.RESCALE, "", 0, 0, np.nan, np.nan, True),)
        + sel2.trace,
        chi2_check=check,
        n_fits=n_fits,
        n_scored=sel.n_scored + sel2.n_scored,
        margin=sel2.margin,
        noise=noise2,
        prior=prior,
        rescaled=(
            f"{final.describe()} (first pass: "
            + (
                f"chi2/dof {ratio:.1f} with the stated uncertainty)"
                if stated is not None
                else f"{sel.chi2_check.message})"
            ),
        ),  # fmt: skip
        noise_scale=final,
    )


#: Poses above which the orders are searched on :data:`SEARCH_POSES` of them (evenly through
#: the file) and the coefficients fitted on all of them (:func:`_staged`).
LARGE_DATA = 4000
SEARCH_POSES = 2000


def _needs_order(effects: Sequence[Effect]) -> bool:
    """True when an effect reads the execution order (a backlash's approach directions): a
    subset of the rows would change it."""
    return any("approach" in e.requires() for e in effects)


def _staged(robot, meas, effects, noise, prior, max_order, margin, prune_fraction, max_steps,
            refits_per_step, chi2_factor, auto_rescale, rescale, say, setup, hold) -> Selection:  # type: ignore[no-untyped-def]  # fmt: skip
    """The search on thousands of poses: the orders from :data:`SEARCH_POSES` of them (evenly
    spread through the file), the coefficients from all of them, with the scatter estimated
    again on every row.

    Every fit costs rows × parameters², and a real robot's model has three times the twin's
    parameters and five times its search steps: the search on all 9,529 rows of the UR10
    series resampled by pose took 58.8 s of CPU and 115 parameters, held-out 0.333 / 0.392 mm
    (mean / RMS); orders from 2,000 of them 4.1 s, 77 parameters, 0.339 / 0.398 mm (the same
    as a fit of the 1,200 rows it was resampled from)."""
    idx = np.unique(np.round(np.linspace(0, meas.n_poses - 1, SEARCH_POSES)).astype(np.int64))
    first = select_orders(robot, meas.subset(idx), effects, noise=noise, prior=prior,
                          max_order=max_order, margin=margin, prune_fraction=prune_fraction,
                          max_steps=max_steps, refits_per_step=refits_per_step,
                          chi2_factor=chi2_factor, auto_rescale=auto_rescale, rescale=rescale,
                          progress=say, setup=setup, hold=hold)  # fmt: skip
    say(f"orders from {len(idx)} of {meas.n_poses} poses; every pose fits the coefficients")
    f1 = first.fitted
    spec = data_spec(robot, meas).with_orders(f1.spec.orders)
    fitted = fit_model(robot, meas, spec, effects, first.noise, first.prior,
                       setup=setup or (f1.T_instr_base0, f1.T_flange_target0), hold=hold)  # fmt: skip
    noise2, scale, n_fits = first.noise, first.noise_scale, first.n_fits + 1
    if scale is not None:  # the scatter again on every row, at the final model
        est = estimate_noise_scale(fitted, meas)
        noise2 = _with_scale(noise, meas, est)
        moved = abs(est.excess_pos / max(scale.excess_pos, 1e-300) - 1) > 0.1 or (
            est.excess_rot is not None
            and scale.excess_rot is not None
            and abs(est.excess_rot / max(scale.excess_rot, 1e-300) - 1) > 0.1
        )
        if moved:
            fitted = fit_model(robot, meas, fitted.spec, effects, noise2, first.prior,
                               init=fitted)  # fmt: skip
            n_fits += 1
        band = estimate_noise_scale(fitted, meas).band_factor
        noise2 = replace(noise2, band_factor=band)
        fitted = replace(fitted, noise=noise2)
        scale = replace(est, band_factor=band, chi2_ratio=scale.chi2_ratio, applied=True)
    step = SearchStep(StepKind.START, f"all {meas.n_poses} poses", 0, 0, np.nan, fitted.bic, True)
    return Selection(
        fitted=fitted,
        trace=first.trace + (step,),
        chi2_check=chi2_check(fitted, chi2_factor),
        n_fits=n_fits,
        n_scored=first.n_scored,
        margin=first.margin,
        noise=noise2,
        prior=first.prior,
        rescaled=first.rescaled,
        noise_scale=scale,
    )


#: χ²/dof of the start (constant) model above which the stated uncertainty is taken as far
#: below the data's scatter and the search starts with a provisional scale (the twin: 1–34,
#: a hidden effect included; tracker series: 1,400–1,900).
GROSS_SCATTER = 100.0


def _with_scale(noise: InstrumentNoise, meas: Measurements, est: NoiseScale) -> InstrumentNoise:
    """``noise`` with the estimated excess scatter, and defaults taken from the data's own
    per-row uncertainties (for rows that state none later, e.g. a prediction's input)."""
    sp = float(np.median(meas.sigma_pos)) if meas.sigma_pos is not None else noise.sigma_pos
    sr = noise.sigma_rot
    if meas.sigma_rot is not None:
        sr = float(np.median(meas.sigma_rot))
    elif meas.sigma_rpy is not None:
        sr = float(np.median(meas.sigma_rpy))
    return replace(
        noise,
        sigma_pos=sp,
        sigma_rot=sr,
        excess_pos=est.excess_pos,
        excess_rot=est.excess_rot or 0.0,
        band_factor=est.band_factor,
    )


def chi2_check(
    fitted: FittedModel, factor: float = 5.0, loose_prior: FittedModel | None = None
) -> Chi2Check:
    """The paper's χ² check with its two diagnoses (instrument vs prior).

    ``loose_prior``: the same model refitted with joint prior sigmas × 10.  If that brings χ²
    back under ``factor`` × its median, the prior was too tight; otherwise the instrument
    (or a missing physical effect) is the cause.  Without it, parameters beyond 3 prior
    sigmas are taken as the sign of a tight prior.
    """
    dof = max(fitted.dof, 1)
    med = chi2_median(dof)
    ratio = fitted.chi2_data / med
    stated = (
        "the instrument uncertainty plus the scatter estimated from the residuals"
        if fitted.noise.rescaled
        else "the stated instrument uncertainty"
    )
    q001 = chi2_ppf(0.001, dof)
    if fitted.chi2_data < q001:  # the check fails both ways: far below the noise is overfitting
        return Chi2Check(
            fitted.chi2_data,
            dof,
            med,
            ratio,
            "overfit",
            f"the model follows the noise ({fitted.n_free} parameters for {fitted.n_poses} "
            f"poses), or {stated} is too large: measure more poses, lower --max-order, or "
            f"check the stated uncertainty (chi2 check FAILED: {fitted.chi2_data:.0f} is "
            f"{ratio:.2f} x its median {med:.0f}, below its 0.1 % point {q001:.0f})",
        )
    if ratio <= factor:
        q999 = chi2_ppf(0.999, dof)
        if fitted.chi2_data <= q999:
            msg = (
                f"the model explains the data down to the noise, consistent with {stated} "
                f"(chi2 check: {fitted.chi2_data:.0f} is {ratio:.2f} x its median {med:.0f})"
            )
        else:  # passes the paper's x5 rule, but is not what the stated noise would give
            msg = (
                f"the residuals are about x{np.sqrt(ratio):.1f} larger than {stated} (chi2 "
                f"check: {fitted.chi2_data:.0f} is {ratio:.2f} x its median {med:.0f}, above "
                f"the 99.9 % point {q999:.0f}; within the paper's x{factor:g} rule)"
            )
        return Chi2Check(fitted.chi2_data, dof, med, ratio, "ok", msg)
    if loose_prior is not None:
        ratio_loose = loose_prior.chi2_data / med
        is_prior = ratio_loose <= factor
        detail = f"with the joint prior 10x looser chi2 is {ratio_loose:.1f} x its median"
    else:
        z = np.abs(fitted.params) / np.maximum(_prior_sigmas(fitted), 1e-300)
        pushed = [lb for lb, zz in zip(fitted.labels, z, strict=True) if zz > 3.0]
        is_prior = bool(pushed)
        detail = f"{len(pushed)} parameters sit beyond 3 prior sigmas"
    if is_prior:
        verdict = "prior"
        why = f"the prior uncertainties are too small ({detail}); raise the prior and rerun"
    else:
        verdict = "instrument"
        why = (
            f"the instrument is worse than assumed ({detail}): check it against a calibration "
            f"artifact, or raise its uncertainty by about x{np.sqrt(fitted.chi2_data / dof):.1f} "
            "and rerun; a physical effect the model lacks shows this way too (run diagnose)"
        )
    return Chi2Check(
        fitted.chi2_data,
        dof,
        med,
        ratio,
        verdict,
        f"{why[0].upper()}{why[1:]} (chi2 check FAILED: {fitted.chi2_data:.0f} is {ratio:.1f} x "
        f"its median {med:.0f})",
    )


# --------------------------------------------------------------------------- internals


def _loosen(prior: ParameterPrior, factor: float = 10.0) -> ParameterPrior:
    return ParameterPrior(
        prior.joint_pos * factor, prior.joint_rot * factor, prior.setup_pos, prior.setup_rot
    )


def _prior_sigmas(fitted: FittedModel) -> F:
    return np.concatenate(
        [fitted.prior.sigmas(fitted.spec)]
        + [np.asarray(e.prior_sigma, float) for e in fitted.effects]
    )


@dataclass
class _Lin:
    """Linearisation of the current fit for scoring moves."""

    n: int
    d: int
    Q: F  # (m + P, P) orthonormal basis of the augmented normalised Jacobian
    b: F  # (m + P,) augmented residual
    Hinv: F  # (P, P) normalised
    x: F  # (P,) normalised free parameters
    A: F  # (m + P, P)
    free_idx: NDArray[np.int64]  # indices (into all params) of the free ones
    Jw: F  # (n, d, nj, 6) whitened motion Jacobian
    u: F  # (n, nj)
    n_free: int
    bp: F  # (m + P,) the residual projected off the current model (what a new term can take)
    bp_data: F  # (n, d) its data rows per pose
    bb: F  # (d, d) bp_dataᵀ bp_data


def _linearise(fitted: FittedModel, meas: Measurements) -> _Lin:
    lin = linearised(fitted, meas)
    p = fitted.params
    r, J, Jw, u = lin.r, lin.J, lin.J_motion, lin.u
    labels = fitted.labels
    fixed = set(fitted.unidentifiable) | set(fitted.held)
    free = np.array([lb not in fixed for lb in labels])
    D = lin.sigma_p[free]
    Jf = J[:, free] * D
    P = Jf.shape[1]
    A = np.vstack([Jf, np.eye(P)])
    b = np.concatenate([r, -(p[free] / D)])  # r(δ) ≈ b − A δ (model Jacobian)
    Q, _ = np.linalg.qr(A)
    H = A.T @ A
    Hinv = np.linalg.inv(H)
    x = Hinv @ (A.T @ b)  # remaining step (≈ 0 at the optimum)
    bp = b - Q @ (Q.T @ b)
    bpd = bp[: meas.n_poses * lin.d].reshape(meas.n_poses, lin.d)
    return _Lin(
        meas.n_poses,
        lin.d,
        Q,
        b,
        Hinv,
        x,
        A,
        np.flatnonzero(free),
        Jw,
        u,
        int(free.sum()),
        bp,
        bpd,
        bpd.T @ bpd,
    )


def _score_raises(lin: _Lin, j: int, m: int, cur: int, top: int, sigma: float) -> F:
    """Linearised BIC after raising joint ``j`` motion ``m`` from ``cur`` to each order
    ``cur + 1 … top``, shape (top − cur,).

    The new columns of all those orders are projected off the current model once; each
    order's one-step refit then needs only their Gram matrices: the residual's covariance
    ``RᵀR`` (d × d) follows from ``bᵀb``, ``Cᵀb`` and ``CᵀC`` resolved per component, so no
    residual vector is formed per move (cost ``O(n d P K)`` per motion, not per move).
    """
    n, d = lin.n, lin.d
    nd = n * d
    B = chebyshev_basis(lin.u[:, j], top)[:, cur + 1 : top + 1]  # (n, K)
    K = B.shape[1]
    C = (lin.Jw[:, :, j, m][:, :, None] * B[:, None, :]).reshape(nd, K) * sigma
    QtC = lin.Q[:nd].T @ C  # (P, K): the new columns' prior rows are zero
    Cp = C - lin.Q[:nd] @ QtC  # data rows of the projected columns
    Cp_prior = -lin.Q[nd:] @ QtC
    G = Cp.T @ Cp + Cp_prior.T @ Cp_prior + np.eye(K)
    g = Cp.T @ lin.bp[:nd] + Cp_prior.T @ lin.bp[nd:]
    M = Cp.reshape(n, d * K)  # column a*K + k: component a of column k
    Mcc = (M.T @ M).reshape(d, K, d, K)  # [a, k, b, l] = Σ_i Cp_ia,k Cp_ib,l
    Mcb = (M.T @ lin.bp_data).reshape(d, K, d)  # [a, k, b] = Σ_i Cp_ia,k b_ib
    out = np.empty(K)
    for k in range(1, K + 1):
        delta = np.linalg.solve(G[:k, :k], g[:k])
        cb = np.einsum("akb,k->ab", Mcb[:, :k], delta)
        cc = np.einsum("akbl,k,l->ab", Mcc[:, :k, :, :k], delta, delta)
        RtR = lin.bb - cb - cb.T + cc
        sign, logdet = np.linalg.slogdet(RtR / n + np.eye(d) * 1e-300)
        out[k - 1] = n / 2 * logdet + (lin.n_free + k + d) / 2 * np.log(n)
    return out


def _score_lower(lin: _Lin, cols: NDArray[np.int64]) -> float:
    """Linearised BIC after fixing the free parameters at positions ``cols`` to zero."""
    x = lin.x
    S = cols
    Hss = lin.Hinv[np.ix_(S, S)]
    full_x = x  # current point is the optimum: the parameters' values are in b's prior rows
    # parameter values (normalised) of the current estimate: −b_prior
    z = -lin.b[lin.A.shape[0] - lin.A.shape[1] :]
    target = z[S] + full_x[S]
    dx = -lin.Hinv[:, S] @ np.linalg.solve(Hss, target)
    res = lin.b - lin.A @ (full_x + dx)
    # prior rows change too: the removed parameters no longer carry a prior term
    res = res[: lin.n * lin.d].reshape(lin.n, lin.d)
    return bic_value(res, lin.n_free - len(S))


def _search(
    robot: RobotModel,
    meas: Measurements,
    effects: tuple[Effect, ...],
    noise: InstrumentNoise,
    prior: ParameterPrior,
    spec0: ErrorModelSpec,
    max_order: int,
    margin: float | None,
    prune_fraction: float,
    max_steps: int,
    refits_per_step: int,
    chi2_factor: float,
    say: Callable[[str], None],
    setup: tuple[F, F] | None = None,
    hold: tuple[str, ...] = (),
) -> Selection:
    nj = robot.n_joints
    fitted = fit_model(robot, meas, spec0, effects, noise, prior, setup=setup, hold=hold)
    n_fits = 1
    n_scored = 0
    trace: list[SearchStep] = [SearchStep(StepKind.START, "", 0, 0, np.nan, fitted.bic, True)]
    n_moves = nj * 6 * max_order
    if margin is None:
        margin = float(np.log(max(n_moves, 2)))
    visited = {fitted.spec.orders.tobytes()}
    say(f"start: constant model, BIC {fitted.bic:.1f}")
    for _step in range(max_steps):
        lin = _linearise(fitted, meas)
        orders = fitted.spec.orders
        labels = parameter_labels(fitted.spec, effects)
        pos_of = {lb: i for i, lb in enumerate(labels)}
        free_pos = {int(ix): k for k, ix in enumerate(lin.free_idx)}
        # the data must support the model with margin: at most half as many parameters as
        # measured components (as many residual degrees of freedom as parameters, so the
        # χ² check keeps its power; a 14-pose run fitted 62 parameters to 84 numbers)
        room = max_parameters(meas.n_poses * lin.d) - lin.n_free
        moves: list[tuple[float, StepKind, int, int, int]] = []
        for j in range(nj):
            for m in range(6):
                cur = int(orders[j + 1, m])
                sig = prior.joint_rot if m >= 3 else prior.joint_pos
                top = min(max_order, cur + max(room, 0))
                if cur < top:
                    bics = _score_raises(lin, j, m, cur, top, sig)
                    moves += [
                        (float(bic), StepKind.RAISE, j, m, cur + 1 + i)
                        for i, bic in enumerate(bics)
                    ]
                for new in range(max(cur - 1, -1), -1, -1) if cur > 0 else ():
                    cols = [
                        free_pos[pos_of[f"j{j + 1}.{MOTIONS[m]}.c{k}"]]
                        for k in range(new + 1, cur + 1)
                        if pos_of[f"j{j + 1}.{MOTIONS[m]}.c{k}"] in free_pos
                    ]
                    if not cols or new < 0:
                        continue
                    moves.append((_score_lower(lin, np.array(cols)), StepKind.LOWER, j, m, new))
        n_scored += len(moves)
        # the same evidence bar in both directions: a raise must lower the BIC by more than
        # the margin, and a lower is taken unless it raises the BIC by more than the margin
        # (else a start above the truth keeps the largest of many noise terms).
        moves = sorted(
            (mv for mv in moves if mv[0] < fitted.bic - _need(mv[1], margin)),
            key=lambda t: t[0],
        )
        accepted = False
        tried = 0
        for bic_lin, kind, j, m, new in moves:
            need = _need(kind, margin)
            if tried >= refits_per_step:
                break
            o2 = orders.copy()
            o2[j + 1, m] = new
            if o2.tobytes() in visited:
                continue
            tried += 1
            visited.add(o2.tobytes())
            cand = fit_model(
                robot, meas, fitted.spec.with_orders(o2), effects, noise, prior, init=fitted
            )
            n_fits += 1
            name = f"j{j + 1}.{MOTIONS[m]}"
            ok = cand.bic < fitted.bic - need
            trace.append(SearchStep(kind, name, int(orders[j + 1, m]), new, bic_lin, cand.bic, ok))
            if ok:
                say(
                    f"{name}: order {orders[j + 1, m]} -> {new}, BIC {fitted.bic:.1f} -> {cand.bic:.1f}"
                )
                fitted = cand
                accepted = True
                break
        if not accepted:
            break
        fitted, k_fits = _prune(
            robot, meas, effects, noise, prior, fitted, prune_fraction, trace, visited, say
        )
        n_fits += k_fits
    loose = None
    if fitted.chi2_data > chi2_factor * chi2_median(max(fitted.dof, 1)):
        loose = fit_model(robot, meas, fitted.spec, effects, noise, _loosen(prior), init=fitted)
        n_fits += 1
    check = chi2_check(fitted, chi2_factor, loose)
    say(check.message)
    return Selection(
        fitted=fitted,
        trace=tuple(trace),
        chi2_check=check,
        n_fits=n_fits,
        n_scored=n_scored,
        margin=float(margin),
        noise=noise,
        prior=prior,
    )


def max_parameters(n_components: int) -> int:
    """The most parameters a raise may bring a model to: half the measured components."""
    return n_components // 2


def _need(kind: StepKind, margin: float) -> float:
    """BIC drop a move must reach: ``margin`` for a raise, ``−margin`` for a lower."""
    return margin if kind is StepKind.RAISE else -margin


def _prune(
    robot: RobotModel,
    meas: Measurements,
    effects: tuple[Effect, ...],
    noise: InstrumentNoise,
    prior: ParameterPrior,
    fitted: FittedModel,
    fraction: float,
    trace: list[SearchStep],
    visited: set[bytes],
    say: Callable[[str], None],
) -> tuple[FittedModel, int]:
    """The paper's pruning rules on the top coefficients of every joint series."""
    spec = fitted.spec
    orders = spec.orders.copy()
    labels = fitted.labels
    val = dict(zip(labels, fitted.params, strict=True))
    sig = dict(zip(labels, fitted.sigma, strict=True))
    unid = set(fitted.unidentifiable)
    changed = []
    for f in range(1, spec.n_joints + 1):
        for m in range(6):
            cur = int(orders[f, m])
            o = cur
            while o >= 1:
                name = f"j{f}.{MOTIONS[m]}"
                c = np.array([abs(val[f"{name}.c{k}"]) for k in range(1, o + 1)])
                top = f"{name}.c{o}"
                small = c[-1] < fraction * c.max() or abs(val[top]) < sig[top] or top in unid
                if not small:
                    break
                o -= 1
            if o != cur:
                orders[f, m] = o
                changed.append((f"j{f}.{MOTIONS[m]}", cur, o))
    if not changed:
        return fitted, 0
    cand = fit_model(robot, meas, spec.with_orders(orders), effects, noise, prior, init=fitted)
    ok = cand.bic <= fitted.bic
    for name, a, b in changed:
        trace.append(SearchStep(StepKind.PRUNE, name, a, b, np.nan, cand.bic, ok))
    visited.add(orders.tobytes())
    if ok:
        say("pruned " + ", ".join(f"{n} {a}->{b}" for n, a, b in changed) + f", BIC {cand.bic:.1f}")
        return cand, 1
    return fitted, 1
