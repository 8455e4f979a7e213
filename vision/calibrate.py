"""Camera calibration, mono or stereo, with mrcal-style evidence that the result can be trusted.

Pipeline: :func:`detect_board` per image → :func:`calibrate` (mono fits with outlier rejection
→ intrinsics covariance → projection uncertainty and coverage → stereo fit → verdict).

Outlier rule (stated, as mrcal does): with σ̂ = median(corner error norm) / 1.1774 (the
median of a Rayleigh distribution), a corner is an outlier when its reprojection error norm
exceeds ``max(5 σ̂, 0.1 px)`` (4 in a million false rejections for Gaussian noise); a view is
dropped when more than half of its corners are outliers or fewer than ``min_corners`` remain.
The fit is repeated until nothing changes (at most 5 rounds).

Uncertainty: the full covariance of the 9 intrinsics (fx fy cx cy k1 k2 p1 p2 k3) comes from
``σ̂² (JᵀJ)⁻¹`` over the whole problem (intrinsics + 6 per view), so the correlation with the
board poses is accounted for (its diagonal equals OpenCV's ``stdDeviationsIntrinsics``).
Projection uncertainty is the worst-direction standard deviation of projecting a direction
(a point at infinity) held fixed in the boards' reference frame, mapped over the image; the
reference frame's rotation follows the least-squares rigid fit of every observed board
point's displacement, as mrcal aligns the perturbed frame, so a principal-point shift that
the board poses absorb by turning is not counted.  Like mrcal's, it measures sampling error
from corner noise, not a wrong lens model.

SYNOPSIS
    >>> views = [detect_board(board, img) for img in images]
    >>> result = calibrate(board, views, image_size)
    >>> result.verdict, result.reasons
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.transforms import log_so3, skew

from .boards import BoardKind, BoardSpec
from .camera import CameraModel

F = NDArray[np.float64]
I64 = NDArray[np.int64]

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


class Verdict(Enum):
    """Whether a calibration can be trusted."""

    OK = "ok"
    UNRELIABLE = "unreliable"


@dataclass(frozen=True)
class CalibrationSettings:
    """Rules of the fit and of the verdict.

    Attributes
    ----------
    outlier_sigma : float
        Corner outlier threshold in robust standard deviations (see module docstring).
    min_corners : int
        Fewest corners for a view to be used.
    min_views : int
        Fewest usable views for an "ok" verdict.
    min_coverage : float
        Smallest fraction of the image's 10 × 6 cells that must hold a corner.
    max_rel_focal_std : float
        Largest relative standard deviation of fx and fy.
    max_center_std_px : float
        Largest standard deviation of cx, cy, px.
    max_projection_std_px : float
        Largest worst-direction projection standard deviation, px, over the image cells
        the board covered ("unreliable" above it; a warning above ``warn_projection_std_px``).
    max_rms_px : float
        Largest RMS reprojection error, px (higher: wrong board spec or lens model).
    max_stereo_ratio : float
        Largest ratio of the stereo RMS to the mono RMS (pairs that disagree).
    """

    outlier_sigma: float = 5.0
    min_corners: int = 8
    min_views: int = 8
    min_coverage: float = 0.5
    max_rel_focal_std: float = 0.005
    max_center_std_px: float = 5.0
    max_projection_std_px: float = 5.0
    warn_projection_std_px: float = 1.0
    max_rms_px: float = 1.5
    max_stereo_ratio: float = 2.0


@dataclass(frozen=True, eq=False)
class BoardView:
    """Corners of a board found in one image: ids, board-frame points (m) and pixels."""

    ids: I64
    obj: F
    px: F


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One camera's calibration with its evidence.

    Attributes
    ----------
    camera : CameraModel
    cov : ndarray, shape (9, 9)
        Covariance of (fx fy cx cy k1 k2 p1 p2 k3).
    rms_px : float
        RMS of the per-corner error norm over the used corners (OpenCV's convention).
    view_rms_px : ndarray, shape (n_images,)
        Per-view RMS (NaN for views not used).
    residuals : tuple of ndarray
        Per used view, (k, 2) px: observed minus projected, outliers included.
    corners_px : tuple of ndarray
        Per used view, (k, 2) px: the observed corners.
    outlier : tuple of ndarray
        Per used view, (k,) bool.
    views_used : tuple of int
        Image indices used.
    views_rejected : tuple of (int, str)
        Image index and reason.
    rvecs, tvecs : ndarray, shape (n_used, 3)
        Board poses (OpenCV rotation vectors; m).
    coverage : float
        Fraction of the image's 10 × 6 cells holding a used corner.
    projection_std_px : ndarray, shape (ny, nx)
        Worst-direction projection standard deviation on a grid over the image.
    grid_px : tuple of ndarray
        The grid's x (nx,) and y (ny,) pixel positions.
    """

    camera: CameraModel
    cov: F
    rms_px: float
    view_rms_px: F
    residuals: tuple[F, ...]
    corners_px: tuple[F, ...]
    outlier: tuple[NDArray[np.bool_], ...]
    views_used: tuple[int, ...]
    views_rejected: tuple[tuple[int, str], ...]
    rvecs: F
    tvecs: F
    coverage: float
    projection_std_px: F
    grid_px: tuple[F, F]

    @property
    def std(self) -> F:
        """Standard deviations of (fx fy cx cy k1 k2 p1 p2 k3)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def n_outliers(self) -> int:
        """Number of outlier corners in the used views."""
        return int(sum(int(o.sum()) for o in self.outlier))

    @property
    def n_corners(self) -> int:
        """Number of corners in the used views."""
        return int(sum(len(o) for o in self.outlier))

    def covered_cells(self, nx: int = 10, ny: int = 6) -> NDArray[np.bool_]:
        """(ny, nx) mask of the image cells that hold at least one used corner."""
        px = np.concatenate([c[~o] for c, o in zip(self.corners_px, self.outlier, strict=True)])
        w, h = self.camera.image_size
        ix = np.clip((px[:, 0] / w * nx).astype(int), 0, nx - 1)
        iy = np.clip((px[:, 1] / h * ny).astype(int), 0, ny - 1)
        m = np.zeros((ny, nx), bool)
        m[iy, ix] = True
        return m

    def covered_projection_std_px(self) -> float:
        """Largest projection std-dev over the image cells the board covered (where the
        calibration has data and will be used)."""
        gx, gy = self.grid_px
        w, h = self.camera.image_size
        m = self.covered_cells()
        ny, nx = m.shape
        ix = np.clip((gx / w * nx).astype(int), 0, nx - 1)
        iy = np.clip((gy / h * ny).astype(int), 0, ny - 1)
        v = self.projection_std_px[m[iy][:, ix]]
        return float(np.nanmax(v)) if np.any(np.isfinite(v)) else float("inf")


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """A mono or stereo calibration, its evidence and its verdict.

    Attributes
    ----------
    cameras : tuple of CameraCalibration
        Left (and right); for stereo, the intrinsics after the joint stereo refinement.
    R, T : ndarray or None
        Stereo only: rotation (3, 3) and translation (3,) m mapping left-camera points into
        the right camera (OpenCV's convention, ``x_right = R x_left + T``).
    rms_px : float
        Final RMS (mono: the camera's; stereo: the joint stereo fit's).
    stereo_rms_px : float or None
    pairs_used : tuple of int
        Stereo: pair indices used in the joint fit.
    verdict : Verdict
    reasons : tuple of str
    """

    cameras: tuple[CameraCalibration, ...]
    R: F | None
    T: F | None
    rms_px: float
    stereo_rms_px: float | None
    pairs_used: tuple[int, ...]
    n_images: int
    verdict: Verdict
    reasons: tuple[str, ...] = field(default_factory=tuple)
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def is_stereo(self) -> bool:
        """True for a stereo calibration."""
        return self.R is not None

    @property
    def mono_rms_px(self) -> float:
        """RMS of the mono fits (pooled over the cameras)."""
        n = np.array([c.n_corners for c in self.cameras], dtype=float)
        r = np.array([c.rms_px for c in self.cameras])
        return float(np.sqrt((n * r**2).sum() / n.sum()))

    def T_left_right(self) -> F:
        """Stereo: maps right-camera points into the left frame (m)."""
        if self.R is None or self.T is None:
            raise ValueError("a mono calibration has no stereo transform")
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = -self.R.T @ self.T
        return T

    def summary(self) -> list[str]:
        """Lines for the command line and the report."""
        out = []
        for i, c in enumerate(self.cameras):
            name = ("left", "right")[i] if self.is_stereo else "camera"
            s = c.std
            out.append(
                f"{name}: fx {c.camera.fx:.2f}±{s[0]:.2f} fy {c.camera.fy:.2f}±{s[1]:.2f} "
                f"cx {c.camera.cx:.2f}±{s[2]:.2f} cy {c.camera.cy:.2f}±{s[3]:.2f} px; "
                f"RMS {c.rms_px:.3f} px over {len(c.views_used)} views, outliers "
                f"{c.n_outliers}/{c.n_corners} ({100 * c.n_outliers / max(c.n_corners, 1):.1f} %), "
                f"coverage {100 * c.coverage:.0f} %, projection σ ≤ {c.covered_projection_std_px():.3f} px "
                f"(covered cells), {np.nanmax(c.projection_std_px):.3f} px (whole image)"
            )
        if self.is_stereo and self.T is not None:
            out.append(
                f"stereo: baseline {1000 * np.linalg.norm(self.T):.2f} mm, RMS {self.stereo_rms_px:.3f} px "
                f"({self.stereo_rms_px / max(self.mono_rms_px, 1e-12):.2f}× mono) over {len(self.pairs_used)} pairs"
            )
        out.append(f"verdict: {self.verdict.value}" + "".join(f"\n  - {r}" for r in self.reasons))
        out += [f"warning: {w}" for w in self.warnings]
        return out

    def to_dict(self) -> dict[str, Any]:
        """CAL.json content (CONTRACTS.md; lengths in mm)."""
        cams = []
        for c in self.cameras:
            cams.append({
                "K": c.camera.K.tolist(),
                "dist": c.camera.dist.tolist(),
                "image_size": list(c.camera.image_size),
                "rms_px": c.rms_px,
                "std": dict(zip(INTRINSIC_NAMES, c.std.tolist(), strict=True)),
                "cov": c.cov.tolist(),
                "views_used": list(c.views_used),
                "views_rejected": [{"view": i, "reason": r} for i, r in c.views_rejected],
                "view_rms_px": [None if not np.isfinite(v) else float(v) for v in c.view_rms_px],
                "n_corners": c.n_corners,
                "n_outliers": c.n_outliers,
                "coverage": c.coverage,
                "projection_std_px_max": float(np.nanmax(c.projection_std_px)),
                "projection_std_px_valid_fraction": float(np.isfinite(c.projection_std_px).mean()),
                "projection_std_px_covered": c.covered_projection_std_px(),
            })  # fmt: skip
        used = self.pairs_used if self.is_stereo else self.cameras[0].views_used
        rejected = sorted(set(range(self.n_images)) - set(used))
        reasons_by_view: dict[int, str] = {}
        for c in self.cameras:
            for i, r in c.views_rejected:
                reasons_by_view.setdefault(i, r)
        d: dict[str, Any] = {
            "format": "quickhealth-calibration",
            "version": 1,
            "rms_px": self.rms_px,
            "cameras": cams,
            "views_used": list(used),
            "views_rejected": [
                {"view": i, "reason": reasons_by_view.get(i, "no corners shared by both images")}
                for i in rejected
            ],
            "verdict": self.verdict.value,
            "reasons": list(self.reasons),
            "warnings": list(self.warnings),
            "outlier_rule": "corner error norm > max(5·median/1.1774, 0.1 px); view dropped if > 50 % outliers",
        }
        if self.is_stereo and self.R is not None and self.T is not None:
            d["R"] = self.R.tolist()
            d["T"] = (1000 * self.T).tolist()
            d["baseline_mm"] = float(1000 * np.linalg.norm(self.T))
            d["stereo_rms_px"] = self.stereo_rms_px
            d["mono_rms_px"] = self.mono_rms_px
        return d


def detect_board(board: BoardSpec, image: NDArray[np.uint8]) -> BoardView | None:
    """Find the board's corners in a grey image; None when it is not found.

    Chessboard: ``findChessboardCornersSB`` (whole board or nothing) then ``cornerSubPix`` with
    a window inside one square, order made canonical so
    that corner 0 is the one nearer the image's top-left.  ChArUco: ``CharucoDetector``,
    corners paired with the board through their ids.
    """
    if board.kind is BoardKind.CHESSBOARD:
        flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, c = cv2.findChessboardCornersSB(image, (board.cols, board.rows), flags=flags)
        if not ok or c is None:
            return None
        # the SB detector leaves ≈ 0.2 px errors with a scale bias of ≈ 0.2 % on small
        # squares; a cornerSubPix pass with its window inside one square removes both
        g = c.reshape(board.rows, board.cols, 2)
        spacing = min(
            float(np.linalg.norm(np.diff(g, axis=1), axis=-1).min()),
            float(np.linalg.norm(np.diff(g, axis=0), axis=-1).min()),
        )
        half = int(np.clip(0.4 * spacing, 2, 11))
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        c = cv2.cornerSubPix(
            image, c.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), crit
        )
        px = c.reshape(-1, 2).astype(float)
        if px[0].sum() > px[-1].sum():
            px = px[::-1].copy()
        ids = np.arange(board.n_corners)
        return BoardView(ids, board.object_points(), px)
    cb = board.cv_board()
    params = cv2.aruco.DetectorParameters()
    params.minMarkerPerimeterRate = 0.01
    det = cv2.aruco.CharucoDetector(cb, cv2.aruco.CharucoParameters(), params)
    cc, ci, _, _ = det.detectBoard(image)
    if ci is None or len(ci) < 4:
        return None
    ids = np.asarray(ci, dtype=np.int64).ravel()
    obj = board.object_points()[ids]
    return BoardView(ids, obj, np.asarray(cc, dtype=float).reshape(-1, 2))


def calibrate(
    board: BoardSpec,
    left: Sequence[BoardView | None],
    image_size: tuple[int, int],
    right: Sequence[BoardView | None] | None = None,
    *,
    settings: CalibrationSettings = CalibrationSettings(),
) -> CalibrationResult:
    """Calibrate one camera, or a stereo pair from views paired by index.

    Parameters
    ----------
    board : BoardSpec
    left : sequence of BoardView or None
        Corners per image (None: board not found).
    image_size : (width, height)
        Of every image (both cameras of a pair must match it).
    right : sequence of BoardView or None, optional
        The right camera's views, same length as ``left``.
    settings : CalibrationSettings

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ValueError
        Fewer than 3 usable views, or left/right counts differ.
    """
    if right is not None and len(right) != len(left):
        raise ValueError(f"{len(left)} left views but {len(right)} right views")
    cams = []
    for name, views in (("left", left), ("right", right)):
        if views is None:
            continue
        try:
            cams.append(_calibrate_mono(board, views, image_size, settings))
        except ValueError as exc:
            who = f"{name} camera: " if right is not None else ""
            raise ValueError(f"{who}{exc}") from None
    reasons: list[str] = []
    R = T = None
    stereo_rms = None
    pairs: tuple[int, ...] = ()
    if right is not None:
        R, T, stereo_rms, pairs, cams = _calibrate_stereo(
            board, left, right, image_size, cams, settings
        )
    n_img = len(left)
    for i, c in enumerate(cams):
        who = ("left camera: " if i == 0 else "right camera: ") if right is not None else ""
        reasons += [who + r for r in _camera_reasons(c, settings)]
    rms = stereo_rms if stereo_rms is not None else cams[0].rms_px
    res = CalibrationResult(tuple(cams), R, T, float(rms), stereo_rms, pairs, n_img, Verdict.OK, ())
    if right is not None and stereo_rms is not None:
        ratio = stereo_rms / max(res.mono_rms_px, 1e-12)
        if ratio > settings.max_stereo_ratio:
            reasons.append(
                f"the stereo fit's RMS ({stereo_rms:.3f} px) is {ratio:.1f}× the mono fits' "
                f"({res.mono_rms_px:.3f} px), above {settings.max_stereo_ratio}×: the pairs are "
                "inconsistent (not simultaneous, moved cameras, or unobservable intrinsics)"
            )
        if len(pairs) < settings.min_views:
            reasons.append(
                f"only {len(pairs)} pairs show the board in both images; need ≥ {settings.min_views}"
            )
    warnings: list[str] = []
    for i, c in enumerate(cams):
        who = ("left camera: " if i == 0 else "right camera: ") if right is not None else ""
        cp = c.covered_projection_std_px()
        if settings.warn_projection_std_px < cp <= settings.max_projection_std_px:
            warnings.append(
                f"{who}projection uncertainty reaches {cp:.2f} px (1σ) where the board was seen"
            )
        if c.coverage < 0.8:
            warnings.append(
                f"{who}no data in {100 * (1 - c.coverage):.0f} % of the image; projection uncertainty there "
                f"reaches {np.nanmax(c.projection_std_px):.1f} px: avoid those regions or add views"
            )
    verdict = Verdict.UNRELIABLE if reasons else Verdict.OK
    return CalibrationResult(
        tuple(cams),
        R,
        T,
        float(rms),
        stereo_rms,
        pairs,
        n_img,
        verdict,
        tuple(reasons),
        tuple(warnings),
    )


def _camera_reasons(c: CameraCalibration, s: CalibrationSettings) -> list[str]:
    out = []
    if len(c.views_used) < s.min_views:
        out.append(f"only {len(c.views_used)} usable views; need ≥ {s.min_views}")
    if c.coverage < s.min_coverage:
        out.append(
            f"the board covers too little of the image: corners fall in {100 * c.coverage:.0f} % of "
            f"the image's 10×6 cells (need ≥ {100 * s.min_coverage:.0f} %); move it into the corners and edges"
        )
    std = c.std
    rel = max(std[0] / c.camera.fx, std[1] / c.camera.fy)
    if rel > s.max_rel_focal_std:
        out.append(
            f"focal length poorly determined: σ(fx)/fx = {100 * std[0] / c.camera.fx:.2f} %, σ(fy)/fy = {100 * std[1] / c.camera.fy:.2f} % (limit {100 * s.max_rel_focal_std:.2f} %)"
        )
    if max(std[2], std[3]) > s.max_center_std_px:
        out.append(
            f"principal point poorly determined: σ(cx) = {std[2]:.1f} px, σ(cy) = {std[3]:.1f} px (limit {s.max_center_std_px} px)"
        )
    cp = c.covered_projection_std_px()
    if cp > s.max_projection_std_px:
        out.append(
            f"large projection uncertainty: up to {cp:.2f} px (1σ, worst direction) where the board was seen (limit {s.max_projection_std_px} px)"
        )
    if c.rms_px > s.max_rms_px:
        out.append(
            f"RMS reprojection error {c.rms_px:.2f} px exceeds {s.max_rms_px} px: wrong board size or lens model?"
        )
    return out


def _views_to_cv(
    views: Sequence[BoardView],
) -> tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]]:
    return (
        [v.obj.astype(np.float32).reshape(-1, 1, 3) for v in views],
        [v.px.astype(np.float32).reshape(-1, 1, 2) for v in views],
    )


def _calibrate_mono(
    board: BoardSpec,
    views: Sequence[BoardView | None],
    size: tuple[int, int],
    s: CalibrationSettings,
) -> CameraCalibration:
    rejected: dict[int, str] = {}
    masks: dict[int, NDArray[np.bool_]] = {}
    for i, v in enumerate(views):
        if v is None:
            rejected[i] = "board not found"
        elif len(v.ids) < s.min_corners:
            rejected[i] = f"only {len(v.ids)} corners (need {s.min_corners})"
        elif board.kind is BoardKind.CHARUCO and _collinear(v.obj):
            rejected[i] = "corners collinear"
        else:
            masks[i] = np.ones(len(v.ids), bool)
    K = dist = None
    rounds = 5
    for rnd in range(rounds + 1):
        used = sorted(masks)
        if len(used) < 3:
            raise ValueError(f"only {len(used)} images show the board usably; need at least 3")
        vv = [
            BoardView(views[i].ids[masks[i]], views[i].obj[masks[i]], views[i].px[masks[i]])  # type: ignore[union-attr]
            for i in used
        ]
        obj, img = _views_to_cv(vv)
        flags = 0 if K is None else cv2.CALIB_USE_INTRINSIC_GUESS
        _, K, dist, rv, tv = cv2.calibrateCamera(obj, img, size, K, dist, flags=flags)[:5]
        # residuals over all corners of the used views (outliers included)
        res_all = []
        for k, i in enumerate(used):
            v = views[i]
            assert v is not None
            proj, _ = cv2.projectPoints(v.obj.astype(np.float64), rv[k], tv[k], K, dist)
            res_all.append(v.px - proj.reshape(-1, 2))
        if rnd == rounds:
            break  # last fit: keep the masks it was made with
        norms = np.concatenate(
            [np.linalg.norm(r, axis=1)[masks[i]] for r, i in zip(res_all, used, strict=True)]
        )
        thr = max(s.outlier_sigma * float(np.median(norms)) / 1.1774, 0.1)
        changed = False
        for r, i in zip(res_all, used, strict=True):
            m = np.linalg.norm(r, axis=1) <= thr
            if (~m).mean() > 0.5 or m.sum() < s.min_corners:
                rejected[i] = f"{int((~m).sum())} of {len(m)} corners are outliers (> {thr:.2f} px)"
                del masks[i]
                changed = True
            elif not np.array_equal(m, masks[i]):
                masks[i] = m
                changed = True
        if not changed:
            break
    # rv, tv and res_all belong to `used` and `masks` (the last fit changed nothing)
    cam = CameraModel(K, np.asarray(dist).ravel()[:5], size)
    rvecs = np.array([np.asarray(r).ravel() for r in rv])
    tvecs = np.array([np.asarray(t).ravel() for t in tv])
    view_rms = np.full(len(views), np.nan)
    residuals, corners, outl = [], [], []
    for k, i in enumerate(used):
        v = views[i]
        assert v is not None
        r = res_all[k]
        view_rms[i] = float(np.sqrt((r[masks[i]] ** 2).sum(1).mean()))
        residuals.append(r)
        corners.append(v.px)
        outl.append(~masks[i])
    inl = np.concatenate([r[~o] for r, o in zip(residuals, outl, strict=True)])
    rms = float(np.sqrt((inl**2).sum(1).mean()))
    cov12 = intrinsics_cov(cam, [views[i] for i in used], [masks[i] for i in used], rvecs, tvecs)  # type: ignore[misc]
    cov = cov12[:9, :9]
    gx = np.linspace(0, size[0] - 1, 32)
    gy = np.linspace(0, size[1] - 1, 24)
    pstd = projection_std(cam, cov12, gx, gy)
    cov_frac = _coverage(np.concatenate([c[~o] for c, o in zip(corners, outl, strict=True)]), size)
    return CameraCalibration(
        cam, cov, rms, view_rms, tuple(residuals), tuple(corners), tuple(outl), tuple(used),
        tuple(sorted(rejected.items())), rvecs, tvecs, cov_frac, pstd, (gx, gy),
    )  # fmt: skip


def _collinear(obj: F) -> bool:
    P = obj[:, :2] - obj[:, :2].mean(0)
    sv = np.linalg.svd(P, compute_uv=False)
    return bool(sv[1] < 0.1 * sv[0])


def _coverage(px: F, size: tuple[int, int], nx: int = 10, ny: int = 6) -> float:
    ix = np.clip((px[:, 0] / size[0] * nx).astype(int), 0, nx - 1)
    iy = np.clip((px[:, 1] / size[1] * ny).astype(int), 0, ny - 1)
    return float(np.unique(iy * nx + ix).size / (nx * ny))


def intrinsics_cov(
    cam: CameraModel,
    views: Sequence[BoardView],
    masks: Sequence[NDArray[np.bool_]],
    rvecs: F,
    tvecs: F,
) -> F:
    """Covariance (12×12) of the 9 intrinsics and the rotation δφ of the boards' reference
    frame (camera frame, rad): ``σ̂² G (JᵀJ)⁻¹ Gᵀ`` over the full problem (intrinsics + 6
    per view).  δφ is the rotation of the rigid motion that best fits (least squares) the
    displacement of every observed board point when the view poses change, as mrcal aligns
    the perturbed reference frame."""
    nv = len(views)
    npar = 9 + 6 * nv
    N = np.zeros((npar, npar))
    sse = 0.0
    n = 0
    M = np.zeros((6, 6))
    AB = np.zeros((6, npar))
    for k, (v, m, r, t) in enumerate(zip(views, masks, rvecs, tvecs, strict=True)):
        obj = v.obj[m].astype(np.float64)
        proj, jac = cv2.projectPoints(obj, r, t, cam.K, cam.dist)
        res = (v.px[m] - proj.reshape(-1, 2)).ravel()
        sse += float(res @ res)
        n += res.size
        J = np.zeros((res.size, npar))
        J[:, :9] = jac[:, 6:15]  # fx fy cx cy k1 k2 p1 p2 k3
        J[:, 9 + 6 * k : 15 + 6 * k] = jac[:, :6]  # rvec, tvec
        N += J.T @ J
        # rigid-fit bookkeeping: A = [-[p]x, I] maps (δφ, δτ) to a point's displacement,
        # B = [-[R P]x · Jl(r), I] maps this view's (δr, δt) to it
        R = cv2.Rodrigues(np.asarray(r, float))[0]
        RP = obj @ R.T
        p = RP + np.asarray(t, float).ravel()
        A = np.concatenate([-skew(p), np.broadcast_to(np.eye(3), (len(p), 3, 3))], -1)  # (k, 3, 6)
        Jl = _left_jacobian(np.asarray(r, float).ravel())
        B = np.concatenate([-skew(RP) @ Jl, np.broadcast_to(np.eye(3), (len(p), 3, 3))], -1)
        M += np.einsum("kia,kib->ab", A, A)
        AB[:, 9 + 6 * k : 15 + 6 * k] = np.einsum("kia,kib->ab", A, B)
    G = np.zeros((12, npar))
    G[:9, :9] = np.eye(9)
    G[9:] = np.linalg.solve(M, AB)[:3]
    dof = max(n - npar, 1)
    s2 = sse / dof
    return s2 * G @ np.linalg.pinv(N) @ G.T


def _left_jacobian(r: F) -> F:
    """d(log(R(r + δr) R(r)ᵀ))/dδr: camera-frame rotation per change of a rotation vector."""
    R0 = cv2.Rodrigues(r)[0]
    J = np.empty((3, 3))
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        Rp = cv2.Rodrigues(r + e)[0]
        Rm = cv2.Rodrigues(r - e)[0]
        J[:, k] = (log_so3(Rp @ R0.T) - log_so3(Rm @ R0.T)) / (2 * h)
    return J


def projection_std(cam: CameraModel, cov: F, gx: F, gy: F) -> F:
    """Worst-direction std-dev (px) of projecting the direction seen at each grid pixel.

    ``cov`` is 12×12 over (9 intrinsics, mean board rotation ω̄): the direction is held fixed
    in the boards' mean frame, as in mrcal, so a principal-point shift that the board poses
    absorb by turning is not counted as uncertainty.  A 9×9 ``cov`` holds the direction fixed
    in the camera frame instead.  Shape (len(gy), len(gx)); NaN where the lens model folds.
    """
    X, Y = np.meshgrid(gx, gy)
    xn = cam.pixel_to_ray(np.stack([X, Y], -1))
    p = np.concatenate([xn, np.ones((*xn.shape[:-1], 1))], -1)
    theta = np.array([cam.fx, cam.fy, cam.cx, cam.cy, *cam.dist])
    npar = cov.shape[0]
    J = np.empty((*X.shape, 2, npar))
    for k in range(9):
        h = 1e-6 * max(abs(theta[k]), 1.0)
        tp, tm = theta.copy(), theta.copy()
        tp[k] += h
        tm[k] -= h
        J[..., k] = (
            _cam_from(tp, cam.image_size).project(p) - _cam_from(tm, cam.image_size).project(p)
        ) / (2 * h)
    if npar == 12:
        h = 1e-7
        for k in range(3):
            w = np.zeros(3)
            w[k] = h
            # the point turns with the boards: p' = exp(ω) p ≈ p + ω × p
            J[..., 9 + k] = (cam.project(p + np.cross(w, p)) - cam.project(p - np.cross(w, p))) / (
                2 * h
            )
    C = J @ cov @ np.swapaxes(J, -1, -2)
    ev = np.linalg.eigvalsh(C)
    out = np.sqrt(np.clip(ev[..., -1], 0.0, None))
    # where the lens model folds over (non-monotonic radial distortion) the pixel has no
    # unique direction: leave it out (NaN)
    back = cam.project(p)
    bad = ~np.isfinite(back).all(-1) | (np.linalg.norm(back - np.stack([X, Y], -1), axis=-1) > 1e-3)
    out[bad] = np.nan
    return out


def _cam_from(theta: F, size: tuple[int, int]) -> CameraModel:
    K = np.array([[theta[0], 0.0, theta[2]], [0.0, theta[1], theta[3]], [0.0, 0.0, 1.0]])
    return CameraModel(K, theta[4:9], size)


def _calibrate_stereo(
    board: BoardSpec,
    left: Sequence[BoardView | None],
    right: Sequence[BoardView | None],
    size: tuple[int, int],
    cams: list[CameraCalibration],
    s: CalibrationSettings,
) -> tuple[F, F, float, tuple[int, ...], list[CameraCalibration]]:
    usedL, usedR = set(cams[0].views_used), set(cams[1].views_used)
    obj, pl, pr, pairs = [], [], [], []
    for i in sorted(usedL & usedR):
        vl, vr = left[i], right[i]
        assert vl is not None and vr is not None
        # leave out the corners either mono fit called outliers
        okl = ~cams[0].outlier[cams[0].views_used.index(i)]
        okr = ~cams[1].outlier[cams[1].views_used.index(i)]
        vl = BoardView(vl.ids[okl], vl.obj[okl], vl.px[okl])
        vr = BoardView(vr.ids[okr], vr.obj[okr], vr.px[okr])
        common, il, ir = np.intersect1d(vl.ids, vr.ids, return_indices=True)
        if len(common) < s.min_corners:
            continue
        obj.append(vl.obj[il].astype(np.float32).reshape(-1, 1, 3))
        pl.append(vl.px[il].astype(np.float32).reshape(-1, 1, 2))
        pr.append(vr.px[ir].astype(np.float32).reshape(-1, 1, 2))
        pairs.append(i)
    if len(pairs) < 3:
        raise ValueError(
            f"only {len(pairs)} image pairs show the board in both cameras; need at least 3"
        )
    cl, cr = cams[0].camera, cams[1].camera
    out = cv2.stereoCalibrate(
        obj, pl, pr, cl.K.copy(), cl.dist.copy(), cr.K.copy(), cr.dist.copy(), size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9),
    )  # fmt: skip
    rms, K1, d1, K2, d2, R, T = out[:7]
    from dataclasses import replace

    new = [
        replace(cams[0], camera=CameraModel(K1, np.asarray(d1).ravel()[:5], size)),
        replace(cams[1], camera=CameraModel(K2, np.asarray(d2).ravel()[:5], size)),
    ]
    return np.asarray(R, float), np.asarray(T, float).ravel(), float(rms), tuple(pairs), new
