"""The heavy computations behind the screens, as module-level functions.

Each takes plain data (robot, measurements, fitted model, names, paths) and a ``progress``
callback, and returns picklable results, so :func:`~quickhealth.station.tui.offload.offload`
can run it in a child process (forked from a server that has loaded this module and what it
imports).  The application layer does the work (:mod:`quickhealth.station.services`), as for
every other door; figures and reports are written where asked.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ...identify.assess import Assessment, evaluate
from ...identify.compare import Comparison, compare_effect, plot_comparison
from ...identify.diagnose import Diagnosis, diagnose, state_from_fitted
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.robot import RobotModel
from ...identify.workspace import reference_conditions
from ..archive import Archive
from ..fsio import write_figure
from ..reporting.verdict import Judgement, Spec
from ..services import fitting
from ..services.options import FitOptions, ReportOptions
from ..services.report import report_run
from . import figures
from .views import HistoryRow, JointCurve, Region

Progress = Callable[[str], None]


def assess_job(
    robot: RobotModel,
    meas: Measurements,
    options: FitOptions,
    progress: Progress | None = None,
) -> Assessment:
    """The assessment with ``options``: the same function and defaults as ``identify fit``
    (:func:`~quickhealth.station.services.fitting.assess`), so the TUI's report.json equals
    the command line's."""
    return fitting.assess(meas, robot, options, progress=progress)


def evaluate_job(
    fitted: FittedModel, meas: Measurements, progress: Progress | None = None
) -> Assessment:
    """``identify.assess.evaluate``: the assessment of an already fitted model."""
    return evaluate(meas, fitted)


def diagnose_job(
    fitted: FittedModel, meas: Measurements, progress: Progress | None = None
) -> Diagnosis:
    """The diagnosis (``identify.diagnose.Diagnosis``) of ``fitted`` on ``meas``."""
    return diagnose(state_from_fitted(fitted), meas)


def compare_job(
    fitted: FittedModel,
    meas: Measurements,
    effect: str,
    heldout: Measurements | None,
    folds: int,
    png: str | None = None,
    progress: Progress | None = None,
) -> Comparison:
    """``identify.compare.compare_effect``; its before/after figure written to ``png`` if given."""
    cmp = compare_effect(fitted, meas, effect, heldout=heldout, folds=folds, progress=progress)
    if png is not None:
        write_figure(plot_comparison(cmp), png, dpi=90)
    return cmp


def report_job(
    run_dir: str,
    archive_root: str,
    archive_url: str,
    robot: str,
    run_id: str,
    spec: Spec | None,
    progress: Progress | None = None,
) -> Judgement:
    """The run's report as ``quickhealth report`` makes it against the robot's archive (the
    sections, the verdict and the run object in report.json; no report.html: the screens
    show the figures, ``quickhealth report`` writes the page); its verdict."""
    res = report_run(
        Path(run_dir),
        archive=Archive.open(archive_root, archive_url),
        robot=robot,
        run_id=run_id,
        options=ReportOptions(accuracy_spec=spec),
        write_html=False,
    )
    return res.report.judgement


def results_pngs_job(
    counts: Sequence[int],
    edges_mm: Sequence[float],
    spec_mm: float | None,
    curves: Sequence[JointCurve],
    out_dir: str,
    progress: Progress | None = None,
) -> tuple[str, str]:
    """The Results screen's PNGs: workspace error histogram and joint curves."""
    d = Path(out_dir)
    return (
        figures.histogram_png(counts, edges_mm, spec_mm, d / "workspace_error.png"),
        figures.curves_png(curves, d / "joint_curves.png"),
    )


def trend_png_job(
    rows: Sequence[HistoryRow],
    spec_mm: float | None,
    png: str,
    progress: Progress | None = None,
) -> str:
    """The History screen's PNG: the main figures over the runs."""
    return figures.trend_png(rows, spec_mm, Path(png))


def regions_job(fitted: FittedModel, progress: Progress | None = None) -> tuple[Region, ...]:
    """Where in the workspace the model's TCP error is largest (:func:`worst_regions`)."""
    return worst_regions(fitted)


def worst_regions(
    fitted: FittedModel, n_samples: int = 4000, seed: int = 1, top: int = 5
) -> tuple[Region, ...]:
    """Where in the workspace the model's TCP error is largest, in words a technician can use.

    Commands are drawn uniformly over the model's joint ranges; the target's nominal position
    in the robot base frame is binned by side (front = +x, left = +y, back, right of the base;
    90° sectors),
    height (low/mid/high thirds of the sampled heights) and reach (near/far half); the regions
    with the largest mean error come first.
    """
    rng = np.random.default_rng(seed)
    spec = fitted.spec
    q = rng.uniform(spec.q_lo, spec.q_hi, (n_samples, spec.n_joints))
    cond = reference_conditions(fitted).arrays(q, fitted.robot)  # at the stated conditions
    err = fitted.tcp_error(q, approach=np.ones_like(q), **cond) * 1e3
    p = (fitted.robot.fk(q) @ fitted.T_flange_target0)[:, :3, 3]
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    side = np.digitize((az + 45.0) % 360.0, [90.0, 180.0, 270.0])
    height = np.digitize(p[:, 2], np.quantile(p[:, 2], [1 / 3, 2 / 3]))
    reach = np.hypot(p[:, 0], p[:, 1])
    far = (reach > np.median(reach)).astype(int)
    key = side * 6 + height * 2 + far
    sides = ("front", "left", "back", "right")
    heights = ("low", "mid", "high")
    out = []
    for k in np.unique(key):
        sel = key == k
        if sel.sum() < n_samples // 100:
            continue
        s, h, f = k // 6, (k % 6) // 2, k % 2
        zs = p[sel, 2] * 1e3
        where = (
            f"{sides[s]} {heights[h]} {'far' if f else 'near'} (z {zs.min():.0f}…{zs.max():.0f})"
        )
        out.append(Region(where, float(np.mean(err[sel]))))
    out.sort(key=lambda r: -r.err_mm)
    return tuple(out[:top])
