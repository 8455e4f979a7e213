"""The trend's inputs from the archive: a robot's runs a trend can read, what it needs of
each (:func:`run_state`), and the trend over them (:func:`trend_for`); the quick checks in
words beside it (:func:`check_lines`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...identify.errormodel import ErrorModelSpec
from ...identify.errors import InputError
from ...identify.fit import FittedModel, fit_model
from .. import formats
from .folders import read_json, report_figures
from .records import CheckRecord, RunRecord, safe_name
from .store import Archive

if TYPE_CHECKING:
    from ...identify.trend import RunState, TrendResult


def model_arrays(
    doc: Mapping[str, Any], name: str = "model.json"
) -> tuple[ErrorModelSpec, np.ndarray, np.ndarray | None]:
    """Error-model spec, Chebyshev coefficients (SI) and their covariance from a model.json object.

    The covariance is the Chebyshev block of the fit's covariance (effect parameters left out).
    """

    fitted = formats.model_from_json(dict(doc), name)
    n = fitted.spec.n_params
    return fitted.spec, np.asarray(fitted.coeffs, float), np.asarray(fitted.cov, float)[:n, :n]


def run_state(
    arch: Archive, rec: RunRecord, like: RunRecord | None = None, folder: Path | None = None
) -> RunState:
    """What the trend needs of a run: figures and their uncertainty, error model, metadata.

    Parameters
    ----------
    rec : RunRecord
    like : RunRecord, optional
        The baseline.  When the run's model has other orders than the baseline's, the run's
        measurements are fitted again at the baseline's orders (cached in the run folder as
        ``model.like-<baseline>.json``), so that a term one fit selected and the other did
        not is not mistaken for a change.
    folder : path, optional
        Read the run's fit from this folder instead of its archive folder (a reprocessed
        copy): its report's figures replace the index's.
    """

    own = folder is not None
    folder = arch.folder(rec) if folder is None else Path(folder)
    figs, sig = rec.figures_mm, {}
    rp = folder / "report.json"
    if rp.is_file():
        f2, sig = report_figures(read_json(rp))
        keep = {} if own else {k: v for k, v in figs.items() if not math.isnan(v)}
        figs = {**figs, **f2, **keep}
    spec = coeffs = cov = model = poses = None
    mp = folder / "model.json"
    csv = folder / "measurements.csv"
    if mp.is_file():
        model = formats.read_model(mp)  # validated as report, reprocess, predict read it
        if like is not None and like.run_id != rec.run_id and csv.is_file():
            bp = arch.folder(like) / "model.json"
            if bp.is_file():
                bspec, _, _ = model_arrays(read_json(bp), str(bp))
                spec = model.spec
                same = (
                    bspec.orders.shape == spec.orders.shape
                    and np.array_equal(bspec.orders, spec.orders)
                    and np.allclose(bspec.q_lo, spec.q_lo)
                    and np.allclose(bspec.q_hi, spec.q_hi)
                )
                if not same and bspec.n_joints == spec.n_joints:
                    model = _like_model(folder, mp, csv, like, bspec)
        n = model.spec.n_params
        spec, coeffs = model.spec, np.asarray(model.coeffs, float)
        cov = np.asarray(model.cov, float)[:n, :n]
    q_measured = None
    if spec is not None and csv.is_file():
        poses = formats.read_measurements(csv, spec.n_joints)
        q_measured = (poses.q.min(axis=0), poses.q.max(axis=0))
    from ...identify.trend import RunState  # scipy.stats: see FIGURES

    return RunState(
        run_id=rec.run_id,
        t_s=rec.t_s,
        figures_mm=figs,
        spec=spec,
        coeffs=coeffs,
        cov=cov,
        figure_sigma_mm=sig,
        meta=rec.meta,
        q_measured=q_measured,
        model=model,
        poses=poses,
    )


def _like_model(
    folder: Path, mp: Path, csv: Path, like: RunRecord, bspec: ErrorModelSpec
) -> FittedModel:

    cache = folder / f"model.like-{safe_name(like.run_id, 'run id')}.json"
    if not cache.is_file():
        own = formats.read_model(mp)
        meas = formats.read_measurements(csv, own.robot.n_joints)
        refit = fit_model(own.robot, meas, bspec, own.effects, own.noise, own.prior)
        formats.write_model(cache, refit)
    return formats.read_model(cache)


def trend_runs(
    arch: Archive, robot: str, upto: str | None = None
) -> tuple[list[RunRecord], list[RunRecord]]:
    """The robot's runs a trend can read (time order, up to run ``upto``), and those left out
    because their archive folder is missing (deleted behind the index).

    Raises
    ------
    InputError
        The latest run's folder (the run judged) or the baseline's is missing: a verdict
        without them would be made up.  One line naming the folder.
    """
    recs = arch.runs(robot)
    if upto is not None:
        ids = [r.run_id for r in recs]
        if upto in ids:
            recs = recs[: ids.index(upto) + 1]
    missing = [r for r in recs if not arch.folder(r).is_dir()]
    gone = {r.run_id for r in missing}
    latest = recs[-1]
    if latest.run_id in gone:
        raise InputError(
            f"latest run {latest.run_id} of robot {robot}: its folder {arch.folder(latest)} is "
            "missing (deleted behind the index?): it cannot be judged; restore the folder"
        )
    base = next((r for r in recs if r.baseline), None)
    if base is not None and base.run_id in gone:
        raise InputError(
            f"baseline run {base.run_id} of robot {robot}: its folder {arch.folder(base)} is "
            "missing (deleted behind the index?): restore it, or choose another baseline "
            "(quickhealth archive baseline ROBOT RUN_ID)"
        )
    return [r for r in recs if r.run_id not in gone], missing


def missing_words(arch: Archive, missing: list[RunRecord]) -> list[str]:
    """One warning per run :func:`trend_runs` left out."""
    return [
        f"run {r.run_id}: its folder {arch.folder(r)} is missing (deleted behind the index?): "
        "left out of the trend"
        for r in missing
    ]


def check_lines(checks: list[CheckRecord]) -> list[str]:
    """A robot's quick checks, one line each (not assessments: no figures)."""
    if not checks:
        return []
    out = [f"quick checks ({len(checks)}; not assessments):"]
    for c in checks:
        frac = (
            c.robot_time_s / c.full_loop_robot_time_s if c.full_loop_robot_time_s else float("nan")
        )
        out.append(
            f"  {c.check_id:<23} {c.time_utc:<21} {c.verdict.upper() if c.verdict == 'changed' else c.verdict}"
            f"{'' if c.decided else ' (undecided)'} after {c.poses} poses, {c.robot_time_s:.0f} s "
            f"({100 * frac:.0f} % of the loop) vs baseline {c.baseline_run_id}"
            + (f": {c.changes}" if c.changes else "")
        )
    return out


def trend_for(arch: Archive, robot: str, **kwargs: Any) -> TrendResult:
    """:func:`~quickhealth.identify.trend.assess_trend` over a robot's archived runs (oldest
    first) whose folders exist (:func:`trend_runs`), against its baseline run; ``kwargs`` go
    to ``assess_trend``."""
    from ...identify.trend import assess_trend  # scipy.stats: see FIGURES

    recs, _ = trend_runs(arch, robot)
    b = next((i for i, r in enumerate(recs) if r.baseline), None)
    if b is None:
        raise InputError(
            f"robot {robot!r} has no healthy run to be its baseline: "
            "quickhealth archive baseline ROBOT RUN_ID"
        )
    states = [run_state(arch, r, like=recs[b]) for r in recs]
    return assess_trend(states, b, **kwargs)
