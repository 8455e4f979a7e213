"""Plots of a plan as in the paper's Fig. 6 (matplotlib, Agg backend).

- ``fig6_joints.png``: per-joint histograms of the kept poses over the joint's usable range,
  with the planning limits, coverage and evenness in each title;
- ``fig6_targets.png``: Cartesian scatter of the generated targets, kept (by leg type) and
  dropped (by reason), in 3D and seen from above, with the cameras and the robot base.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..fsio import write_figure
from ..hardware.legs import Leg
from .planner import DropReason, PlanResult


def write_figures(res: PlanResult, out_dir: Path) -> list[Path]:
    """Write the Fig. 6 plots into ``out_dir``; returns their paths."""
    import matplotlib  # only when a plan is written: the planner itself draws nothing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    paths = []
    cell = res.cell
    q = np.degrees(np.array([p.q for p in res.poses]))
    c = res.coverage
    lo, hi = np.degrees(c.usable_min), np.degrees(c.usable_max)
    names = cell.robot.joint_names
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), constrained_layout=True)
    for j, ax in enumerate(axes.flat):
        w = (hi[j] - lo[j]) / c.bins  # the evenness bins, extended over any kept value outside
        k0 = int(np.floor((min(q[:, j].min(), lo[j]) - lo[j]) / w))
        k1 = int(np.ceil((max(q[:, j].max(), hi[j]) - lo[j]) / w))
        edges = lo[j] + w * np.arange(k0, k1 + 1)
        ax.hist(q[:, j], bins=edges, color="tab:blue", edgecolor="white")
        ax.axvspan(lo[j], hi[j], color="tab:green", alpha=0.08, label="usable range")
        ax.set_xlim(np.degrees(cell.robot.q_min[j]), np.degrees(cell.robot.q_max[j]))
        ax.set_title(
            f"j{j + 1} {names[j] if j < len(names) else ''}: coverage {c.coverage[j] * 100:.0f}%,"
            f" evenness {c.evenness[j]:.2f}",
            fontsize=9,
        )
        ax.set_xlabel("joint angle (deg)")
        ax.set_ylabel("kept poses")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(
        f"Joint distribution of the kept poses ({len(res.poses)} of {res.n_generated}; cell {cell.name})"
    )
    p = out_dir / "fig6_joints.png"
    write_figure(fig, p, dpi=110)  # atomic; closes the pyplot figure
    paths.append(p)

    fig = plt.figure(figsize=(13, 6), constrained_layout=True)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    groups: list[tuple[str, np.ndarray, str, str]] = []
    for leg, col in ((Leg.LINEAR, "tab:blue"), (Leg.JOINT, "tab:cyan")):
        pts = np.array([p.T_world_target[:3, 3] for p in res.poses if p.leg == leg]).reshape(-1, 3)
        groups.append((f"kept, {leg.value} leg ({len(pts)})", pts, col, "o"))
    colours = dict(
        zip(
            DropReason,
            (
                "tab:gray",
                "tab:brown",
                "tab:orange",
                "tab:pink",
                "tab:purple",
                "tab:red",
                "black",
                "tab:olive",
            ),
            strict=True,
        )
    )
    for r in DropReason:
        pts = np.array([d.T_world_target[:3, 3] for d in res.dropped if d.reason == r]).reshape(
            -1, 3
        )
        if len(pts):
            groups.append((f"dropped: {r.value} ({len(pts)})", pts, colours[r], "x"))
    for label, pts, col, mk in groups:
        if len(pts) == 0:
            continue
        ax3.scatter(pts[:, 0], pts[:, 1], pts[:, 2], c=col, marker=mk, s=14, label=label)
        ax2.scatter(pts[:, 0], pts[:, 1], c=col, marker=mk, s=14, label=label)
    loop = np.array(
        [p.T_world_target[:3, 3] for p in res.poses] + [res.poses[0].T_world_target[:3, 3]]
    )
    ax2.plot(loop[:, 0], loop[:, 1], color="tab:blue", lw=0.5, alpha=0.5)
    for Tc, name in (
        (cell.T_world_cam_left, "left camera"),
        (cell.T_world_cam_right, "right camera"),
    ):
        ax3.scatter(*Tc[:3, 3], c="k", marker="s", s=30)
        ax2.scatter(Tc[0, 3], Tc[1, 3], c="k", marker="s", s=30)
        ax2.annotate(name, (Tc[0, 3], Tc[1, 3]), fontsize=8)
    b = cell.T_world_base[:3, 3]
    ax3.scatter(*b, c="k", marker="^", s=40)
    ax2.scatter(b[0], b[1], c="k", marker="^", s=40)
    ax2.annotate("robot base", (b[0], b[1]), fontsize=8)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax2.set_xlabel("x (m)")
    ax2.set_ylabel("y (m)")
    ax2.set_aspect("equal")
    ax2.set_title("seen from above (world frame); line = loop order")
    ax2.legend(fontsize=7, loc="best")
    fig.suptitle(f"Generated targets: kept and dropped (cell {cell.name}, seed {res.seed})")
    p = out_dir / "fig6_targets.png"
    write_figure(fig, p, dpi=110)  # atomic; closes the pyplot figure
    paths.append(p)
    return paths
