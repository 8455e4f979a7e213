"""One pose of the smart target from a stereo pair, with its covariance (the 7D measurement).

Markers are detected in both images, matched to the target description by id, their corners
sharpened (:func:`~quickhealth.vision.markers.refine_marker_corners`), and one pose
``T_left_target`` is solved that minimises the reprojection error in *both* cameras at once
(Gauss–Newton on 6 parameters; not two mono poses averaged).  The covariance is
``σ̂² (JᵀJ)⁻¹`` with σ̂ from the residuals.  Poses with too few or collinear corners, seen by
one camera only, or with a large residual are returned as :class:`Rejection` with the reason.

The pose parameters are ``T = [exp(ω)·R₀ | t₀ + δt]``: δt is the error of the target origin
in the instrument (left camera) frame, ω the orientation error in that frame; the 6×6
covariance is over (δt, ω) in (m, rad).

SYNOPSIS
    >>> result = measure_stereo(rig, target, img_left, img_right, pan=np.radians(30))
    >>> if isinstance(result, PoseMeasurement): row = result.row()
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.measurements import Measurements
from quickhealth.identify.transforms import R_to_rpy, exp_so3, log_so3, make_T

from .boards import TargetDescription
from .camera import CameraModel, StereoRig
from .markers import Box, detect_markers, refine_marker_corners

F = NDArray[np.float64]


class RejectReason(Enum):
    """Why a stereo pair gave no pose."""

    NOT_DETECTED = "not-detected"
    ONE_CAMERA = "one-camera"
    TOO_FEW_CORNERS = "too-few-corners"
    COLLINEAR = "collinear"
    LARGE_RESIDUAL = "large-residual"
    NO_CONVERGENCE = "no-convergence"


@dataclass(frozen=True)
class PoseSettings:
    """Acceptance rules of :func:`measure_stereo`.

    Attributes
    ----------
    min_corners : int
        Fewest matched corners per camera (planar PnP is ambiguous below ~10).
    min_spread : float
        Smallest ratio of the second to the first singular value of the used corners'
        target-plane positions (0 = all on one line).
    max_rms_px : float
        Largest accepted RMS reprojection error (per-corner norm), px.
    outlier_sigma : float
        Corners whose residual norm exceeds this many robust standard deviations (and
        0.5 px) are dropped once and the pose re-solved.
    """

    min_corners: int = 12
    min_spread: float = 0.15
    max_rms_px: float = 1.0
    outlier_sigma: float = 5.0


@dataclass(frozen=True, eq=False)
class PoseMeasurement:
    """A measured pose of the target frame in the instrument (left camera) frame.

    Attributes
    ----------
    T_left_target : ndarray, shape (4, 4), m
    cov : ndarray, shape (6, 6)
        Covariance of (δt [m], ω [rad]), see the module docstring.
    rms_px : float
        RMS reprojection error over both cameras (per-corner norm).
    n_corners : tuple of int
        Corners used in (left, right).
    n_outliers : int
        Corners dropped as outliers.
    pan : float or None
        Commanded pan angle, rad (travels with the measurement).
    time : float or None
        Time stamp given by the caller, s.
    """

    T_left_target: F
    cov: F
    rms_px: float
    n_corners: tuple[int, int]
    n_outliers: int = 0
    pan: float | None = None
    time: float | None = None

    @property
    def position(self) -> F:
        """Target origin in the instrument frame, m."""
        return self.T_left_target[:3, 3].copy()

    @property
    def rpy(self) -> F:
        """(pitch, yaw, roll), rad, with R = Rz(roll)·Ry(yaw)·Rx(pitch)."""
        return R_to_rpy(self.T_left_target[:3, :3])

    @property
    def sigma_pos(self) -> F:
        """Standard uncertainty of x, y, z, m."""
        return np.sqrt(np.diag(self.cov)[:3])

    @property
    def sigma_rpy(self) -> F:
        """Standard uncertainty of (pitch, yaw, roll), rad (covariance propagated)."""
        R0 = self.T_left_target[:3, :3]
        h = 1e-7
        J = np.empty((3, 3))
        for k in range(3):
            w = np.zeros(3)
            w[k] = h
            J[:, k] = (R_to_rpy(exp_so3(w) @ R0) - R_to_rpy(exp_so3(-w) @ R0)) / (2 * h)
        J[~np.isfinite(J)] = 0.0
        return np.sqrt(np.diag(J @ self.cov[3:, 3:] @ J.T))

    def row(self) -> dict[str, float]:
        """The CSV v1 values of this pose in SI (m, rad, s): x y z pitch yaw roll, sx sy sz
        spitch syaw sroll, and pan / time when known.  ``station/formats/measurements.py`` converts."""
        p, a, sp, sa = self.position, self.rpy, self.sigma_pos, self.sigma_rpy
        out = {
            "x": p[0], "y": p[1], "z": p[2], "pitch": a[0], "yaw": a[1], "roll": a[2],
            "sx": sp[0], "sy": sp[1], "sz": sp[2], "spitch": sa[0], "syaw": sa[1], "sroll": sa[2],
        }  # fmt: skip
        if self.pan is not None:
            out["pan"] = self.pan
        if self.time is not None:
            out["time"] = self.time
        return {k: float(v) for k, v in out.items()}


@dataclass(frozen=True)
class Rejection:
    """A stereo pair that gave no pose, and why."""

    reason: RejectReason
    detail: str
    n_corners: tuple[int, int] = (0, 0)
    pan: float | None = None
    time: float | None = None


def roi_from_pose(
    camera: CameraModel, T_cam_target: F, target: TargetDescription, *, margin: float = 0.25
) -> Box:
    """Search box around the target's predicted image, grown by ``margin`` of its size + 20 px."""
    (x0, y0), (x1, y1) = target.plate
    pl = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)
    p = pl @ T_cam_target[:3, :3].T + T_cam_target[:3, 3]
    if np.any(p[:, 2] <= 0):
        w, h = camera.image_size
        return (0, 0, w, h)
    px = camera.project(p)
    lo, hi = px.min(0), px.max(0)
    g = margin * (hi - lo) + 20.0
    return (int(lo[0] - g[0]), int(lo[1] - g[1]), int(hi[0] + g[0]) + 1, int(hi[1] + g[1]) + 1)


def search_boxes(rig: StereoRig, T_left_target: F, target: TargetDescription) -> tuple[Box, Box]:
    """The search boxes of both cameras around the target's predicted image (``T_left_target``).

    Detection in a box and in the whole image can differ for a marker at the edge of
    detectability (OpenCV's candidate stages see other neighbourhoods), so a measurement
    that is to be repeated from the stored images records its boxes and searches them again.
    """
    return (
        roi_from_pose(rig.left, T_left_target, target),
        roi_from_pose(rig.right, rig.T_right_left @ T_left_target, target),
    )


def detect_target(
    camera: CameraModel,
    target: TargetDescription,
    image: NDArray[np.uint8] | NDArray[np.uint16],
    roi: Box | None = None,
    *,
    bits: int | None = None,
) -> tuple[F, F]:
    """Target corners seen in one image: (object points (k, 3) m, pixels (k, 2)).

    Unknown ids are ignored; corners are refined by line fits in the ideal image, at the
    image's full depth (``bits`` significant bits of a uint16 image).
    """
    det = detect_markers(image, target.dictionary, roi=roi, bits=bits)
    pos = {int(i): k for k, i in enumerate(target.ids)}
    keep = [k for k, i in enumerate(det.ids) if int(i) in pos]
    if not keep:
        return np.zeros((0, 3)), np.zeros((0, 2))
    ids = det.ids[keep]
    corners = det.corners[keep]
    f = camera.fx

    def to_ideal(p: F) -> F:
        return camera.pixel_to_ray(p) * f

    def from_ideal(x: F) -> F:
        return camera.project(np.concatenate([x / f, np.ones((*x.shape[:-1], 1))], -1))

    refined = refine_marker_corners(
        image, corners, bits=bits, to_ideal=to_ideal, from_ideal=from_ideal
    )
    obj = target.corners[[pos[int(i)] for i in ids]].reshape(-1, 3)
    return obj, refined.reshape(-1, 2)


def measure_stereo(
    rig: StereoRig,
    target: TargetDescription,
    img_left: NDArray[np.uint8] | NDArray[np.uint16],
    img_right: NDArray[np.uint8] | NDArray[np.uint16],
    *,
    bits: int | None = None,
    roi_hint: F | tuple[Box, Box] | None = None,
    pan: float | None = None,
    time: float | None = None,
    settings: PoseSettings = PoseSettings(),
) -> PoseMeasurement | Rejection:
    """Measure the target pose from a stereo pair.

    Parameters
    ----------
    rig : StereoRig
    target : TargetDescription
    img_left, img_right : ndarray, shape (h, w), uint8 or uint16
        A 10- to 16-bit camera's images are measured at their depth (``bits``: significant
        bits of uint16 images, LSB-aligned; default 16).
    bits : int, optional
    roi_hint : ndarray (4, 4) or ((x0, y0, x1, y1), (x0, y0, x1, y1)), optional
        Predicted ``T_left_target`` (the search regions are grown around its image) or the
        search boxes themselves; None searches the whole images.  A camera whose region
        yields too few corners is searched again over its whole image.
    pan : float, optional
        Commanded pan angle, rad, carried into the result.
    time : float, optional
        Time stamp, s, carried into the result.
    settings : PoseSettings

    Returns
    -------
    PoseMeasurement or Rejection
    """
    rois: tuple[Box | None, Box | None] = (None, None)
    if roi_hint is not None:
        if isinstance(roi_hint, np.ndarray) and roi_hint.shape == (4, 4):
            rois = search_boxes(rig, roi_hint, target)
        else:
            rois = (tuple(roi_hint[0]), tuple(roi_hint[1]))  # type: ignore[assignment,index]
    seen = []
    for cam, img, roi in zip(rig.cameras, (img_left, img_right), rois, strict=True):
        found = detect_target(cam, target, img, roi, bits=bits)
        if roi is not None and len(found[0]) < settings.min_corners:
            found = detect_target(cam, target, img, None, bits=bits)  # the prediction was off
        seen.append(found)
    return solve_stereo_pose(rig, seen, pan=pan, time=time, settings=settings)


def solve_stereo_pose(
    rig: StereoRig,
    seen: Sequence[tuple[F, F]],
    *,
    pan: float | None = None,
    time: float | None = None,
    settings: PoseSettings = PoseSettings(),
) -> PoseMeasurement | Rejection:
    """Pose from matched corners in both cameras: ``seen[i] = (obj (k, 3) m, px (k, 2))``."""
    n = (len(seen[0][0]), len(seen[1][0]))

    def reject(reason: RejectReason, detail: str, nn: tuple[int, int] = n) -> Rejection:
        return Rejection(reason, detail, nn, pan, time)

    if n == (0, 0):
        return reject(RejectReason.NOT_DETECTED, "no target marker found in either image")
    if min(n) == 0:
        side = "left" if n[0] == 0 else "right"
        return reject(RejectReason.ONE_CAMERA, f"target not found in the {side} image")
    if min(n) < settings.min_corners:
        return reject(
            RejectReason.TOO_FEW_CORNERS,
            f"{n[0]} left / {n[1]} right corners, need {settings.min_corners} in each",
        )
    for i in range(2):
        P = seen[i][0][:, :2] - seen[i][0][:, :2].mean(0)
        sv = np.linalg.svd(P, compute_uv=False)
        if sv[1] < settings.min_spread * sv[0]:
            side = ("left", "right")[i]
            return reject(
                RejectReason.COLLINEAR,
                f"corners in the {side} image nearly collinear (spread {sv[1] / sv[0]:.3f})",
            )
    # initial pose: PnP in the camera with more corners
    i0 = int(np.argmax(n))
    cam = rig.cameras[i0]
    ok, rvec, tvec = cv2.solvePnP(
        seen[i0][0], seen[i0][1], cam.K, cam.dist, flags=cv2.SOLVEPNP_SQPNP
    )
    if not ok:
        return reject(RejectReason.NO_CONVERGENCE, "initial PnP failed")
    rvec, tvec = cv2.solvePnPRefineLM(seen[i0][0], seen[i0][1], cam.K, cam.dist, rvec, tvec)
    T_cam_target = make_T(cv2.Rodrigues(rvec)[0], tvec.ravel())
    T0 = rig.T_left_right @ T_cam_target if i0 == 1 else T_cam_target
    obj = [s[0] for s in seen]
    px = [s[1] for s in seen]
    T, r, J, conv = _gauss_newton(rig, T0, obj, px)
    n_out = 0
    rn = np.linalg.norm(r.reshape(-1, 2), axis=1)
    med = np.median(rn)
    sig = 1.4826 * np.median(np.abs(rn - med)) + 1e-9
    bad = rn > max(med + settings.outlier_sigma * sig, 0.5)
    if np.any(bad):
        n_out = int(bad.sum())
        keep = ~bad
        k0 = n[0]
        obj = [obj[0][keep[:k0]], obj[1][keep[k0:]]]
        px = [px[0][keep[:k0]], px[1][keep[k0:]]]
        n = (len(obj[0]), len(obj[1]))
        if min(n) < settings.min_corners:
            return reject(
                RejectReason.TOO_FEW_CORNERS, f"{n_out} outlier corners left {n[0]} / {n[1]}", n
            )
        T, r, J, conv = _gauss_newton(rig, T, obj, px)
    if not conv:
        return reject(RejectReason.NO_CONVERGENCE, "stereo pose did not converge in 20 iterations")
    rms = float(np.sqrt((r**2).sum() / (r.size / 2)))
    if rms > settings.max_rms_px:
        return reject(
            RejectReason.LARGE_RESIDUAL,
            f"RMS reprojection error {rms:.2f} px > {settings.max_rms_px} px",
        )
    dof = max(r.size - 6, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.inv(J.T @ J)
    return PoseMeasurement(T, cov, rms, n, n_out, pan, time)


def _residuals(rig: StereoRig, T: F, obj: Sequence[F], px: Sequence[F]) -> F:
    out = []
    for i, cam in enumerate(rig.cameras):
        Tc = T if i == 0 else rig.T_right_left @ T
        p = obj[i] @ Tc[:3, :3].T + Tc[:3, 3]
        out.append((cam.project(p) - px[i]).ravel())
    return np.concatenate(out)


def _perturb(T: F, x: F) -> F:
    return make_T(exp_so3(x[3:]) @ T[:3, :3], T[:3, 3] + x[:3])


def _jacobian(rig: StereoRig, T: F, obj: Sequence[F], px: Sequence[F], r0: F) -> F:
    J = np.empty((r0.size, 6))
    for k in range(6):
        h = 1e-7
        e = np.zeros(6)
        e[k] = h
        J[:, k] = (
            _residuals(rig, _perturb(T, e), obj, px) - _residuals(rig, _perturb(T, -e), obj, px)
        ) / (2 * h)
    return J


def _gauss_newton(
    rig: StereoRig, T: F, obj: Sequence[F], px: Sequence[F], max_iter: int = 20
) -> tuple[F, F, F, bool]:
    r = _residuals(rig, T, obj, px)
    J = _jacobian(rig, T, obj, px, r)
    for _ in range(max_iter):
        dx = np.linalg.lstsq(J, -r, rcond=None)[0]
        T = _perturb(T, dx)
        r = _residuals(rig, T, obj, px)
        J = _jacobian(rig, T, obj, px, r)
        if np.linalg.norm(dx[:3]) < 1e-10 and np.linalg.norm(dx[3:]) < 1e-10:
            return T, r, J, True
    return T, r, J, False


def pose_crb(rig: StereoRig, target: TargetDescription, T_left_target: F, sigma_px: float) -> F:
    """Cramér–Rao bound on the covariance of (δt, ω) for a target pose seen by both cameras
    with independent Gaussian corner noise ``sigma_px`` (px, per coordinate) on every corner
    that projects inside each image and faces the camera.  Shape (6, 6)."""
    obj, px = [], []
    for i, cam in enumerate(rig.cameras):
        Tc = T_left_target if i == 0 else rig.T_right_left @ T_left_target
        p = target.corners.reshape(-1, 3) @ Tc[:3, :3].T + Tc[:3, 3]
        q = cam.project(p)
        w, h = cam.image_size
        vis = (p[:, 2] > 0) & (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        obj.append(target.corners.reshape(-1, 3)[vis])
        px.append(q[vis])
    r0 = _residuals(rig, T_left_target, obj, px)
    J = _jacobian(rig, T_left_target, obj, px, r0)
    return sigma_px**2 * np.linalg.inv(J.T @ J)


def pose_error(T_est: F, T_true: F) -> tuple[F, F]:
    """(position error (3,) m, orientation error vector (3,) rad) in the instrument frame."""
    return T_est[:3, 3] - T_true[:3, 3], log_so3(T_est[:3, :3] @ T_true[:3, :3].T)


def rows_si(results: Sequence[PoseMeasurement]) -> dict[str, F]:
    """Column arrays (SI) of :meth:`PoseMeasurement.row` for a list of accepted poses."""
    rows = [p.row() for p in results]
    keys = list(rows[0]) if rows else []
    return {k: np.array([r.get(k, np.nan) for r in rows]) for k in keys}


def to_measurements(
    q: F,
    results: Sequence[PoseMeasurement],
    *,
    temp: F | None = None,
    pose_id: Sequence[str] | None = None,
    meta: dict[str, str] | None = None,
) -> Measurements:
    """Accepted poses with their joint readings ``q`` (n, nj) rad as :class:`Measurements`."""
    if len(results) != len(q):
        raise ValueError("one joint reading per pose measurement")
    cols = rows_si(results)
    pan = cols.get("pan")
    time = cols.get("time")
    return Measurements(
        q=np.asarray(q, dtype=float),
        pos=np.stack([cols["x"], cols["y"], cols["z"]], -1),
        rpy=np.stack([cols["pitch"], cols["yaw"], cols["roll"]], -1),
        time=None if time is None or np.any(np.isnan(time)) else time,
        temp=temp,
        pan=None if pan is None or np.any(np.isnan(pan)) else pan,
        sigma_pos=np.stack([cols["sx"], cols["sy"], cols["sz"]], -1),
        sigma_rpy=np.stack([cols["spitch"], cols["syaw"], cols["sroll"]], -1),
        pose_id=None if pose_id is None else tuple(pose_id),
        meta=dict(meta or {}),
    )
