"""The heavy computations behind the screens, as pure module-level functions.

Each takes plain data (robot, measurements, fitted model, names) and a ``progress`` callback,
and returns picklable results, so :func:`~quickhealth.station.tui.offload.offload` can run
it in a child process.  Nothing here reads files; figures are written where asked (PNG).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import RobotModel

from .views import Region

Progress = Callable[[str], None]


def assess_job(
    robot: RobotModel,
    meas: Measurements,
    effects: Sequence[str],
    max_order: int,
    progress: Progress | None = None,
) -> Any:
    """The assessment (``identify.assess.Assessment``) with ``effects``: the same function and
    defaults as ``identify fit``, so the TUI's report.json equals the command line's."""
    from quickhealth.identify.assess import assess

    return assess(meas, robot, list(effects), max_order=max_order, progress=progress)


def evaluate_job(fitted: Any, meas: Measurements, progress: Progress | None = None) -> Any:
    """``identify.assess.evaluate``: the assessment of an already fitted model."""
    from quickhealth.identify.assess import evaluate

    return evaluate(meas, fitted)


def diagnose_job(fitted: Any, meas: Measurements, progress: Progress | None = None) -> Any:
    """The diagnosis (``identify.diagnose.Diagnosis``) of ``fitted`` on ``meas``."""
    from quickhealth.identify.diagnose import diagnose, state_from_fitted

    return diagnose(state_from_fitted(fitted), meas)


def compare_job(
    fitted: Any,
    meas: Measurements,
    effect: str,
    heldout: Measurements | None,
    folds: int,
    png: str | None = None,
    progress: Progress | None = None,
) -> Any:
    """``identify.compare.compare_effect``; its before/after figure written to ``png`` if given."""
    from quickhealth.identify.compare import compare_effect, plot_comparison

    cmp = compare_effect(fitted, meas, effect, heldout=heldout, folds=folds, progress=progress)
    if png is not None:
        from ..fsio import write_figure

        write_figure(plot_comparison(cmp), png, dpi=90)
    return cmp


def results_pngs_job(
    counts: Sequence[int],
    edges_mm: Sequence[float],
    threshold_mm: float,
    curves: Sequence[Any],
    out_dir: str,
    progress: Progress | None = None,
) -> tuple[str, str]:
    """The Results screen's PNGs: workspace error histogram and joint curves."""
    from pathlib import Path

    from . import figures

    d = Path(out_dir)
    return (
        figures.histogram_png(counts, edges_mm, threshold_mm, d / "workspace_error.png"),
        figures.curves_png(curves, d / "joint_curves.png"),
    )


def trend_png_job(
    rows: Sequence[Any], threshold_mm: float, png: str, progress: Progress | None = None
) -> str:
    """The History screen's PNG: the main figures over the runs."""
    from pathlib import Path

    from . import figures

    return figures.trend_png(rows, threshold_mm, Path(png))


def regions_job(fitted: Any, progress: Progress | None = None) -> tuple[Region, ...]:
    """Where in the workspace the model's TCP error is largest (:func:`worst_regions`)."""
    return worst_regions(fitted)


def worst_regions(
    fitted: Any, n_samples: int = 4000, seed: int = 1, top: int = 5
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
    from quickhealth.identify.workspace import reference_conditions

    cond = reference_conditions(fitted).arrays(n_samples)  # thermal/drift at stated conditions
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
