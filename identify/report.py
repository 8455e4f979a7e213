"""Figures a user looks at (matplotlib): they are returned, never saved here.

Figures are built with ``matplotlib.figure.Figure`` directly (no pyplot, no global backend
state); ``fig.savefig(path)`` renders them with the Agg renderer.  Fixed margins, not
``tight_layout``: measuring every tick label's extent was 40 % of ``identify fit --plots``.

- :func:`workspace_histogram`: TCP error over the workspace (paper Fig. 7).
- :func:`joint_curve_figure`: one joint's six error motions with confidence bands (Fig. 8).
- :func:`residual_plot`: measured minus model per pose, so a user sees where the model fails.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .errormodel import MOTION_WORDS, MOTIONS
from .fit import FittedModel
from .measurements import Measurements
from .workspace import JointCurves, WorkspaceError


def workspace_histogram(ws: WorkspaceError, title: str = "") -> Figure:
    """Histogram of the model's TCP position error over the sampled workspace (mm)."""
    fig = Figure(figsize=(6.4, 4.0))
    ax = fig.add_subplot(111)
    e = ws.hist_edges * 1e3
    ax.bar(
        e[:-1], ws.hist_counts, width=np.diff(e), align="edge", color="#4477aa", edgecolor="white"
    )
    for v, lab, ls in ((ws.mean, "mean", "-"), (ws.p95, "95 %", "--"), (ws.max, "max", ":")):
        ax.axvline(v * 1e3, color="k", ls=ls, lw=1)
        ax.text(v * 1e3, ax.get_ylim()[1] * 0.95, f" {lab} {v * 1e3:.3f}", fontsize=8, va="top")
    ax.set_xlabel("TCP position error from the model (mm)")
    ax.set_ylabel(f"joint commands (of {ws.n_samples})")
    ax.set_title(
        title or f"Workspace TCP error: mean {ws.mean * 1e3:.3f} mm, std {ws.std * 1e3:.3f} mm"
    )
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.12, top=0.91)
    return fig


def joint_curve_figure(curves: JointCurves, truth: np.ndarray | None = None) -> Figure:
    """Six panels: each error motion of one joint over its range with its band.

    ``truth`` (6, k), optional: curves to overlay (synthetic checks).
    """
    fig = Figure(figsize=(9.0, 6.0))
    th = np.degrees(curves.theta)
    axes = fig.subplots(2, 3, sharex=True).ravel()  # x tick labels on the bottom row only
    for m in range(6):
        ax = axes[m]
        v = curves.values[m] * 1e3
        h = curves.half_width[m] * 1e3
        unit = "mm" if m < 3 else "mrad"
        if not np.any(v) and not np.any(h):  # held at zero: not "no error", unknown
            ax.set_title(f"{MOTIONS[m]}: {MOTION_WORDS[MOTIONS[m]]}", fontsize=8, y=1.0)
            ax.set_facecolor("#f2f2f2")
            ax.text(0.5, 0.5, "not identifiable\nfrom this data", ha="center", va="center",
                    fontsize=8, color="0.3", transform=ax.transAxes)  # fmt: skip
            ax.set_yticks([])
            ax.tick_params(labelsize=7)
            if m >= 3:
                ax.set_xlabel(f"joint {curves.joint} angle (deg)", fontsize=8)
            ax.set_xlim(th[0], th[-1])
            continue
        ax.fill_between(
            th,
            v - h,
            v + h,
            color="#88ccee",
            alpha=0.6,
            lw=0,
            label=f"{curves.level:.0%} band (whole curve)",
        )
        ax.plot(th, v, color="#224488", lw=1.5, label="identified")
        if truth is not None:
            ax.plot(th, truth[m] * 1e3, color="#cc3311", lw=1, ls="--", label="truth")
        # a fixed title position: placing it above the tick labels measured every label
        ax.set_title(f"{MOTIONS[m]}: {MOTION_WORDS[MOTIONS[m]]}", fontsize=8, y=1.0)
        ax.set_ylabel(unit, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=4)
        if m >= 3:
            ax.set_xlabel(f"joint {curves.joint} angle (deg)", fontsize=8)
        if m == 0:
            ax.legend(fontsize=7)
    fig.suptitle(f"Joint {curves.joint}: error motions")
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.09, top=0.9, wspace=0.32, hspace=0.3)
    return fig


def residuals_in_base(fitted: FittedModel) -> tuple[np.ndarray, np.ndarray | None]:
    """The fit's residuals (measured − model) turned from the instrument's axes into the robot
    base's (the registered base, :attr:`~.fit.FittedModel.registration`): position (m) and,
    for pose data, rotation vectors (rad), shape (n, 3) each."""
    R = fitted.registration[0][:3, :3]  # base axes in the instrument frame
    rot = None if fitted.residual_rot is None else fitted.residual_rot @ R
    return fitted.residual_pos @ R, rot


def residual_plot(fitted: FittedModel, meas: Measurements) -> Figure:
    """Measured minus model per pose (execution order) and against each joint angle, in the
    robot base frame (the registered base's axes: :func:`residuals_in_base`)."""
    rp, rr = residuals_in_base(fitted)
    rp = rp * 1e3
    n = rp.shape[0]
    rows = 2 if fitted.residual_rot is not None else 1
    fig = Figure(figsize=(10.0, 3.2 * (rows + 1)))
    ax = fig.add_subplot(rows + 1, 1, 1)
    idx = np.arange(1, n + 1)
    for k, c in enumerate("xyz"):
        ax.plot(idx, rp[:, k], ".", ms=3, label=f"{c}")
    ax.plot(idx, np.linalg.norm(rp, axis=1), "k-", lw=0.6, label="|r|")
    sp = fitted.noise.sigma_pos * 1e3
    ax.axhspan(-2 * sp, 2 * sp, color="0.9", zorder=0, label="±2σ instrument")
    ax.set_xlabel("pose (execution order)")
    ax.set_ylabel("measured − model (mm, base frame)")
    ax.legend(fontsize=7, ncol=5)
    ax.set_title(f"Residuals: rms {fitted.rms_pos * 1e3:.4f} mm", y=1.0)
    if rr is not None:
        ax2 = fig.add_subplot(rows + 1, 1, 2)
        rr = rr * 1e3
        for k, c in enumerate("xyz"):
            ax2.plot(idx, rr[:, k], ".", ms=3, label=f"rot {c}")
        ax2.set_xlabel("pose (execution order)")
        ax2.set_ylabel("rotation residual (mrad, base frame)")
        ax2.legend(fontsize=7, ncol=3)
    nj = meas.n_joints
    qd = np.degrees(meas.q)
    norm_r = np.linalg.norm(rp, axis=1)
    for j in range(nj):
        a = fig.add_subplot(rows + 1, nj, rows * nj + j + 1)
        a.plot(qd[:, j], norm_r, ".", ms=2)
        a.set_xlabel(f"q{j + 1} (deg)", fontsize=7)
        a.tick_params(labelsize=6)
        if j == 0:
            a.set_ylabel("|r| (mm)", fontsize=7)
        a.locator_params(nbins=4)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.08, top=0.95, hspace=0.45, wspace=0.3)
    return fig
