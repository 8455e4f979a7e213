"""Diagnosis: which physical effect does the fitted model miss, and how much would it help?

The fitted model is compared with the measurements pose by pose.  What it leaves in the
residuals is tested against every candidate effect of :mod:`quickhealth.identify.effects`
that the model does not have yet, as each registered effect type proposes them: e.g. gravity
compliance of each joint (residual against the joint's gravity torque), backlash of each joint
(against its approach direction), cyclic errors of every joint and harmonic (the residual
*spectrum* against each joint angle), thermal growth (against temperature), drift (against
time) and the instrument's depth scale (against the distance from the instrument).

The test is a linearised score (Lagrange-multiplier) test.  With whitened residuals ``r``
(n_obs,) and the fitted model's whitened Jacobian ``J`` at the estimate, a candidate's
Jacobian columns ``Z`` are projected off ``J`` (what the model can already absorb does not
count), ``Z⊥ = (I − P_J) Z``, and

    S = rᵀ P_{Z⊥} r     (the drop of the residual sum of squares a one-step refit would give)
    F = (S / k) / ((RSS − S) / (dof − k)),   k = rank Z⊥, dof = n_obs − rank J

is compared with the F distribution.  Because ~140 candidates are tested at once, the
p-values are Bonferroni-corrected (× the number of candidates): a noise-only data set then
raises a false alarm with probability below ``alpha`` (1 %).  The verdict is
``missing-effect`` when the best candidate is significant, else ``adequate``.  The one-step
refit also gives each candidate's predicted position RMS drop (mm) and parameter estimate.

SYNOPSIS::

    state = state_from_fitted(fitted)                # or LoopState(...)
    diag = diagnose(state, meas)                     # Diagnosis
    print("\\n".join(diag.summary()))
    fig = plot_candidate(state, meas, diag.candidates[0].effect)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .effects import (
    Effect,
    EffectContext,
    NotIdentifiable,
    ProposalOptions,
    missing_channels,
    parse_effect,
    propose,
    same_effect_key,
    total_perturbation,
)
from .errormodel import ErrorModelSpec, chebyshev_basis, chebyshev_u
from .linearize import (
    InstrumentNoise,
    Sensitivities,
    Whitening,
    coefficient_columns,
    effect_jacobian,
    loop_pose,
    measurement_context,
    noise_covariance,
    pose_residuals,
)
from .linearize import sensitivities as loop_sensitivities
from .measurements import Measurements
from .robot import RobotModel

F = NDArray[np.float64]

_NOISE = InstrumentNoise()


class Verdict(StrEnum):
    """Outcome of a diagnosis (the contract's strings)."""

    ADEQUATE = "adequate"
    MISSING_EFFECT = "missing-effect"


@dataclass(frozen=True, eq=False)
class LoopState:
    """A fitted loop model as the diagnosis sees it (SI units).

    ``T_instr_target = linearize.loop_pose(robot, spec, coeffs, T_instr_base0,
    T_flange_target0, q, Σ effect perturbations)``.

    Attributes
    ----------
    robot : RobotModel
    spec : ErrorModelSpec
    coeffs : ndarray, shape (spec.n_params,)
    T_instr_base0, T_flange_target0 : ndarray, shape (4, 4)
    effects : tuple of Effect
    effect_params : tuple of ndarray
    noise : InstrumentNoise
        The instrument and encoder noise the model assumes (the fit's, for a fitted model):
        the residuals are whitened with :func:`~.linearize.noise_covariance`, as in the fit.
    """

    robot: RobotModel
    spec: ErrorModelSpec
    coeffs: F
    T_instr_base0: F
    T_flange_target0: F
    effects: tuple[Effect, ...] = ()
    effect_params: tuple[F, ...] = ()
    noise: InstrumentNoise = _NOISE

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects in the model."""
        return tuple(e.name for e in self.effects)

    def with_effect(self, effect: Effect, params: F | None = None) -> LoopState:
        """The same model with one more effect (parameters zero unless given)."""
        p = np.zeros(effect.n_params) if params is None else np.asarray(params, float)
        return replace(
            self, effects=(*self.effects, effect), effect_params=(*self.effect_params, p)
        )


# --------------------------------------------------------------------------------------------
# Loop, residuals and Jacobians: all from quickhealth.identify.linearize
# --------------------------------------------------------------------------------------------

context_for = measurement_context


def model_pose(state: LoopState, ctx: EffectContext) -> F:
    """Model ``T_instr_target`` (n, 4, 4) of every pose, effects included."""
    pert = total_perturbation(state.effects, state.effect_params, ctx)
    return loop_pose(
        state.robot,
        state.spec,
        state.coeffs,
        state.T_instr_base0,
        state.T_flange_target0,
        ctx.q,
        pert,
    )


def whitening(state: LoopState, meas: Measurements, sens: Sensitivities) -> Whitening:
    """The per-pose whitening of ``meas`` under ``state``'s noise model (the fit's)."""
    return Whitening.of(noise_covariance(meas, state.noise, sens.dq))


def sensitivities(state: LoopState, ctx: EffectContext) -> Sensitivities:
    """Every channel's derivative of the loop at the estimate (:func:`~.linearize.sensitivities`)."""
    pert = total_perturbation(state.effects, state.effect_params, ctx)
    return loop_sensitivities(
        state.robot,
        state.spec,
        state.coeffs,
        state.T_instr_base0,
        state.T_flange_target0,
        ctx.q,
        pert,
    )


def chebyshev_jacobian(state: LoopState, ctx: EffectContext, sens: Sensitivities) -> F:
    """Derivative of the model pose with respect to every Chebyshev coefficient ``(n, 6, p)``."""
    Jmot = np.moveaxis(sens.frame_motion, 3, 1)  # (n, 6c, nf, 6m)
    return coefficient_columns(state.spec, ctx.q, Jmot)


@dataclass(frozen=True, eq=False)
class WhitenedProblem:
    """Whitened residuals and Jacobian of a fitted loop at its estimate.

    ``r = (measured − model) / σ`` flattened per pose; ``J = ∂model/∂p / σ`` so that a step
    ``Δp`` changes the residual by ``−J Δp``.
    """

    r: F  # (n_obs,)
    J: F  # (n_obs, n_params)
    labels: tuple[str, ...]
    whiten: Whitening
    n_comp: int  # 6 for pose data, 3 for position-only
    ctx: EffectContext
    sens: Sensitivities
    T_model: F


def whitened(state: LoopState, meas: Measurements) -> WhitenedProblem:
    """Residuals and Jacobian (Chebyshev coefficients, then effect parameters), whitened."""
    ctx = context_for(state.robot, meas)
    T = model_pose(state, ctx)
    res = pose_residuals(meas, T)
    c = res.shape[1]
    sens = sensitivities(state, ctx)
    wh = whitening(state, meas, sens)
    cols = [chebyshev_jacobian(state, ctx, sens)]
    labels = list(state.spec.labels())
    for e in state.effects:
        cols.append(effect_jacobian(e, ctx, sens))
        labels += [f"{e.name}.{p}" for p in e.param_names]
    Jp = wh.white(np.concatenate(cols, axis=2)[:, :c, :])
    return WhitenedProblem(
        r=wh.white(res).reshape(-1),
        J=Jp.reshape(-1, Jp.shape[2]),
        labels=tuple(labels),
        whiten=wh,
        n_comp=c,
        ctx=ctx,
        sens=sens,
        T_model=T,
    )


# --------------------------------------------------------------------------------------------
# Candidates and the score test
# --------------------------------------------------------------------------------------------


def candidate_names(
    robot: RobotModel,
    meas: Measurements,
    exclude: Sequence[str] = (),
    max_harmonic: int = 30,
) -> list[str]:
    """Every effect worth testing on this data set, minus those already in the model.

    Each registered effect type proposes its own (:func:`~.effects.propose`): e.g. compliance
    in its mass and lumped forms for every joint whose gravity load varies, backlash for a
    joint approached from both sides, thermal when the ``temp`` column varies, cyclic
    harmonics up to ``max_harmonic`` cycles per revolution.
    """
    ex = set(exclude)
    out = propose(robot, meas, ProposalOptions(max_harmonic=max_harmonic))
    return [c for c in out if c not in ex]


@dataclass(frozen=True)
class Candidate:
    """One candidate effect and the evidence for it.

    Attributes
    ----------
    effect : str
        Contract name, e.g. ``compliance:j2``.
    score : float
        ``−log10`` of the Bonferroni-corrected p-value (≥ 2 ⇔ significant at 1 %).
    lm_statistic : float
        Score statistic ``S / σ̂²`` (≈ χ² with ``dof`` degrees of freedom under no effect).
    dof : int
        Identifiable parameters of the candidate beyond the model (rank of ``Z⊥``).
    p_value : float
        Bonferroni-corrected p-value (capped at 1).
    delta_bic : float
        BIC change a one-step refit with the effect would give (negative = better).
    predicted_rms_drop_mm : float
        Position RMS (3D, mm) now minus after a one-step refit with the effect.
    rms_after_mm : float
        Predicted position RMS after adding it (mm).
    params : tuple of float
        One-step estimate of the effect's parameters (SI).
    significant : bool
        Bonferroni-corrected p-value below ``alpha`` *and* the effect explains at least
        ``min_share`` of the (whitened) residual sum of squares: a statistically detectable
        effect smaller than about a third of the noise is not worth a parameter.
    evidence : str
        The evidence in words.
    explained_share : float
        Fraction of the whitened residual sum of squares the effect would explain.
    f_statistic, f_dof2 : float, int
        The F statistic the p-value is of, on ``(dof, f_dof2)`` degrees of freedom (the
        residual variance estimated after the effect: the score statistic saturates at
        ``dof`` when the effect explains nearly everything, the F statistic does not).
    """

    effect: str
    score: float
    lm_statistic: float
    dof: int
    p_value: float
    delta_bic: float
    predicted_rms_drop_mm: float
    rms_after_mm: float
    params: tuple[float, ...]
    significant: bool
    evidence: str
    explained_share: float = float("nan")
    predicted_rot_drop_mrad: float | None = None
    rot_rms_after_mrad: float | None = None
    f_statistic: float = float("nan")
    f_dof2: int = 0

    @property
    def orientation_only(self) -> bool:
        """True when the effect would lower the orientation residual but not the position's
        (below 1 % of the position RMS): it moves the target's orientation, not the TCP."""
        return (
            self.predicted_rot_drop_mrad is not None
            and self.predicted_rot_drop_mrad > 0
            and self.predicted_rms_drop_mm
            <= max(1e-4, 0.01 * (self.rms_after_mm + self.predicted_rms_drop_mm))
        )

    def to_dict(self) -> dict[str, Any]:
        """The contract's keys (``effect``, ``score``, ``predicted_rms_drop_mm``, ``evidence``)
        first, then the details."""
        return {
            "effect": self.effect,
            "score": self.score,
            "predicted_rms_drop_mm": self.predicted_rms_drop_mm,
            "evidence": self.evidence,
            "significant": self.significant,
            "p_value": self.p_value,
            "lm_statistic": self.lm_statistic,
            "dof": self.dof,
            "f_statistic": self.f_statistic,
            "f_dof2": self.f_dof2,
            "delta_bic": self.delta_bic,
            "rms_after_mm": self.rms_after_mm,
            "params": list(self.params),
            "explained_share": self.explained_share,
            "predicted_rot_drop_mrad": self.predicted_rot_drop_mrad,
            "rot_rms_after_mrad": self.rot_rms_after_mrad,
            "orientation_only": self.orientation_only,
        }


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes
    ----------
    verdict : Verdict
    candidates : tuple of Candidate
        Best first: the significant ones by how much they lower the position RMS (then the
        orientation RMS; one that only moves the orientation comes after every one that moves
        the TCP, and says so), then the rest by p-value.
    n_tested : int
        Number of candidates tested (the Bonferroni factor).
    alpha : float
        Family-wise false-alarm rate.
    rms_pos_mm : float
        Position RMS (3D) of the model against the measurements now.
    rms_rot_mrad : float or None
    noise_scale : float
        σ̂ / σ assumed: ≈ 1 when the model explains the data down to the noise.
    spectra : dict of str to list of float
        Per joint (``j1`` …), the LM statistic of ``cyclic`` for harmonics 1, 2, …: the
        residual spectrum against that joint's angle.
    not_identifiable : tuple of str
        Candidates the model already absorbs completely (with why).
    notes : tuple of str
    order_hints : tuple of str
        Joints whose residuals still follow a smooth function of the joint angle (the
        Chebyshev orders are too low there: refit, this is no physical effect).
    suggested : tuple of str
        Forward selection: the effects to add together (the best first), each significant
        with the ones before it in the model; empty when adequate.
    """

    verdict: Verdict
    candidates: tuple[Candidate, ...]
    n_tested: int
    alpha: float
    rms_pos_mm: float
    rms_rot_mrad: float | None
    noise_scale: float
    spectra: dict[str, list[float]] = field(default_factory=dict)
    not_identifiable: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    suggested: tuple[str, ...] = ()
    order_hints: tuple[str, ...] = ()

    def to_dict(self, top: int | None = None) -> dict[str, Any]:
        """The contract's JSON: ``verdict`` and ``candidates`` (best first), plus details."""
        cands = self.candidates if top is None else self.candidates[:top]
        return {
            "verdict": self.verdict.value,
            "candidates": [c.to_dict() for c in cands],
            "n_tested": self.n_tested,
            "alpha": self.alpha,
            "rms_pos_mm": self.rms_pos_mm,
            "rms_rot_mrad": self.rms_rot_mrad,
            "noise_scale": self.noise_scale,
            "spectra": self.spectra,
            "not_identifiable": list(self.not_identifiable),
            "notes": list(self.notes),
            "suggested": list(self.suggested),
            "order_hints": list(self.order_hints),
        }

    def summary(self, top: int = 5) -> list[str]:
        """Lines for the command line and the TUI: what was found and what to do first, the
        statistics after, under their own heading."""
        best = next((c for c in self.candidates if c.significant), None)
        if self.verdict is Verdict.MISSING_EFFECT and best is not None:
            after = self.rms_pos_mm - best.predicted_rms_drop_mm
            lines = [
                f"a physical effect is missing from the model: {best.effect} (adding it would "
                f"lower the position residual from {self.rms_pos_mm:.4f} to {after:.4f} mm)",
                f"what to do: add it and compare on held-out data (quickhealth identify compare "
                f"MODEL MEAS --effects {best.effect})",
            ]
        elif self.noise_scale <= 1.5 and not self.order_hints:
            lines = ["no physical effect is missing: the model explains the data down to the noise"]
        else:
            lines = [
                "no candidate effect is significant, but the residuals are "
                f"{self.noise_scale:.1f} x the noise: see the notes below"
            ]
        rot = "" if self.rms_rot_mrad is None else f", rotation RMS {self.rms_rot_mrad:.3f} mrad"
        lines += [
            "statistics:",
            f"  verdict: {self.verdict.value}  (position RMS {self.rms_pos_mm:.4f} mm{rot}; "
            f"residual/noise {self.noise_scale:.2f}; {self.n_tested} candidates tested, "
            f"family-wise false-alarm rate {self.alpha:g})",
        ]
        for i, c in enumerate(self.candidates[:top], 1):
            mark = "*" if c.significant else " "
            change = _rms_change_words(c.predicted_rms_drop_mm, "mm", 4)
            if c.predicted_rot_drop_mrad is not None:
                change += ", orientation " + _rms_change_words(c.predicted_rot_drop_mrad, "mrad", 4)
            lines.append(
                f" {mark}{i:2d}. {c.effect:<16} score {c.score:7.2f}  position {change}  "
                f"— {c.evidence}"
            )
        lines += list(self.order_hints) + list(self.notes)
        return lines


def _rms_change_words(drop: float, unit: str, digits: int) -> str:
    """A predicted RMS drop as the change it makes: "−0.0004 mm" lower, "+0.0001 mm" higher."""
    return f"RMS {-drop:+.{digits}f} {unit}"


def _orthonormal_basis(J: F, rtol: float = 1e-7) -> F:
    """Orthonormal basis of the column space of ``J`` (columns scaled to unit norm first).

    Directions below ``rtol`` of the largest singular value are left out: they are the
    rounding noise of (near-)duplicate columns such as a held-at-zero constant, not
    something the model can fit.
    """
    norms = np.linalg.norm(J, axis=0)
    Jn = J[:, norms > 0] / norms[norms > 0]
    return _range_basis(Jn, lambda s: max(rtol, GRAM_RTOL) * (s[0] if s.size else 1.0))[0]


#: Smallest relative singular value a Gram matrix resolves (its eigenvalues carry ~1e-16).
GRAM_RTOL = 1e-6


def _gram_svd(X: F) -> tuple[F, F]:
    """Singular values (descending) and right singular vectors of a tall ``X`` from its Gram
    matrix ``XᵀX`` (one BLAS product and a small eigenproblem instead of an SVD of the tall
    matrix: 10 × faster at 10,000 poses).  Resolves singular values down to
    :data:`GRAM_RTOL` of the largest; the callers' thresholds sit at or above it."""
    w, V = np.linalg.eigh(X.T @ X)
    order = np.argsort(w)[::-1]
    return np.sqrt(np.clip(w[order], 0.0, None)), V[:, order]


def _range_basis(X: F, floor: Callable[[F], float]) -> tuple[F, F]:
    """Orthonormal basis ``U`` of the column space of a tall ``X`` (singular values above
    ``floor(s)`` kept) and the map ``W`` with ``U = X @ W``.

    Two Gram passes (CholeskyQR2's idea): one pass leaves ``U`` orthonormal only to about
    ε·(s₀/s)², 1e-4 for a direction kept at 1e-6 of the largest, and every projection on it
    inherits that error (a change of one unit in the last place of the data moved a
    candidate's RMS after by 4e-8).  ``U`` of the first pass is well conditioned, so the
    second makes it orthonormal to rounding, for the price of one more product.
    """
    s, V = _gram_svd(X)
    keep = s > floor(s)
    W = V[:, keep] / s[keep]
    U = X @ W
    s2, V2 = _gram_svd(U)
    W2 = V2 / s2
    return U @ W2, W @ W2


def rms_pos_mm(res: F) -> float:
    """3D position RMS ``sqrt(mean |e|²)`` of residuals ``(n, ≥3)`` (m) in mm."""
    return float(np.sqrt(np.mean(np.sum(res[:, :3] ** 2, axis=1))) * 1e3)


def diagnose(
    state: LoopState,
    meas: Measurements,
    candidates: Sequence[str] | None = None,
    alpha: float = 0.01,
    max_harmonic: int = 30,
    max_suggested: int = 3,
    min_share: float = 0.1,
    progress: Callable[[str], None] | None = None,
    advance: Callable[[int, int, str], None] | None = None,
) -> Diagnosis:
    """Test the residuals of a fitted model for every candidate effect.

    Parameters
    ----------
    state : LoopState
        The fitted model (see :func:`state_from_fitted`).
    meas : Measurements
        The data it was fitted to (or new data of the same robot and set-up).
    candidates : sequence of str, optional
        Effect names to test (default: :func:`candidate_names`).  A name that is explained,
        never fitted (``uniformscale``), may be asked about: it is reported as not
        identifiable, with the reason.
    alpha : float
        Family-wise false-alarm rate of the Bonferroni-corrected test.
    max_harmonic : int
        Highest cyclic harmonic tested by default.
    min_share : float
        Smallest share of the residual sum of squares a significant effect must explain
        (practical significance; 0.1 ≈ an effect a third of the noise in RMS).
    max_suggested : int
        Forward selection: after the best candidate, the others are tested again with it
        in the model, and so on while one stays significant, up to this many effects
        (``Diagnosis.suggested``).  A large effect leaves side peaks in other candidates;
        this tells them apart from a second real effect.
    progress, advance : callable, optional
        Receive each stage's name, and ``(done, total, what)`` while the candidates are
        tested (the command line's progress bar).

    The residuals and Jacobians are computed here (:func:`whitened`) with the model's
    instrument and encoder noise (:func:`whitening`), so the candidates' columns and the
    model's share one whitening; the model pose equals ``FittedModel.predict`` to rounding.

    Returns
    -------
    Diagnosis
    """
    say = progress or (lambda s: None)
    say("linearising the model at its estimate")
    wp = whitened(state, meas)
    r, J = wp.r, wp.J
    names = (
        list(candidates)
        if candidates is not None
        else candidate_names(state.robot, meas, _in_model(state), max_harmonic)
    )
    notes: list[str] = []
    not_ident: list[str] = []
    parsed: list[tuple[str, Effect]] = []
    for name in names:
        try:
            parsed.append((name, parse_effect(name, state.robot)))
        except NotIdentifiable as exc:
            not_ident.append(f"{exc.name}: {exc.reason}")
    names = [n for n, _ in parsed]
    Q = _orthonormal_basis(J)
    r_perp = r - Q @ (Q.T @ r)
    rss = float(r_perp @ r_perp)
    n_obs = r.size
    dof_res = n_obs - Q.shape[1]
    s2 = rss / max(dof_res, 1)
    c = wp.n_comp
    res_now = wp.whiten.unwhite(r.reshape(-1, c))
    rms_now = rms_pos_mm(res_now)
    rms_rot = _rms_rot_mrad(res_now) if c == 6 else None
    m_tests = max(len(names), 1)
    effects: list[Effect] = []
    for name, effect in parsed:
        missing = missing_channels(effect, meas)
        if missing:
            notes.append(f"{name} not tested: the data have no {', '.join(missing)} column")
            continue
        effects.append(effect)
    raw: list[tuple[float, Candidate]] = []
    spectra: dict[str, list[float]] = {}
    bases = _bases(state, wp, Q, r)
    for effect, one, logp_adj, s2_c, one_plain, f_test in _scan(
        wp, bases, effects, m_tests, advance
    ):
        if one is None:
            not_ident.append(
                f"{effect.name}: the fitted model already expresses it (its Jacobian lies in "
                "the model's), so the data cannot tell it apart"
            )
            continue
        k, S = one[0], one[1]
        _, _, theta, fit_res = one_plain if one_plain is not None else one
        p_adj = float(np.exp(logp_adj))
        score = max(0.0, float(-logp_adj / np.log(10.0)))
        rms_after = rms_pos_mm(res_now - fit_res)
        rot_after = _rms_rot_mrad(res_now - fit_res) if c == 6 else None
        lm = S / s2_c
        dbic = -S / s2_c + k * np.log(n_obs)
        share = float(S / rss) if rss > 0 else 0.0
        cand = Candidate(
            effect=effect.name,
            score=score,
            lm_statistic=float(lm),
            dof=k,
            f_statistic=float(f_test[0]),
            f_dof2=int(f_test[1]),
            p_value=p_adj,
            delta_bic=float(dbic),
            predicted_rms_drop_mm=float(rms_now - rms_after),
            rms_after_mm=float(rms_after),
            params=tuple(float(v) for v in theta),
            significant=bool(p_adj < alpha and share >= min_share),
            evidence="",
            explained_share=share,
            predicted_rot_drop_mrad=(
                None if rms_rot is None or rot_after is None else float(rms_rot - rot_after)
            ),
            rot_rms_after_mrad=rot_after,
        )
        raw.append((logp_adj, cand))
        spectrum_bin = effect.spectrum_bin()
        if spectrum_bin is not None:
            jk, h = spectrum_bin
            spec_list = spectra.setdefault(jk, [])
            while len(spec_list) < h:
                spec_list.append(0.0)
            spec_list[h - 1] = float(lm)
    raw = _prefer_simpler_form(raw, {e.name: e for e in effects}, alpha)
    raw.sort(key=lambda t: _rank(t[1], t[0]))
    cands = tuple(
        replace(c_, evidence=_evidence(c_, state, spectra, m_tests, rms_now)) for _, c_ in raw
    )
    verdict = Verdict.MISSING_EFFECT if cands and cands[0].significant else Verdict.ADEQUATE
    suggested: tuple[str, ...] = ()
    if verdict is Verdict.MISSING_EFFECT:
        say("forward selection of the effects to add together")
        suggested = _forward(
            state, wp, Q, r, effects, cands[0].effect, m_tests, alpha, max_suggested
        )
        rest = [c_.effect for c_ in cands[1:] if c_.significant and c_.effect not in suggested]
        if len(suggested) == 1:
            notes.append(
                f"with {suggested[0]} in the model no other candidate is significant"
                + (f" ({len(rest)} others were only its side effects)" if rest else "")
            )
        else:
            notes.append(
                f"forward selection: {', '.join(suggested)} each stay significant with the "
                "ones before them in the model: add them together"
            )
    noise_scale = float(np.sqrt(s2))
    hints = _order_hints(state, wp, bases, alpha) if verdict is Verdict.ADEQUATE else []
    if verdict is Verdict.ADEQUATE and noise_scale > 1.5 and not hints:
        notes.append(
            f"the residuals are {noise_scale:.1f}× the assumed instrument noise but have no "
            "structure any candidate explains: the instrument may be worse than assumed, or "
            "the error model's orders too low"
        )
    return Diagnosis(
        verdict=verdict,
        candidates=cands,
        n_tested=m_tests,
        alpha=alpha,
        rms_pos_mm=rms_now,
        rms_rot_mrad=rms_rot,
        noise_scale=noise_scale,
        spectra=spectra,
        not_identifiable=tuple(not_ident),
        notes=tuple(notes),
        suggested=suggested,
        order_hints=tuple(hints),
    )


def _rms_rot_mrad(res: F) -> float:
    """Orientation RMS ``sqrt(mean |w|²)`` of residuals ``(n, 6)`` (rad) in mrad."""
    return float(np.sqrt(np.mean(np.sum(res[:, 3:] ** 2, axis=1))) * 1e3)


def _prefer_simpler_form(
    raw: list[tuple[float, Candidate]], effects: dict[str, Effect], alpha: float
) -> list[tuple[float, Candidate]]:
    """Of two forms of one physical effect (:attr:`~.effects.Effect.physical`), the one with
    more parameters (a joint's lumped compliance: it estimates the moments, an unknown payload
    included) only counts where it explains significantly more than each form with fewer
    parameters tested (nested χ² test at ``alpha``); otherwise it is marked not significant,
    so the simpler form (the known masses) is ranked and suggested.  A form with as many
    parameters as the plain one (``compliance:j2:torque`` beside ``compliance:j2``) is held
    to the same test with one degree of freedom: the two regressors are nearly the same where
    the model's masses are right, and which one comes first must not be a coin toss."""
    from scipy import stats

    forms: dict[str, list[Candidate]] = {}
    for _, c in raw:
        forms.setdefault(effects[c.effect].physical, []).append(c)
    out = []
    for logp, c in raw:
        e = effects[c.effect]
        n = e.n_params
        simpler = [
            s
            for s in forms[e.physical]
            if effects[s.effect].n_params < n
            or (effects[s.effect].n_params == n and s.effect == e.physical != c.effect)
        ]
        for s in simpler if c.significant else ():
            extra = c.lm_statistic - s.lm_statistic
            # a form with as many parameters as the plain one (the measured torque for the
            # model's gravity torque) must explain as much more as one added parameter would
            # have to: a lower bound of the encompassing test with both regressors
            k = max(c.dof - s.dof, 1)
            p = float(stats.chi2.sf(max(extra, 0.0), k))
            if p >= alpha:
                c = replace(c, significant=False)
                break
        out.append((logp, c))
    return out


def _rank(c: Candidate, logp_adj: float) -> tuple[float, ...]:
    """Sort key: significant candidates first, by position RMS drop (a TCP that moves
    matters more than an orientation), those that only move the orientation after them by
    their orientation drop; then the rest by p-value."""
    if not c.significant:
        return (2.0, logp_adj, -c.predicted_rms_drop_mm)
    rot = c.predicted_rot_drop_mrad or 0.0
    if c.orientation_only:
        return (1.0, -rot, logp_adj)
    return (0.0, -c.predicted_rms_drop_mm, -rot)


def _in_model(state: LoopState) -> tuple[str, ...]:
    """Names the model already has, with the physical effect each is a form of (a model with
    ``compliance:j2:lumped`` has ``compliance:j2``)."""
    return state.effect_names + tuple(same_effect_key(e) for e in state.effects)


ORDER_BLOCK = 6  # Chebyshev orders a joint candidate must beat (see _nuisance_joints)


def _order_block(state: LoopState, wp: WhitenedProblem, joint: int, order: int = ORDER_BLOCK) -> F:
    """Whitened columns of every error motion of ``joint`` (0-based) at orders 1 … ``order``."""
    spec = state.spec
    u = chebyshev_u(wp.ctx.q[:, joint], spec.q_lo[joint], spec.q_hi[joint])
    B = chebyshev_basis(u, order)[:, 1:]  # (n, order)
    S = wp.sens.frame_motion[:, joint + 1, :, : wp.n_comp]  # (n, 6 motions, c)
    cols = S[:, :, None, :] * B[:, None, :, None]  # (n, 6, order, c)
    cols = np.moveaxis(cols.reshape(cols.shape[0], -1, wp.n_comp), 1, 2)  # (n, c, 6·order)
    return wp.whiten.white(cols).reshape(-1, 6 * order)


@dataclass(frozen=True, eq=False)
class _Basis:
    """What a candidate is tested against: the model's columns (plus nuisance columns)."""

    Q: F
    r_perp: F
    rss: float
    dof: int

    @classmethod
    def of(cls, Q: F, r: F) -> _Basis:
        rp = r - Q @ (Q.T @ r)
        return cls(Q, rp, float(rp @ rp), int(r.size - Q.shape[1]))


def _nuisance_joints(effect: Effect, nj: int) -> tuple[int, ...]:
    """Joints whose smooth (Chebyshev) errors a candidate must be more than, as the effect
    declares (:meth:`~.effects.Effect.nuisance_joints`): backlash and cyclic errors of joint K
    against higher orders of joint K, compliance of joint K against joints K and K+1."""
    return tuple(effect.nuisance_joints(nj))


class _Bases:
    """What candidates are tested against: the model's columns plus nuisance columns.

    The model's own basis is kept; of the others only the last one asked for (each is poses ×
    parameters: at 20,000 poses a dozen of them held 1.2 GB).  :func:`_scan` takes the
    candidates grouped by their nuisance joints, so each basis is still made once.
    """

    def __init__(self, state: LoopState, wp: WhitenedProblem, Q: F, r: F) -> None:
        self.state, self.wp, self.Q, self.r = state, wp, Q, r
        self._plain = _Basis.of(Q, r)
        self._last: tuple[tuple[int, ...], _Basis] | None = None

    def __getitem__(self, joints: tuple[int, ...]) -> _Basis:
        if not joints:
            return self._plain
        if self._last is None or self._last[0] != joints:
            self._last = None  # let the previous one go before the next is made
            blocks = [_order_block(self.state, self.wp, j) for j in joints]
            cols = np.concatenate([self.Q, *blocks], axis=1)
            self._last = (joints, _Basis.of(_orthonormal_basis(cols), self.r))
        return self._last[1]


def _bases(state: LoopState, wp: WhitenedProblem, Q: F, r: F) -> _Bases:
    """Bases for the candidates of :func:`diagnose` (see :func:`_nuisance_joints`)."""
    return _Bases(state, wp, Q, r)


_OneStep = tuple[int, float, F, F]


def _scan(
    wp: WhitenedProblem,
    bases: _Bases,
    effects: Sequence[Effect],
    m_tests: int,
    advance: Callable[[int, int, str], None] | None = None,
) -> list[tuple[Effect, _OneStep | None, float, float, _OneStep | None, tuple[float, int]]]:
    """Score test of every effect.

    Returns ``(effect, conditional one-step, log adjusted p, σ̂², plain one-step, (F, dof2))``:
    the test is conditional on the candidate's nuisance columns (:func:`_nuisance_joints`);
    the plain one-step (against the model alone) gives what adding the effect to *this*
    model would do, for the predicted RMS drop and the parameter estimate; ``F`` on ``(dof,
    dof2)`` degrees of freedom is the statistic the p-value is of.
    """
    from scipy import stats  # 1 s to import: only where it is used

    out: list[tuple[Effect, _OneStep | None, float, float, _OneStep | None, tuple[float, int]]]
    out = [(e, None, 0.0, 0.0, None, (0.0, 0)) for e in effects]
    plain = bases[()]
    nj = bases.state.robot.n_joints
    # grouped by nuisance joints, so that each basis is made once; results in the given order
    order = sorted(range(len(effects)), key=lambda i: _nuisance_joints(effects[i], nj))
    for done, i in enumerate(order):
        effect = effects[i]
        if advance is not None:
            advance(done, len(effects), "testing candidate effects")
        nuisance = _nuisance_joints(effect, nj)
        b = bases[nuisance]
        one = _one_step(wp, b.Q, b.r_perp, effect)
        s2 = b.rss / max(b.dof, 1)
        if one is None:
            out[i] = (effect, None, 0.0, s2, None, (0.0, 0))
            continue
        one_plain = _one_step(wp, plain.Q, plain.r_perp, effect) if nuisance else one
        k, S = one[0], one[1]
        d2 = max(b.dof - k, 1)
        F_stat = (S / k) / max((b.rss - S) / d2, 1e-300)
        logp = float(stats.f.logsf(F_stat, k, d2))
        if not np.isfinite(logp):  # beyond double precision: the χ² tail's asymptote
            logp = float(stats.chi2.logsf(k * F_stat, k))
            logp = logp if np.isfinite(logp) else -0.5 * k * F_stat
        out[i] = (effect, one, min(0.0, logp + np.log(m_tests)), s2, one_plain, (F_stat, d2))
    return out


def _order_hints(state: LoopState, wp: WhitenedProblem, bases: _Bases, alpha: float) -> list[str]:
    """Joints whose residuals still follow a smooth function of the joint angle."""
    from scipy import stats

    base = bases[()]
    nj = state.robot.n_joints
    res_now = wp.whiten.unwhite(base.r_perp.reshape(-1, wp.n_comp))
    hints = []
    for j in range(nj):
        bj = bases[(j,)]
        k = bj.Q.shape[1] - base.Q.shape[1]
        if k <= 0:
            continue
        S = base.rss - bj.rss
        F_stat = (S / k) / max(bj.rss / max(bj.dof, 1), 1e-300)
        p = float(np.exp(min(0.0, float(stats.f.logsf(F_stat, k, max(bj.dof, 1))) + np.log(nj))))
        if p < alpha:
            drop = wp.whiten.unwhite((base.r_perp - bj.r_perp).reshape(-1, wp.n_comp))
            hints.append(
                f"the residuals still follow a smooth function of q{j + 1} (Chebyshev orders up "
                f"to {ORDER_BLOCK} of joint {j + 1} would lower the position RMS from "
                f"{rms_pos_mm(res_now):.4f} to {rms_pos_mm(res_now - drop):.4f} mm, p = {p:.2g}): "
                "the error model's orders are too low there, not a missing effect; refit with "
                "a higher --max-order"
            )
    return hints


def _forward(
    state: LoopState,
    wp: WhitenedProblem,
    Q: F,
    r: F,
    effects: Sequence[Effect],
    first: str,
    m_tests: int,
    alpha: float,
    max_effects: int,
) -> tuple[str, ...]:
    """Forward selection from ``first``: add the best candidate while it stays significant."""
    chosen = [first]
    by_name = {e.name: e for e in effects}
    c = wp.n_comp
    while len(chosen) < max_effects:
        Z = np.concatenate(
            [
                wp.whiten.white(effect_jacobian(by_name[n], wp.ctx, wp.sens)[:, :c, :]).reshape(
                    -1, by_name[n].n_params
                )
                for n in chosen
            ],
            axis=1,
        )
        Qc = _orthonormal_basis(np.concatenate([Q, Z], axis=1))
        rest = [e for e in effects if e.name not in chosen]
        scored = [
            (lp, e.name)
            for e, one, lp, _, _, _ in _scan(wp, _bases(state, wp, Qc, r), rest, m_tests)
            if one
        ]
        if not scored:
            break
        lp, name = min(scored)
        if np.exp(lp) >= alpha:
            break
        chosen.append(name)
    return tuple(chosen)


def _one_step(
    wp: WhitenedProblem, Q: F, r_perp: F, effect: Effect
) -> tuple[int, float, F, F] | None:
    """Linearised refit with one more effect: ``(k, S, θ, fitted residual change (n, c) SI)``.

    ``None`` when the effect's columns lie in the model's column space (not identifiable).
    """
    c = wp.n_comp
    Z = wp.whiten.white(effect_jacobian(effect, wp.ctx, wp.sens)[:, :c, :])
    Z = Z.reshape(-1, effect.n_params)
    Zp = Z - Q @ (Q.T @ Z)
    zn = np.linalg.norm(Z, axis=0)
    Uk, W = _range_basis(Zp, lambda s: 1e-6 * max(float(zn.max()), 1e-300))
    k = Uk.shape[1]
    if k == 0:
        return None
    proj = Uk.T @ r_perp
    theta = W @ proj
    return k, float(proj @ proj), theta, wp.whiten.unwhite((Uk @ proj).reshape(-1, c))


def _evidence(
    c: Candidate,
    state: LoopState,
    spectra: dict[str, list[float]],
    m_tests: int,
    rms_now: float,
) -> str:
    effect = parse_effect(c.effect, state.robot)
    what = effect.regressor_name
    p = "p < 1e-300" if c.p_value == 0 else f"p = {c.p_value:.2g}"
    base = (
        f"residuals follow the {what}: F = {c.f_statistic:.4g} on ({c.dof}, {c.f_dof2}) dof, "
        f"{p} after Bonferroni over {m_tests} candidates; adding it would lower the position "
        f"RMS from {rms_now:.4f} to {c.rms_after_mm:.4f} mm"
    )
    if c.rot_rms_after_mrad is not None and c.predicted_rot_drop_mrad is not None:
        base += (
            f" and the orientation RMS from {c.rot_rms_after_mrad + c.predicted_rot_drop_mrad:.4f}"
            f" to {c.rot_rms_after_mrad:.4f} mrad"
        )
    if c.orientation_only:
        base = "moves only the orientation, not the TCP position: " + base
    est = ", ".join(
        f"{n} ≈ {v:.3g} {u}"
        for n, v, u in zip(effect.param_names, c.params, effect.param_units, strict=False)
    )
    spectrum_bin = effect.spectrum_bin()
    if spectrum_bin is not None:
        jk, h = spectrum_bin
        sp = np.asarray(spectra.get(jk, []))
        if sp.size > 1:
            others = np.delete(sp, h - 1)
            j2 = int(np.argmax(others))
            j2 = j2 + 1 if j2 < h - 1 else j2 + 2
            where = "peaks at" if sp[h - 1] >= others.max() else "has a side peak at"
            base += (
                f"; the residual spectrum against q{jk[1:]} {where} {h} cycles/rev "
                f"(χ² {sp[h - 1]:.1f}; largest other harmonic {j2}: χ² {float(others.max()):.1f})"
            )
    if not c.significant and c.p_value < 0.01 and np.isfinite(c.explained_share):
        base = (
            f"detectable but too small to matter (explains {100 * c.explained_share:.0f} % of "
            "the residual): " + base
        )
    elif not c.significant:
        base = "not significant: " + base
    return f"{base} ({est})"


def state_from_fitted(fitted: Any) -> LoopState:
    """The diagnosis's view of a :class:`quickhealth.identify.fit.FittedModel` (its noise too)."""
    return LoopState(
        robot=fitted.robot,
        spec=fitted.spec,
        coeffs=np.asarray(fitted.coeffs, float),
        T_instr_base0=np.asarray(fitted.T_instr_base0, float),
        T_flange_target0=np.asarray(fitted.T_flange_target0, float),
        effects=tuple(fitted.effects),
        effect_params=tuple(np.asarray(p, float) for p in fitted.effect_params),
        noise=fitted.noise,
    )


# --------------------------------------------------------------------------------------------
# Residual against a candidate's regressor (numbers for the TUI, figures for people)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EffectView:
    """Residuals seen through one effect, against its regressor.

    Every pose's residual is expressed in the effect's own quantity (weighted least squares
    per pose on the whitened residual): a joint effect shows the joint-angle error the
    residual implies (mrad), thermal the link growth (ppm), drift the base motion along the
    fitted drift (mm or mrad), depth scale the residual along the optical axis (mm).

    Attributes
    ----------
    effect : str
    x : ndarray, shape (n,)
        The effect's regressor per pose (``x_label`` says what and in which unit).
    x_label : str
    implied : ndarray, shape (n,)
        The effect's quantity the residual of each pose implies (``y_label``).
    predicted : ndarray, shape (n,)
        What the effect explains of it: for an effect not in the model, the part of the
        residual a one-step refit with it removes (what the Chebyshev terms could already
        absorb is not counted); for an effect in the model, the fitted effect itself.
    y_label : str
    params : ndarray
        The effect's parameters used for ``predicted`` (SI).
    """

    effect: str
    x: F
    x_label: str
    implied: F
    predicted: F
    y_label: str
    params: F


def regressor_values(
    effect: Effect, ctx: EffectContext, T_model: F, params: F | None = None
) -> tuple[F, str]:
    """The effect's regressor per pose and its label (:meth:`~.effects.Effect.regressor_at`:
    the depth from the model pose for depthscale; the modelled deflection for the lumped
    compliance, whose many columns have one regressor only once ``params`` are known)."""
    p = None if params is None else np.asarray(params, float)
    x, label = effect.regressor_at(ctx, p, T_model)
    return np.asarray(x, float), str(label)


def implied_channel(
    effect: Effect,
    params: F,
    ctx: EffectContext,
    sens: Sensitivities,
    T_model: F,
    residual: F,
    whiten: Whitening,
) -> tuple[F, F, str]:
    """Per-pose value of the effect's quantity implied by ``residual`` (n, c).

    Returns ``(implied, effect, label)`` in display units (see :class:`EffectView`):
    ``effect`` is the quantity the effect itself gives at ``params``.  (``params`` also
    fixes the drift's direction.)
    """
    n, c = residual.shape
    p = effect.perturbation(ctx, np.asarray(params, float))
    if p.dq is not None and np.count_nonzero(np.any(p.dq != 0, axis=0)) <= 1:
        cols = np.any(p.dq != 0, axis=0)
        k = int(np.flatnonzero(cols)[0]) if cols.any() else _effect_joint(effect, ctx)
        g, pred, scale = sens.dq[:, k], p.dq[:, k], 1e3
        label = f"joint {k + 1} angle error (mrad)"
    elif p.joint_motion is not None:  # a joint's error motions (a warm joint's growth, drift)
        fitted = bool(np.any(np.asarray(params, float)))
        jm = np.asarray(
            (p if fitted else effect.perturbation(ctx, np.ones(effect.n_params))).joint_motion
        )
        k = int(np.argmax(np.abs(jm).sum(axis=(0, 2))))
        i = int(np.argmax(np.linalg.norm(jm[:, k], axis=1)))
        h = jm[i, k] / max(float(np.linalg.norm(jm[i, k])), 1e-300)  # the effect's direction
        g = np.einsum("m,nmc->nc", h, sens.frame_motion[:, k + 1])
        pred = np.asarray(p.joint_motion)[:, k] @ h
        scale = 1e6
        label = f"joint {k + 1} error motion along the effect (µm, µrad)"
    elif p.link_scale is not None:
        g, pred, scale = sens.link_scale, p.link_scale, 1e6
        label = "link growth (ppm)"
    elif p.instr_scale_z is not None:
        g = np.tile([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (n, 1))
        pred, scale = p.instr_scale_z * T_model[:, 2, 3], 1e3
        label = "residual along the instrument's optical axis (mm)"
    elif p.base_twist is not None:
        norm = np.linalg.norm(params)
        u = np.asarray(params, float) / norm if norm > 0 else np.eye(effect.n_params)[0]
        g = np.einsum("c,nck->nk", u[:6], sens.base_twist)
        pred, scale = p.base_twist @ u[:6], 1e3
        label = "base motion along the fitted drift (mm or mrad)"
    else:
        raise ValueError(f"{effect.name}: no channel to show")
    gw = whiten.white(g[:, :c])
    rw = whiten.white(residual)
    implied = np.einsum("nc,nc->n", gw, rw) / np.maximum(np.einsum("nc,nc->n", gw, gw), 1e-300)
    return implied * scale, np.asarray(pred, float) * scale, label


def _effect_joint(effect: Effect, ctx: EffectContext) -> int:
    unit = np.ones(effect.n_params)
    dq = effect.perturbation(ctx, unit).dq
    assert dq is not None
    return int(np.argmax(np.abs(dq).sum(0)))


def effect_view(state: LoopState, meas: Measurements, effect_name: str) -> EffectView:
    """Residuals of ``state`` seen through the effect ``effect_name``, against its regressor.

    When the model has the effect, its fitted parameters are shown; otherwise the one-step
    estimate of :func:`diagnose`.
    """
    effect = parse_effect(effect_name, state.robot)
    wp = whitened(state, meas)
    res = wp.whiten.unwhite(wp.r.reshape(-1, wp.n_comp))
    if effect.name in state.effect_names:  # in the model: show it with what is left around it
        theta = np.asarray(state.effect_params[state.effect_names.index(effect.name)], float)
        y, pred, ylabel = implied_channel(
            effect, theta, wp.ctx, wp.sens, wp.T_model, res, wp.whiten
        )
        y = y + pred
    else:  # not in the model: the residual, and what a one-step refit would explain of it
        b = _bases(state, wp, _orthonormal_basis(wp.J), wp.r)[
            _nuisance_joints(effect, state.robot.n_joints)
        ]
        one = _one_step(wp, b.Q, b.r_perp, effect)
        theta = np.zeros(effect.n_params) if one is None else one[2]
        explained = np.zeros_like(res) if one is None else one[3]
        y, _, ylabel = implied_channel(effect, theta, wp.ctx, wp.sens, wp.T_model, res, wp.whiten)
        pred, _, _ = implied_channel(
            effect, theta, wp.ctx, wp.sens, wp.T_model, explained, wp.whiten
        )
    x, xlabel = regressor_values(effect, wp.ctx, wp.T_model, theta)
    return EffectView(effect.name, np.asarray(x, float), xlabel, y, pred, ylabel, theta)


def plot_candidate(state: LoopState, meas: Measurements, effect_name: str) -> Any:
    """Figure: the residual along the effect against its regressor, with what it explains.

    Returns a matplotlib ``Figure`` (Agg; nothing is shown or saved).
    """
    from matplotlib.figure import Figure

    v = effect_view(state, meas, effect_name)
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    lim = np.percentile(np.abs(v.implied), 98) * 1.3 if v.implied.size else 1.0
    x = jitter_binary(v.x)
    ax.scatter(x, np.clip(v.implied, -lim, lim), s=9, alpha=0.6, label="implied by the residual")
    ax.plot(x, v.predicted, ".", color="C3", ms=4, label=f"explained by {v.effect}")
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel(v.x_label)
    ax.set_ylabel(v.y_label)
    ax.set_title(f"Residual against the regressor of {v.effect}")
    ax.legend(loc="best", fontsize=8)
    return fig


def jitter_binary(x: F, width: float = 0.12) -> F:
    """Spread a two-valued regressor (approach ±1) sideways so the points can be seen."""
    x = np.asarray(x, float)
    if np.unique(x).size > 2:
        return x
    return x + np.random.default_rng(0).uniform(-width, width, x.shape)


def plot_spectrum(diag: Diagnosis) -> Any:
    """Figure: the residual spectrum (cyclic score statistic per harmonic) of every joint."""
    from matplotlib.figure import Figure
    from scipy import stats

    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    for jk, sp in sorted(diag.spectra.items()):
        ax.plot(np.arange(1, len(sp) + 1), sp, marker=".", label=jk)
    if diag.spectra:
        dof = 2
        crit = float(
            stats.chi2.isf(diag.alpha / max(diag.n_tested, 1), dof)
        )  # Bonferroni threshold
        ax.axhline(crit, color="0.3", ls="--", lw=0.8, label="significance (Bonferroni)")
    ax.set_xlabel("harmonic M (cycles per joint revolution)")
    ax.set_ylabel("score statistic χ²")
    ax.set_title("Residual spectrum against each joint angle")
    ax.legend(loc="best", fontsize=8)
    return fig
