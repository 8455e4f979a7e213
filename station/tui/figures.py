"""PNG figures of what the TUI shows in the terminal: error histogram, joint curves, trend.

matplotlib's object API (``Figure``, no pyplot state, Agg canvas), so it is safe in worker
threads.  Each function returns the path written.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ...identify.errormodel import MOTIONS
from ..fsio import write_figure
from .views import HistoryRow, JointCurve


def _write(fig: Figure, path: Path) -> str:
    return write_figure(fig, path, dpi=90)  # atomic, parent folders made


def histogram_png(
    counts: Sequence[int], edges_mm: Sequence[float], spec_mm: float | None, path: Path
) -> str:
    """Workspace TCP error histogram (paper Fig. 7) with the accuracy spec (if set)."""
    fig = Figure(figsize=(6.0, 3.6), layout="constrained")
    ax = fig.subplots()
    e = np.asarray(edges_mm, float)
    ax.bar(e[:-1], np.asarray(counts, float), width=np.diff(e), align="edge", color="C0")
    if spec_mm is not None:
        ax.axvline(spec_mm, color="C3", lw=1.2, label=f"spec {spec_mm:g} mm")
        ax.set_xlim(0.0, max(float(e[-1]), spec_mm) * 1.05)
        ax.legend(fontsize=8)
    ax.set_xlabel("TCP position error over the workspace (mm)")
    ax.set_ylabel("sampled commands")
    return _write(fig, path)


def curves_png(curves: Sequence[JointCurve], path: Path) -> str:
    """Every joint's six error motions with their 95 % bands (paper Fig. 8): joints × motions."""
    joints = sorted({c.joint for c in curves}, key=lambda s: int(s[1:]))
    fig = Figure(figsize=(14.0, 2.0 * max(len(joints), 1)), layout="constrained")
    axes = fig.subplots(max(len(joints), 1), 6, squeeze=False, sharex="row")
    by_key = {(c.joint, c.motion): c for c in curves}
    for r, j in enumerate(joints):
        for m, motion in enumerate(MOTIONS):
            ax = axes[r, m]
            c = by_key.get((j, motion))
            if c is None:
                ax.set_axis_off()
                continue
            ax.fill_between(c.q_deg, c.value - c.band, c.value + c.band, color="C0", alpha=0.25)
            ax.plot(c.q_deg, c.value, color="C0", lw=1.2)
            ax.axhline(0.0, color="0.6", lw=0.6)
            ax.tick_params(labelsize=6)
            if r == 0:
                ax.set_title(f"{motion} ({c.unit})", fontsize=8)
            if m == 0:
                ax.set_ylabel(j, fontsize=8)
    fig.supxlabel("joint angle (deg)", fontsize=8)
    return _write(fig, path)


def trend_png(rows: Sequence[HistoryRow], spec_mm: float | None, path: Path) -> str:
    """Workspace mean / std / max error of the robot's runs over time."""
    fig = Figure(figsize=(7.0, 3.6), layout="constrained")
    ax = fig.subplots()
    x = np.arange(1, len(rows) + 1)
    for key, label in (("mean_mm", "mean"), ("std_mm", "std"), ("max_mm", "max")):
        ax.plot(x, [getattr(r, key) for r in rows], "o-", ms=3, label=label)
    if spec_mm is not None:
        ax.axhline(spec_mm, color="C3", lw=1.0, ls="--", label=f"spec {spec_mm:g} mm")
    ax.set_xticks(x, [r.run_id for r in rows], rotation=45, ha="right", fontsize=7)
    ax.set_ylabel("workspace TCP error (mm)")
    ax.legend(fontsize=8)
    return _write(fig, path)
