"""The report's figures (matplotlib's object API, Agg: safe in any thread); SI in, mm / mrad /
degrees on the axes.  Each ``draw_*`` draws into given axes, so the page's figures and the
one-page PDF (:mod:`.pdf`) draw the same thing; the ``*_figure`` functions make a figure of
one.  Figures are returned, never saved here.

- :func:`coverage_figure`: the plan's joint angles over each joint's range (paper Fig. 6);
- :func:`histogram_figure`: the TCP error over the workspace with the spec (paper Fig. 7);
- :func:`workspace_map_figure`: where in the workspace the error is (top and side views);
- :func:`before_after_figure`: the error at measured poses, nominal against the model;
- :func:`joint_figure`: one joint's six error motions as variation about their offset, on
  scales shared by every joint (paper Fig. 8);
- :func:`iso_figure`, :func:`trend_figure`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta

import matplotlib

matplotlib.use("Agg")

import matplotlib.dates as mdates  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from ...identify.errormodel import MOTION_WORDS, MOTIONS  # noqa: E402
from ...identify.fit import FittedModel  # noqa: E402
from ...identify.robot import RobotModel  # noqa: E402
from ...identify.trend import TrendResult  # noqa: E402
from ...identify.workspace import JointCurves, WorkspaceError, WorkspaceMap  # noqa: E402
from .calibration import BeforeAfter  # noqa: E402
from .iso9283 import PoseStats  # noqa: E402

F = NDArray[np.float64]
SPEC_COLOUR = "#cc3311"


def coverage_figure(robot: RobotModel, q: F, q_lo: F, q_hi: F) -> Figure:
    """The commanded joint angles over each joint's modelled range and the flange positions."""
    nj = q.shape[1]
    fig = Figure(figsize=(10.0, 5.6))
    for j in range(nj):
        ax = fig.add_subplot(2, nj, j + 1)
        ax.hist(np.degrees(q[:, j]), bins=24, range=(np.degrees(q_lo[j]), np.degrees(q_hi[j])))
        ax.set_title(f"joint {j + 1}", fontsize=8, y=1.0)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("deg", fontsize=7)
    T = robot.fk(q)
    p = T[:, :3, 3] * 1e3
    for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        ax = fig.add_subplot(2, 3, 4 + k)
        ax.plot(p[:, a], p[:, b], ".", ms=3)
        ax.set_xlabel(f"{'xyz'[a]} (mm, base)", fontsize=7)
        ax.set_ylabel(f"{'xyz'[b]} (mm, base)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Plan coverage: {q.shape[0]} poses (joint angles; flange positions)")
    fig.tight_layout()
    return fig


def draw_histogram(ax: Axes, ws: WorkspaceError, spec_mm: float | None) -> None:
    """The TCP error over the sampled workspace (mm), mean / 95 % / max marked, the spec drawn;
    labels inside the axes, the x axis wide enough for the spec and the max."""
    e = ws.hist_edges * 1e3
    ax.bar(e[:-1], ws.hist_counts, width=np.diff(e), align="edge", color="#4477aa", ec="white")
    top = float(ws.hist_counts.max()) * 1.3 if ws.hist_counts.size else 1.0
    ax.set_ylim(0.0, top)
    right = max(float(e[-1]), spec_mm or 0.0) * 1.12
    ax.set_xlim(0.0, right)
    marks = [(ws.mean, "mean", "-"), (ws.p95, "95 %", "--"), (ws.max, "max", ":")]
    for k, (v, lab, ls) in enumerate(marks):
        x = v * 1e3
        ax.axvline(x, color="k", ls=ls, lw=1)
        ha = "right" if x > 0.75 * right else "left"
        ax.text(x, top * (0.98 - 0.12 * k), f" {lab} {x:.3f} mm ", fontsize=6.5, va="top",
                ha=ha, bbox=dict(fc="white", ec="none", alpha=0.8, pad=0.5))  # fmt: skip
    if spec_mm is not None:
        ax.axvline(spec_mm, color=SPEC_COLOUR, lw=2)
        ha = "right" if spec_mm > 0.75 * right else "left"
        ax.text(spec_mm, top * 0.6, f" spec {spec_mm:g} mm ", color=SPEC_COLOUR, fontsize=8,
                ha=ha, va="center", rotation=90)  # fmt: skip
    ax.set_xlabel("TCP position error from the model (mm)", fontsize=8)
    ax.set_ylabel(f"joint commands (of {ws.n_samples})", fontsize=8)
    ax.tick_params(labelsize=7)


def histogram_figure(ws: WorkspaceError, spec_mm: float | None) -> Figure:
    """:func:`draw_histogram` as a figure."""
    fig = Figure(figsize=(6.4, 3.8))
    ax = fig.add_subplot(111)
    draw_histogram(ax, ws, spec_mm)
    ax.set_title(
        f"TCP error over the workspace: mean {ws.mean * 1e3:.3f} mm, max {ws.max * 1e3:.3f} mm",
        fontsize=9,
    )
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.14, top=0.9)
    return fig


def draw_workspace_map(
    ax_top: Axes, ax_side: Axes | None, wm: WorkspaceMap, spec_mm: float | None
) -> object:
    """The sampled TCP positions (robot base frame), each hexagon coloured by the largest TCP
    error of the commands that reach it (a position is reached with many joint configurations,
    so the worst one counts): seen from above (x, y) and from the side (reach from the base
    axis, z); the worst command marked.  The colour scale ends at the spec when one is set
    and the error stays below it (then red means near the spec), else at the largest error.
    Returns the colour mapping."""
    p, err = wm.xyz_base * 1e3, wm.err * 1e3
    vmax = max(float(err.max()), spec_mm or 0.0)
    kw = dict(C=err, reduce_C_function=np.max, gridsize=22, cmap="turbo", vmin=0.0, vmax=vmax,
              mincnt=1, linewidths=0.2)  # fmt: skip
    sc = ax_top.hexbin(p[:, 0], p[:, 1], **kw)
    w = wm.worst
    ax_top.plot(p[w, 0], p[w, 1], "k*", ms=12, mfc="none", mew=1.2)
    ax_top.plot(0, 0, "k+", ms=10)
    ax_top.set_xlabel("x (mm, robot base)", fontsize=8)
    ax_top.set_ylabel("y (mm, robot base)", fontsize=8)
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.set_title("from above", fontsize=8)
    ax_top.tick_params(labelsize=7)
    if ax_side is not None:
        r = np.hypot(p[:, 0], p[:, 1])
        ax_side.hexbin(r, p[:, 2], **kw)
        ax_side.plot(r[w], p[w, 2], "k*", ms=12, mfc="none", mew=1.2)
        ax_side.set_xlabel("reach from the base axis (mm)", fontsize=8)
        ax_side.set_ylabel("z (mm, robot base)", fontsize=8)
        ax_side.set_aspect("equal", adjustable="datalim")
        ax_side.set_title("from the side", fontsize=8)
        ax_side.tick_params(labelsize=7)
    return sc


def workspace_map_figure(wm: WorkspaceMap, spec_mm: float | None) -> Figure:
    """:func:`draw_workspace_map` as a figure with its colour bar (the spec marked)."""
    fig = Figure(figsize=(10.0, 4.4))
    a1 = fig.add_axes((0.06, 0.12, 0.38, 0.76))
    a2 = fig.add_axes((0.5, 0.12, 0.38, 0.76))
    sc = draw_workspace_map(a1, a2, wm, spec_mm)
    cax = fig.add_axes((0.91, 0.12, 0.018, 0.76))
    colourbar(fig, sc, cax, spec_mm)
    fig.suptitle(
        f"Where the TCP error is: the largest error of {len(wm.err)} commands in each cell "
        f"(★ the largest, {wm.err.max() * 1e3:.3f} mm)",
        fontsize=9,
    )
    return fig


def colourbar(fig: Figure, sc: object, cax: Axes, spec_mm: float | None) -> None:
    """The map's colour bar in mm, the spec a black line across it."""
    cb = fig.colorbar(sc, cax=cax)  # type: ignore[arg-type]
    cb.set_label(
        "TCP error (mm)" + ("; black line: the spec" if spec_mm is not None else ""), fontsize=7
    )
    cb.ax.tick_params(labelsize=7)
    if spec_mm is not None:
        cb.ax.axhline(spec_mm, color="k", lw=3)


def draw_before_after(ax: Axes, sets: Sequence[BeforeAfter], spec_mm: float | None) -> None:
    """RMS and max TCP error at measured poses: nominal kinematics against the model."""
    labels, x = [], 0.0
    for s in sets:
        for which, colour, name in (
            ("before", "#bbbbbb", "nominal"),
            ("after", "#4477aa", "model"),
        ):
            v = getattr(s, which) * 1e3
            rms, mx = float(np.sqrt(np.mean(v**2))), float(v.max())
            ax.bar(x, rms, 0.7, color=colour)
            ax.plot([x - 0.35, x + 0.35], [mx, mx], color="k", lw=1.5)
            where = s.label.split(" (")[0].replace("the fitted poses", "fitted poses")
            labels.append((x, f"{name}, {where}\nRMS {rms:.3f}, max {mx:.3f}"))
            x += 1.0
        x += 0.5
    if spec_mm is not None:
        ax.axhline(spec_mm, color=SPEC_COLOUR, lw=1.5, ls="--")
        ax.text(x - 0.6, spec_mm, f"spec {spec_mm:g} mm", color=SPEC_COLOUR, fontsize=7,
                ha="right", va="bottom")  # fmt: skip
    ax.set_xticks([p for p, _ in labels], [t for _, t in labels], fontsize=7)
    ax.set_ylabel("TCP position error (mm)\nbar: RMS, line: max", fontsize=8)
    ax.tick_params(axis="y", labelsize=7)
    ax.set_ylim(0.0, ax.get_ylim()[1] * 1.12)


def before_after_figure(sets: Sequence[BeforeAfter], spec_mm: float | None) -> Figure:
    """:func:`draw_before_after` as a figure."""
    fig = Figure(figsize=(2.2 + 2.2 * len(sets), 3.6))
    ax = fig.add_subplot(111)
    draw_before_after(ax, sets, spec_mm)
    ax.set_title("Before and after calibration, at measured poses", fontsize=9)
    fig.subplots_adjust(left=0.2, right=0.97, bottom=0.2, top=0.88)
    return fig


def shared_limits(curves: Sequence[JointCurves]) -> tuple[float, float]:
    """The y half-range (mm for translations, mrad for rotations) every joint's panels share:
    the largest variation about its offset, band included, over all joints and motions."""
    out = []
    for rows in (slice(0, 3), slice(3, 6)):
        v = [
            np.abs(c.values[rows] - c.values[rows].mean(axis=1, keepdims=True)) + c.half_width[rows]
            for c in curves
        ]
        m = max((float(x.max()) for x in v), default=0.0) * 1e3
        out.append(m * 1.1 if m > 0 else 1e-3)
    return out[0], out[1]


def joint_figure(
    curves: JointCurves,
    fitted: FittedModel | None = None,
    limits: tuple[float, float] | None = None,
) -> Figure:
    """One joint's six error motions as variation about their mean over the joint's range
    (the offset, in each panel's title), with 95 % bands, on ``limits`` (mm, mrad) shared by
    every joint: a panel shows how the error moves with the joint, and a flat one is flat.

    A motion the data cannot identify (every coefficient held at zero, no band) is labelled
    "not identifiable" instead of drawn as a flat zero line, which would read as "no error";
    one the model does not have says "not in the model"."""
    fig = Figure(figsize=(12.0, 2.5))
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.2, top=0.74, wspace=0.45)
    lim = limits or shared_limits([curves])
    th = np.degrees(curves.theta)
    for m in range(6):
        ax = fig.add_subplot(1, 6, m + 1)
        v = curves.values[m] * 1e3
        h = curves.half_width[m] * 1e3
        unit = "mm" if m < 3 else "mrad"
        state = _motion_state(fitted, curves.joint, m, v, h)
        if state:
            ax.set_title(f"{MOTIONS[m]}: {MOTION_WORDS[MOTIONS[m]]}", fontsize=7, y=1.0)
            ax.set_facecolor("#f2f2f2")
            ax.text(0.5, 0.5, state, ha="center", va="center", fontsize=8, color="0.3",
                    transform=ax.transAxes)  # fmt: skip
            ax.set_yticks([])
            ax.set_xlabel("deg", fontsize=7, labelpad=1)
            ax.tick_params(labelsize=6, pad=1)
            continue
        off = float(v.mean())
        ax.set_title(
            f"{MOTIONS[m]}: {MOTION_WORDS[MOTIONS[m]]}\noffset {off:+.3f} {unit}, "
            f"varies {float(np.ptp(v)):.3f}",
            fontsize=6.5,
            y=1.0,
        )
        ax.fill_between(th, v - off - h, v - off + h, color="#88ccee", alpha=0.6, lw=0)
        ax.plot(th, v - off, color="#224488", lw=1.2)
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.set_ylim(-lim[m >= 3], lim[m >= 3])
        ax.set_ylabel(f"{unit} about the offset", fontsize=6.5, labelpad=1)
        ax.set_xlabel("deg", fontsize=7, labelpad=1)
        ax.tick_params(labelsize=6, pad=1)
    fig.suptitle(
        f"Joint {curves.joint}: error motions about their offset, {curves.level:.0%} bands "
        f"(every joint on the same scales: ±{lim[0]:.3g} mm, ±{lim[1]:.3g} mrad)",
        fontsize=9,
    )
    return fig


def _motion_state(fitted: FittedModel | None, joint: int, m: int, v: F, h: F) -> str:
    """'' for a motion to draw; else why it is not drawn."""
    if fitted is not None:
        if fitted.spec.orders[joint, m] < 0:
            return "not in the model"
        prefix = f"j{joint}.{MOTIONS[m]}."
        labels = [lb for lb in fitted.labels if lb.startswith(prefix)]
        if labels and all(lb in set(fitted.unidentifiable) for lb in labels):
            return "not identifiable"
    if not np.any(v) and not np.any(h):
        return "not identifiable"
    return ""


def iso_figure(stats: list[PoseStats]) -> Figure:
    """ISO 9283 pose accuracy (AP) and repeatability (RP) per repeated pose."""
    rot = all(s.accuracy_abc is not None for s in stats)
    fig = Figure(figsize=(8.0, 5.6 if rot else 3.2))
    ax = fig.add_subplot(2 if rot else 1, 1, 1)
    x = np.arange(len(stats))
    ax.bar(x - 0.2, [s.accuracy * 1e3 for s in stats], 0.4, label="AP (accuracy)")
    ax.bar(x + 0.2, [s.repeatability * 1e3 for s in stats], 0.4, label="RP (repeatability)")
    ax.set_xticks(x, [s.pose_id for s in stats], fontsize=7, rotation=45)
    ax.set_ylabel("mm")
    ax.legend(fontsize=7)
    ax.set_title("ISO 9283-style pose accuracy and repeatability")
    if rot:
        ax2 = fig.add_subplot(2, 1, 2)
        ap = np.array([s.accuracy_abc for s in stats]) * 1e3
        rp = np.array([s.repeatability_abc for s in stats]) * 1e3
        for k, (name, c) in enumerate(zip("abc", ("#4477aa", "#ee6677", "#228833"), strict=True)):
            ax2.errorbar(
                x + (k - 1) * 0.2, ap[:, k], yerr=rp[:, k], fmt="o", ms=3, color=c,
                capsize=2, label=f"AP {name} ± RP {name}",
            )  # fmt: skip
        ax2.axhline(0.0, color="0.5", lw=0.8)
        ax2.set_xticks(x, [s.pose_id for s in stats], fontsize=7, rotation=45)
        ax2.set_ylabel("mrad (about base x, y, z)")
        ax2.legend(fontsize=7)
    fig.tight_layout()
    return fig


def draw_trend(ax: Axes, result: TrendResult, figure: str, spec_mm: float | None) -> None:
    """One figure over time with its EWMA control limit, the baseline marked; the time axis
    fits the runs (a day either side of a single run) and the value axis the data."""
    t = [datetime.fromtimestamp(v, UTC) for v in result.t_s]
    b = result.baseline_index
    ax.plot(t, result.figures_mm[figure], "o-", ms=4, label=f"{figure} (mm)")
    ch = result.charts.get(figure)
    seen = [v for v in result.figures_mm[figure] if math.isfinite(v)]
    if ch is not None:
        ax.plot(t[b:], ch.ewma_mm, "-", color="#228833", lw=1, label="EWMA")
        ax.plot(t[b:], ch.ucl_mm, "--", color="#aa7722", lw=1, label="control limit")
        seen += [v for v in ch.ewma_mm if math.isfinite(v)]
    ax.axvline(t[b], color="0.5", ls=":", lw=1)
    if spec_mm is not None and figure == "max":
        ax.axhline(spec_mm, color=SPEC_COLOUR, lw=1.5, label=f"spec {spec_mm:g} mm")
        seen.append(spec_mm)
    # with 2-3 runs the limit's σ comes from the runs' own differences and can sit far
    # above the data (8 mm over 1 mm figures): the axis follows the data, not the limit
    top = max(seen) * 1.3 if seen else 1.0
    ucl = [u for u in (ch.ucl_mm if ch is not None else ()) if math.isfinite(u)]
    if ucl and max(ucl) > top:
        ax.text(0.99, 0.97, f"control limit up to {max(ucl):.2f} mm (few runs: σ not yet known)",
                transform=ax.transAxes, ha="right", va="top", fontsize=7, color="#aa7722")  # fmt: skip
    ax.set_ylim(0.0, top)
    span = (t[-1] - t[0]) if len(t) > 1 else timedelta(0)
    pad = max(span * 0.08, timedelta(days=1))
    ax.set_xlim(t[0] - pad, t[-1] + pad)
    loc = mdates.AutoDateLocator(maxticks=6)
    ax.xaxis.set_major_locator(loc)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc))
    ax.set_ylabel(f"{figure} TCP error (mm)", fontsize=8)
    ax.legend(fontsize=7, loc="upper left")
    ax.tick_params(labelsize=7)


def trend_figure(result: TrendResult, spec_mm: float | None = None) -> Figure:
    """Main figures over time with the EWMA control limits and the spec, the baseline marked."""
    figs = [f for f in ("mean", "std", "max") if f in result.charts]
    fig = Figure(figsize=(9.0, 2.6 * max(len(figs), 1)))
    spec = spec_mm if spec_mm is not None else result.threshold_mm
    for k, f in enumerate(figs):
        draw_trend(fig.add_subplot(len(figs), 1, k + 1), result, f, spec)
    fig.suptitle("Workspace TCP error over time (dotted: baseline)")
    fig.tight_layout()
    return fig
