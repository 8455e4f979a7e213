"""One assessment: measurements in, everything report.json says out.

:func:`assess` chooses the error model's orders by BIC (or takes given orders), fits it by
maximum likelihood with the requested effects, and evaluates what the model says about the
robot: the workspace TCP error at stated reference conditions and every joint's error
curves with bands.  The command line (``identify fit``), the TUI, fleet reprocessing and the
demo all call this one function and write its result with one writer
(:mod:`quickhealth.station.formats.report`), so the same input gives the same report whichever
door it came through.  Pure: no files, clocks or global state.

SYNOPSIS::

    from quickhealth.identify.assess import assess
    a = assess(meas, ur5(), ["thermal"], max_order=6)
    a.fitted.summary(), a.workspace.mean, a.workspace.conditions.describe()
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .effects import Effect, parse_effects
from .errormodel import ErrorModelSpec
from .errors import InputError
from .fit import FittedModel, ParameterPrior, fit_model
from .linearize import InstrumentNoise
from .measurements import Measurements
from .robot import RobotModel, nominal_of
from .sanity import NumericalError, check_plausible, check_residuals, weakest_directions
from .select import Selection, select_orders
from .workspace import JointCurves, WorkspaceError, all_joint_curves, workspace_error

#: Defaults every door uses unless told otherwise.
MAX_ORDER = 6
WORKSPACE_SAMPLES = 5000
CURVE_POINTS = 61


@dataclass(frozen=True, eq=False)
class Assessment:
    """The result of :func:`assess` (SI inside; the writer converts at the file boundary).

    Attributes
    ----------
    measurements : Measurements
        The data assessed (execution order).
    fitted : FittedModel
        The identified model.
    selection : Selection or None
        The BIC order search and its χ² check; ``None`` when the orders were given.
    noise : InstrumentNoise
        The instrument defaults the final fit used (after an automatic rescale, if any).
    prior : ParameterPrior
    workspace : WorkspaceError
        TCP error over the model's joint ranges, at ``workspace.conditions``.
    curves : tuple of JointCurves
        Every joint's six error motions with confidence bands.
    """

    measurements: Measurements
    fitted: FittedModel
    selection: Selection | None
    noise: InstrumentNoise
    prior: ParameterPrior
    workspace: WorkspaceError
    curves: tuple[JointCurves, ...]

    def summary(self) -> list[str]:
        """The lines the CLI prints and report.json keeps."""
        lines = self.fitted.summary() + (self.selection.summary() if self.selection else [])
        ws = self.workspace
        cond = ws.conditions.describe()
        lines.append(
            f"workspace TCP error (model{', ' + cond if cond else ''}): mean "
            f"{ws.mean * 1e3:.3f} mm, std {ws.std * 1e3:.3f} mm, max {ws.max * 1e3:.3f} mm"
        )
        lines.append(f"errors against the nominal kinematics of {nominal_of(self.fitted.robot)}")
        return lines


def assess(
    measurements: Measurements,
    robot: RobotModel,
    effects: Sequence[str | Effect] = (),
    *,
    noise: InstrumentNoise = InstrumentNoise(),
    prior: ParameterPrior = ParameterPrior(),
    max_order: int = MAX_ORDER,
    spec: ErrorModelSpec | None = None,
    margin: float | None = None,
    auto_rescale: bool = False,
    workspace_samples: int = WORKSPACE_SAMPLES,
    curve_points: int = CURVE_POINTS,
    progress: Callable[[str], None] | None = None,
) -> Assessment:
    """Identify the error model of ``robot`` from ``measurements`` and evaluate it.

    Parameters
    ----------
    effects : sequence of effect names (CONTRACTS.md) or Effect
        Added to the paper's Chebyshev model.
    noise, prior :
        Instrument defaults (where the data have no per-row uncertainties) and parameter prior.
    max_order : int
        Cap of every series' order in the BIC search.
    spec : ErrorModelSpec, optional
        Fixed orders and ranges instead of the search (e.g. reprocessing with a run's orders).
    margin, auto_rescale :
        Passed to :func:`~quickhealth.identify.select.select_orders`.

    Raises
    ------
    InputError
        Unknown effect, missing column an effect needs, too few poses.
    """
    eff = tuple(
        parse_effects([str(x) for x in effects], robot)
        if all(isinstance(x, str) for x in effects)
        else (x if not isinstance(x, str) else parse_effects([x], robot)[0] for x in effects)
    )
    selection = None
    if spec is None:
        selection = select_orders(
            robot,
            measurements,
            eff,
            noise=noise,
            prior=prior,
            max_order=max_order,
            margin=margin,
            auto_rescale=auto_rescale,
            progress=progress,
        )
        fitted = selection.fitted
    else:
        fitted = fit_model(robot, measurements, spec, eff, noise, prior)
    fitted = believable(fitted, measurements)
    if progress is not None:
        progress("workspace TCP error and joint curves")
    return evaluate(
        measurements,
        fitted,
        selection,
        workspace_samples=workspace_samples,
        curve_points=curve_points,
    )


def believable(fitted: FittedModel, measurements: Measurements) -> FittedModel:
    """``fitted`` if every reader of models will accept it, else one actionable error.

    A fit that stopped before converging gets one longer refit from where it stopped.

    Raises
    ------
    NumericalError
        Still not converged, or numbers that are not finite (exit 3).
    InputError
        The data cannot support a model: its TCP correction is beyond any real robot
        (:func:`~quickhealth.identify.sanity.check_plausible`); names the parameters the
        data determine least (exit 2).
    """
    if not fitted.converged:
        fitted = fit_model(
            fitted.robot,
            measurements,
            fitted.spec,
            fitted.effects,
            fitted.noise,
            fitted.prior,
            init=fitted,
            hold=fitted.held,
            max_iter=400,
        )
    if not (np.all(np.isfinite(fitted.params)) and np.isfinite(fitted.chi2)):
        raise NumericalError("the fit produced numbers that are not finite: no model written")
    if not fitted.converged:
        raise NumericalError(
            f"the fit did not converge after {fitted.n_iter} iterations (chi2 "
            f"{fitted.chi2_data:.6g}): no model written; look for rows far from the rest "
            "(residuals.csv of a fit with --max-order 0) or lower --max-order"
        )
    check_residuals(fitted, "the data cannot support a model")
    try:
        check_plausible(fitted, "the data cannot support a model")
    except InputError as exc:
        weak = ", ".join(weakest_directions(fitted))
        raise InputError(
            f"{exc}; check the units (mm, deg), the robot description and that every joint "
            f"moves; the least determined parameters: {weak}"
        ) from None
    return fitted


def evaluate(
    measurements: Measurements,
    fitted: FittedModel,
    selection: Selection | None = None,
    *,
    workspace_samples: int = WORKSPACE_SAMPLES,
    curve_points: int = CURVE_POINTS,
) -> Assessment:
    """The assessment of a model already fitted to ``measurements`` (e.g. the refit with an
    added effect of :func:`~quickhealth.identify.compare.compare_effect`): its workspace
    error at the reference conditions and its joint curves.  :func:`assess` ends here."""
    return Assessment(
        measurements=measurements,
        fitted=fitted,
        selection=selection,
        noise=selection.noise if selection is not None else fitted.noise,
        prior=selection.prior if selection is not None else fitted.prior,
        workspace=workspace_error(fitted, n_samples=workspace_samples),
        curves=tuple(all_joint_curves(fitted, n_points=curve_points)),
    )
