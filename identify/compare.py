"""The loop made visible: add an effect and watch the held-out error fall.

:func:`compare_effect` fits the model without and with one or more effects (same Chebyshev
orders, warm-started from the model without) and measures both on data the fits never saw:
a held-out measurement set when there is one, otherwise K-fold cross-validation of the
training set.  Cross-validation keeps the execution order (the approach directions of
backlash come from it): a fold is left out by giving its rows an enormous uncertainty, not by
deleting them, and is predicted with the approach directions of the whole run.  The result
holds the RMS per axis and overall, before and after, and the residuals seen through each
added effect against its regressor (for the before/after plot and the TUI).

SYNOPSIS::

    cmp = compare_effect(fitted, train, ["backlash:j2"], heldout=test)
    print("\\n".join(cmp.summary()))
    fig = plot_comparison(cmp)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .diagnose import (
    implied_channel,
    jitter_binary,
    regressor_values,
    sensitivities,
    state_from_fitted,
    whitening,
)
from .effects import Effect, EffectContext, missing_channels, parse_effects, same_effect_key
from .errors import InputError
from .fit import FittedModel, fit_model
from .linearize import measurement_context, pose_residuals
from .measurements import Measurements

F = NDArray[np.float64]


@dataclass(frozen=True)
class AxisRMS:
    """Root-mean-square error per axis and overall (instrument frame).

    ``pos_mm = sqrt(mean(|e|²))`` over the three position axes; rotation in mrad (rotation
    vector components), None for position-only data.
    """

    x_mm: float
    y_mm: float
    z_mm: float
    pos_mm: float
    rx_mrad: float | None = None
    ry_mrad: float | None = None
    rz_mrad: float | None = None
    rot_mrad: float | None = None

    @classmethod
    def of(cls, res: F) -> AxisRMS:
        """From residuals (n, 3) or (n, 6) in m and rad."""
        a = np.sqrt(np.mean(res**2, axis=0))
        pos = float(np.sqrt(np.sum(a[:3] ** 2)) * 1e3)
        if res.shape[1] < 6:
            return cls(*(float(v) * 1e3 for v in a[:3]), pos)
        rot = float(np.sqrt(np.sum(a[3:] ** 2)) * 1e3)
        return cls(*(float(v) * 1e3 for v in a[:3]), pos, *(float(v) * 1e3 for v in a[3:]), rot)

    def to_dict(self) -> dict[str, float | None]:
        """Plain dict."""
        return dict(self.__dict__)


@dataclass(frozen=True, eq=False)
class EffectPanel:
    """Residuals of the evaluation data seen through one added effect, before and after."""

    effect: str
    x: F
    x_label: str
    before: F  # effect quantity implied by the residual of the model without the effect
    after: F  # … by the residual of the model with it (what is left: flat if it worked)
    predicted: F  # what adding the effect removed from the residual (before − after)
    y_label: str


@dataclass(frozen=True, eq=False)
class Comparison:
    """Result of :func:`compare_effect`.

    Attributes
    ----------
    effects : tuple of str
        Effects added.
    method : str
        ``held-out`` or ``cross-validation (K folds)``.
    n_train, n_eval : int
    before, after : AxisRMS
        Error on the evaluation data of the model without and with the effects.
    train_before, train_after : AxisRMS
        The same on the training data (fit residuals).
    noise_floor_pos_mm : float
        The position RMS that instrument noise alone gives (√3 σ_pos).
    params : dict of str to list of float
        Fitted parameters of each added effect (SI) …
    param_sigma : dict of str to list of float
        … and their standard uncertainties.
    fitted_before, fitted_after : FittedModel
        Fits on the whole training set.
    panels : tuple of EffectPanel
    """

    effects: tuple[str, ...]
    method: str
    n_train: int
    n_eval: int
    before: AxisRMS
    after: AxisRMS
    train_before: AxisRMS
    train_after: AxisRMS
    noise_floor_pos_mm: float
    params: dict[str, list[float]]
    param_sigma: dict[str, list[float]]
    fitted_before: FittedModel
    fitted_after: FittedModel
    panels: tuple[EffectPanel, ...]

    @property
    def improvement(self) -> float:
        """Fraction of the evaluation position RMS removed (negative = worse)."""
        return 1.0 - self.after.pos_mm / self.before.pos_mm if self.before.pos_mm else 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (no arrays)."""
        return {
            "effects": list(self.effects),
            "method": self.method,
            "n_train": self.n_train,
            "n_eval": self.n_eval,
            "before": self.before.to_dict(),
            "after": self.after.to_dict(),
            "train_before": self.train_before.to_dict(),
            "train_after": self.train_after.to_dict(),
            "noise_floor_pos_mm": self.noise_floor_pos_mm,
            "improvement": self.improvement,
            "params": self.params,
            "param_sigma": self.param_sigma,
        }

    def summary(self) -> list[str]:
        """Lines for the command line and the TUI: what adding the effects does and what to
        do first, then the effects' sizes in their units, then the table per axis."""
        b, a = self.before, self.after
        keep = a.pos_mm < b.pos_mm
        lines = [
            f"adding {', '.join(self.effects)} "
            + ("lowers" if keep else "does not lower")
            + f" the position error on data the fit did not see from {b.pos_mm:.4f} to "
            f"{a.pos_mm:.4f} mm RMS ({abs(100 * self.improvement):.1f} % "
            + ("less" if keep else "more")
            + "); the instrument's noise "
            f"alone gives {self.noise_floor_pos_mm:.4f} mm",
            "what to do: "
            + (
                f"keep it (quickhealth identify fit ... --effects {','.join(self.effects)})"
                if keep
                else "leave it out: it does not describe this robot"
            ),
        ]
        units = {e.name: e.param_units for e in self.fitted_after.effects}
        for name, p in self.params.items():
            s = self.param_sigma.get(name, [])
            lines.append(f"{name}: " + param_words(p, s, units.get(name, ())))
        lines += [
            f"per axis, {self.method} on {self.n_eval} poses (trained on {self.n_train}):",
            f"{'':14}{'x':>9}{'y':>9}{'z':>9}{'3D':>9}  (position RMS, mm)",
            f"{'without':<14}{b.x_mm:9.4f}{b.y_mm:9.4f}{b.z_mm:9.4f}{b.pos_mm:9.4f}",
            f"{'with':<14}{a.x_mm:9.4f}{a.y_mm:9.4f}{a.z_mm:9.4f}{a.pos_mm:9.4f}",
        ]
        if b.rot_mrad is not None and a.rot_mrad is not None:
            lines += [
                f"{'':14}{'rx':>9}{'ry':>9}{'rz':>9}{'3D':>9}  (rotation RMS, mrad)",
                f"{'without':<14}{b.rx_mrad:9.4f}{b.ry_mrad:9.4f}{b.rz_mrad:9.4f}{b.rot_mrad:9.4f}",
                f"{'with':<14}{a.rx_mrad:9.4f}{a.ry_mrad:9.4f}{a.rz_mrad:9.4f}{a.rot_mrad:9.4f}",
            ]
        return lines


#: SI units of effect parameters and how people read them: (unit, factor from SI).
READ_AS = {"rad": ("mrad", 1e3), "m": ("mm", 1e3), "rad/(N·m)": ("µrad/(N·m)", 1e6)}


def param_words(values: list[float], sigmas: list[float], units: tuple[str, ...]) -> str:
    """An effect's parameters with their uncertainty and unit: "0.424 ± 0.017 mrad (0.0243°)"
    (an angle also in degrees); a unit it does not know is kept as SI."""
    out = []
    for k, v in enumerate(values):
        si = units[k] if k < len(units) else ""
        unit, f = READ_AS.get(si, (si, 1.0))
        u = sigmas[k] if k < len(sigmas) else float("nan")
        text = f"{v * f:.4g} ± {u * f:.2g} {unit}".rstrip()
        if si == "rad":
            text += f" ({math.degrees(v):.4g}°)"
        out.append(text)
    return ", ".join(out)


def _context(fitted: FittedModel, meas: Measurements) -> EffectContext:
    return measurement_context(fitted.robot, meas)


def _predict_res(fitted: FittedModel, meas: Measurements, approach: F | None = None) -> F:
    T = fitted.predict(meas.q, approach=approach, **meas.conditions())
    return pose_residuals(meas, T)


def _mask(meas: Measurements, rows: NDArray[np.bool_], fitted: FittedModel) -> Measurements:
    """``meas`` with ``rows`` left out of the fit but kept for the execution order; the other
    rows keep the one noise model (a per-angle sigma put in for them would have weighted
    them differently from the fit of all the data)."""
    return replace(meas, excluded=np.asarray(rows, bool).copy())


def compare_effect(
    fitted: FittedModel,
    train: Measurements,
    effects: str | Sequence[str],
    heldout: Measurements | None = None,
    folds: int = 5,
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Fit without and with ``effects`` and measure both on unseen data.

    Parameters
    ----------
    fitted : FittedModel
        The model without the effects (e.g. from ``identify fit``), fitted to ``train``.
    train : Measurements
        The data it was fitted to.
    effects : str or sequence of str
        Effect names to add (comma-separated or a list).
    heldout : Measurements, optional
        Unseen data of the same robot and set-up; without it, ``folds``-fold
        cross-validation of ``train`` (interleaved folds, so each spans the whole run).
    progress : callable, optional
        Receives one line per fit.

    Returns
    -------
    Comparison

    Raises
    ------
    InputError
        An unknown effect, an effect already in the model, or a missing column.
    """
    robot = fitted.robot
    new = parse_effects(effects, robot)
    if not new:
        raise InputError("name at least one effect to add (e.g. --effects backlash:j2)")
    have = {same_effect_key(e): e.name for e in fitted.effects}
    for e in new:
        if same_effect_key(e) in have:
            raise InputError(f"the model already has {have[same_effect_key(e)]}")
        for data, what in ((train, "training"), (heldout, "held-out")):
            for col in missing_channels(e, data) if data is not None else ():
                raise InputError(f"{e.name} needs a {col!r} column in the {what} data")
    say = progress or (lambda s: None)
    all_effects: tuple[Effect, ...] = (*fitted.effects, *new)

    def fit_pair(data: Measurements, init: FittedModel) -> tuple[FittedModel, FittedModel]:
        f0 = fit_model(
            robot, data, fitted.spec, fitted.effects, fitted.noise, fitted.prior, init=init
        )
        f1 = fit_model(robot, data, fitted.spec, all_effects, fitted.noise, fitted.prior, init=f0)
        return f0, f1

    say(f"fitting with {', '.join(e.name for e in new)} on {train.n_poses} poses")
    full0, full1 = fit_pair(train, fitted)
    if heldout is not None:
        method = "held-out"
        eval_meas = heldout
        res0 = _predict_res(full0, heldout)
        res1 = _predict_res(full1, heldout)
    else:
        k = int(folds)
        if k < 2 or k > train.n_poses // 2:
            raise InputError(f"--folds must be between 2 and {train.n_poses // 2}, got {k}")
        method = f"cross-validation ({k} folds)"
        eval_meas = train
        app = train.approach_sign()
        c = 6 if train.has_orientation else 3
        res0 = np.empty((train.n_poses, c))
        res1 = np.empty((train.n_poses, c))
        fold = np.arange(train.n_poses) % k
        for i in range(k):
            say(f"cross-validation fold {i + 1}/{k}")
            rows = fold == i
            f0, f1 = fit_pair(_mask(train, rows, fitted), full0)
            res0[rows] = _predict_res(f0, train, app)[rows]
            res1[rows] = _predict_res(f1, train, app)[rows]
    panels = _panels(full1, new, eval_meas, res0, res1)
    params: dict[str, list[float]] = {}
    sig: dict[str, list[float]] = {}
    pos = full1.spec.n_params + sum(e.n_params for e in fitted.effects)
    sd = full1.sigma
    for e, p in zip(new, full1.effect_params[len(fitted.effects) :], strict=True):
        params[e.name] = [float(v) for v in p]
        sig[e.name] = [float(v) for v in sd[pos : pos + e.n_params]]
        pos += e.n_params
    res_tr0 = _predict_res(full0, train)
    res_tr1 = _predict_res(full1, train)
    return Comparison(
        effects=tuple(e.name for e in new),
        method=method,
        n_train=train.n_poses,
        n_eval=eval_meas.n_poses,
        before=AxisRMS.of(res0),
        after=AxisRMS.of(res1),
        train_before=AxisRMS.of(res_tr0),
        train_after=AxisRMS.of(res_tr1),
        noise_floor_pos_mm=float(np.sqrt(3.0) * fitted.noise.sigma_pos * 1e3),
        params=params,
        param_sigma=sig,
        fitted_before=full0,
        fitted_after=full1,
        panels=panels,
    )


def _panels(
    fitted_after: FittedModel,
    new: Sequence[Effect],
    meas: Measurements,
    res0: F,
    res1: F,
) -> tuple[EffectPanel, ...]:
    state = state_from_fitted(fitted_after)
    ctx = _context(fitted_after, meas)
    sens = sensitivities(state, ctx)
    T = fitted_after.predict(meas.q, **meas.conditions())
    wh = whitening(state, meas, sens)
    out = []
    names = [e.name for e in fitted_after.effects]
    for e in new:
        p = fitted_after.effect_params[names.index(e.name)]
        y0, _, label = implied_channel(e, p, ctx, sens, T, res0, wh)
        y1, _, _ = implied_channel(e, p, ctx, sens, T, res1, wh)
        x, xlabel = regressor_values(e, ctx, T, p)
        out.append(EffectPanel(e.name, np.asarray(x, float), xlabel, y0, y1, y0 - y1, label))
    return tuple(out)


def plot_comparison(cmp: Comparison) -> Any:
    """Figure: per added effect, the residual against its regressor before and after.

    Left: without the effect (the structure is there, with the fitted effect on top); right:
    with it (what is left should scatter around zero).  Returns a matplotlib Figure.
    """
    from matplotlib.figure import Figure

    rows = max(len(cmp.panels), 1)
    fig = Figure(figsize=(10.0, 3.6 * rows), layout="constrained")
    axes = fig.subplots(rows, 2, squeeze=False, sharey="row")
    for i, pnl in enumerate(cmp.panels):
        both = np.concatenate([pnl.before, pnl.after])
        lim = float(np.percentile(np.abs(both), 98) * 1.3) if both.size else 1.0
        for ax, y, title in (
            (axes[i, 0], pnl.before, f"without {pnl.effect}: {cmp.before.pos_mm:.4f} mm"),
            (axes[i, 1], pnl.after, f"with {pnl.effect}: {cmp.after.pos_mm:.4f} mm"),
        ):
            x = jitter_binary(pnl.x)
            ax.scatter(x, np.clip(y, -lim, lim), s=8, alpha=0.6, label="implied by residual")
            if ax is axes[i, 0]:
                ax.plot(x, pnl.predicted, ".", color="C3", ms=3, label="removed by the effect")
            ax.axhline(0.0, color="0.5", lw=0.8)
            ax.set_xlabel(pnl.x_label)
            ax.set_title(f"{title} ({cmp.method})", fontsize=9)
        axes[i, 0].set_ylabel(pnl.y_label)
        axes[i, 0].legend(loc="best", fontsize=7)
    fig.suptitle(
        f"{', '.join(cmp.effects)}: position RMS {cmp.before.pos_mm:.4f} → "
        f"{cmp.after.pos_mm:.4f} mm"
    )
    return fig
