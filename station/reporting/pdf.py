"""The report on one page: a PDF beside report.html, for the file, the print-out and the
signature (``quickhealth report`` writes RUN_DIR/report.pdf).

Made with matplotlib, like every other figure of the report, not by printing the HTML page
in headless Chromium: matplotlib is already a dependency of every station, draws the same
figures from the same data (:mod:`.figures`), lays out a fixed A4 page whatever the data,
and needs no browser on the station PC or the nightly job's server.  The page holds the
verdict (against the spec and the baseline, what to do), where the error is, before and
after calibration, the TCP error's distribution, how each joint's error varies, and the
trend.  Returned as a figure; the report service writes it.
"""

from __future__ import annotations

import textwrap
from datetime import UTC, datetime
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import FancyBboxPatch

from ...identify.workspace import JointCurves
from ..provenance import software_version
from . import figures
from .verdict import HealthVerdict, Judgement

if TYPE_CHECKING:  # the type only: the report service builds what this page draws
    from ..services.report import RunReport

A4 = (8.27, 11.69)  # inches, portrait
COLOURS = {
    HealthVerdict.HEALTHY: ("#effaf3", "#2a7"),
    HealthVerdict.DEGRADED: ("#fff8e6", "#d90"),
    HealthVerdict.FLAGGED: ("#fdeeee", "#c22"),
}


def report_page(rep: RunReport) -> Figure:
    """One A4 page of a run's report."""
    j = rep.judgement
    spec_mm = None if j.spec is None else j.spec.mm
    fig = Figure(figsize=A4)
    fig.text(0.05, 0.985, rep.title, fontsize=11, weight="bold", va="top")
    fig.text(
        0.05,
        0.965,
        f"made {datetime.now(UTC):%Y-%m-%d %H:%M} UTC by quickhealth {software_version()}; "
        "lengths in mm, angles in mrad, positions in the robot base frame",
        fontsize=7,
        color="0.35",
        va="top",
    )
    _verdict_box(fig, j)
    fig.text(0.05, 0.79, "checked by: ______________________   date: ______________   "
             "signature: ______________________", fontsize=8, color="0.3")  # fmt: skip
    wm = rep.workspace_map
    if wm is not None:
        a1 = fig.add_axes((0.08, 0.555, 0.36, 0.18))
        a2 = fig.add_axes((0.53, 0.555, 0.35, 0.18))
        sc = figures.draw_workspace_map(a1, a2, wm, spec_mm)
        figures.colourbar(fig, sc, fig.add_axes((0.9, 0.555, 0.012, 0.18)), spec_mm)
        fig.text(0.05, 0.762, "Where the TCP error is (each cell: its largest; ★ the largest)",
                 fontsize=9, weight="bold")  # fmt: skip
    calib = rep.calibration
    if calib:
        ax = fig.add_axes((0.1, 0.36, 0.34, 0.12))
        figures.draw_before_after(ax, calib, spec_mm)
        fig.text(0.05, 0.5, "Before and after calibration", fontsize=9, weight="bold")
    ws = rep.workspace
    if ws is not None:
        ax = fig.add_axes((0.58, 0.36, 0.37, 0.12))
        figures.draw_histogram(ax, ws, spec_mm)
        fig.text(0.53, 0.5, "TCP error over the workspace", fontsize=9, weight="bold")
    curves = rep.curves
    if curves:
        ax_t = fig.add_axes((0.1, 0.19, 0.34, 0.1))
        ax_r = fig.add_axes((0.58, 0.19, 0.37, 0.1))
        _variation(ax_t, ax_r, curves)
        fig.text(
            0.05, 0.305, "How much each joint's error varies over its range (peak to peak)",
            fontsize=9, weight="bold",
        )  # fmt: skip
    trend = rep.trend
    ax = fig.add_axes((0.1, 0.045, 0.85, 0.075))
    if trend is not None:
        figures.draw_trend(ax, trend, "max", spec_mm)
        ax.legend(fontsize=6, loc="upper left", ncol=4)
        fig.text(0.05, 0.135, "Trend: max TCP error over time", fontsize=9, weight="bold")
    else:
        ax.set_axis_off()
        ax.text(0, 0.5, f"No trend: {j.no_baseline}", fontsize=8, va="center")
    return fig


def _verdict_box(fig: Figure, j: Judgement) -> None:
    """The verdict's lines in a box coloured by the verdict."""
    face, edge = COLOURS[j.verdict]
    lines = list(j.lines())
    if j.top_missing_effect is not None:
        lines.append(f"top missing effect: {j.top_missing_effect.effect}")
    wrapped = "\n".join(textwrap.fill(x, 118, subsequent_indent="   ") for x in lines[1:])
    head = textwrap.fill(lines[0], 88)
    # the box holds the lines (about 0.0125 of the page per 7.5 pt line, 0.019 per heading)
    height = 0.03 + 0.019 * (head.count("\n") + 1) + 0.0125 * (wrapped.count("\n") + 1)
    bottom = max(0.945 - height, 0.8)
    fig.patches.append(
        FancyBboxPatch(
            (0.04, bottom), 0.92, 0.945 - bottom, boxstyle="round,pad=0.004", fc=face, ec=edge,
            lw=2, transform=fig.transFigure, figure=fig,
        )
    )  # fmt: skip
    fig.text(0.055, 0.937, head, fontsize=11, weight="bold", va="top", color=edge)
    top = 0.915 - 0.016 * head.count("\n")
    fig.text(0.055, top, wrapped, fontsize=7.5, va="top", linespacing=1.35)


def _variation(ax_t: Axes, ax_r: Axes, curves: tuple[JointCurves, ...]) -> None:
    """Peak-to-peak variation of each joint's three translations (mm) and rotations (mrad)."""
    n = len(curves)
    x = np.arange(1, n + 1)
    for ax, rows, unit, names in (
        (ax_t, range(0, 3), "mm", ("δx", "δy", "δz")),
        (ax_r, range(3, 6), "mrad", ("εx", "εy", "εz")),
    ):
        for k, m in enumerate(rows):
            v = [float(np.ptp(c.values[m])) * 1e3 for c in curves]
            ax.bar(x + (k - 1) * 0.27, v, 0.27, label=names[k])
        ax.set_xticks(x, [f"j{c.joint}" for c in curves], fontsize=7)
        ax.set_ylabel(f"variation ({unit})", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, ncol=3)
