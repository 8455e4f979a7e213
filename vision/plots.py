"""Calibration report figures (matplotlib, returned not saved): residual vectors over the
image, board coverage, projection-uncertainty map."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .calibrate import CalibrationResult


def _names(res: CalibrationResult) -> list[str]:
    return ["left", "right"] if res.is_stereo else ["camera"]


def plot_residuals(res: CalibrationResult, *, scale: float | None = None) -> Figure:
    """Reprojection residual vectors at every corner (outliers red), one panel per camera.

    Same-direction clusters mean a lens model that does not fit (mrcal-show-residuals).
    """
    fig = Figure(figsize=(6.5 * len(res.cameras), 4.5))
    for k, (c, name) in enumerate(zip(res.cameras, _names(res), strict=True)):
        ax = fig.add_subplot(1, len(res.cameras), k + 1)
        px = np.concatenate(c.corners_px)
        r = np.concatenate(c.residuals)
        o = np.concatenate(c.outlier)
        w, h = c.camera.image_size
        s = (
            scale
            if scale is not None
            else 0.05 * w / max(float(np.percentile(np.linalg.norm(r, axis=1), 95)), 1e-6)
        )
        ax.quiver(
            px[~o, 0],
            px[~o, 1],
            s * r[~o, 0],
            s * r[~o, 1],
            angles="xy",
            scale_units="xy",
            scale=1,
            width=0.002,
        )
        if o.any():
            ax.quiver(
                px[o, 0],
                px[o, 1],
                s * r[o, 0],
                s * r[o, 1],
                angles="xy",
                scale_units="xy",
                scale=1,
                width=0.003,
                color="red",
            )
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(
            f"{name}: residuals ×{s:.0f} (RMS {c.rms_px:.3f} px, {c.n_outliers} outliers red)",
            fontsize=9,
        )
    fig.tight_layout()
    return fig


def plot_coverage(res: CalibrationResult) -> Figure:
    """Where the board's corners fell, with the 10 × 6 coverage cells shaded."""
    fig = Figure(figsize=(6.5 * len(res.cameras), 4.5))
    for k, (c, name) in enumerate(zip(res.cameras, _names(res), strict=True)):
        ax = fig.add_subplot(1, len(res.cameras), k + 1)
        w, h = c.camera.image_size
        m = c.covered_cells()
        ax.imshow(m, extent=(0, w, h, 0), cmap="Greens", vmin=0, vmax=2, alpha=0.6, aspect="auto")
        for v in c.corners_px:
            ax.plot(v[:, 0], v[:, 1], ".", ms=2)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(
            f"{name}: corners of {len(c.views_used)} views, coverage {100 * c.coverage:.0f} %",
            fontsize=9,
        )
    fig.tight_layout()
    return fig


def plot_uncertainty(res: CalibrationResult) -> Figure:
    """Worst-direction projection standard deviation over the image (px, log colour scale)."""
    from matplotlib.colors import LogNorm

    fig = Figure(figsize=(6.5 * len(res.cameras), 4.5))
    for k, (c, name) in enumerate(zip(res.cameras, _names(res), strict=True)):
        ax = fig.add_subplot(1, len(res.cameras), k + 1)
        gx, gy = c.grid_px
        z = np.ma.masked_invalid(c.projection_std_px)
        lo = max(float(np.nanmin(c.projection_std_px)), 1e-3)
        hi = max(float(np.nanmax(c.projection_std_px)), lo * 10)
        pcm = ax.pcolormesh(gx, gy, z, norm=LogNorm(lo, hi), shading="auto", cmap="viridis")
        cs = ax.contour(
            gx, gy, z.filled(np.nan), levels=[0.1, 0.25, 0.5, 1, 2, 5], colors="w", linewidths=0.6
        )
        ax.clabel(cs, fontsize=7)
        fig.colorbar(pcm, ax=ax, label="px (1σ)")
        ax.set_ylim(gy[-1], gy[0])
        ax.set_aspect("equal")
        ax.set_title(f"{name}: projection uncertainty (grey: lens model folds)", fontsize=9)
    fig.tight_layout()
    return fig
