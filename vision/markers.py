"""ArUco marker detection tuned for small markers far away (OpenCV 5 API).

OpenCV's defaults drop markers whose perimeter is under 3 % of the larger image side and
leave corner refinement off.  :func:`detector_parameters` lowers the size limit to an absolute
perimeter (default 24 px: the contour of a marker of ≈ 8 px side) whatever the image or region size, and turns
sub-pixel corner refinement on with a window that stays inside one marker cell.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .boards import aruco_dictionary

F = NDArray[np.float64]
I64 = NDArray[np.int64]
Box = tuple[int, int, int, int]


@dataclass(frozen=True, eq=False)
class MarkerDetection:
    """Markers found in one image.

    Attributes
    ----------
    ids : ndarray, shape (n,), int
    corners : ndarray, shape (n, 4, 2), px
        Full-image pixel coordinates, OpenCV corner order.
    roi : tuple of int or None
        The (x0, y0, x1, y1) region searched, None for the whole image.
    """

    ids: I64
    corners: F
    roi: Box | None = None


def detector_parameters(
    min_perimeter_px: float, search_size_px: int, *, cell_px: float | None = None
) -> cv2.aruco.DetectorParameters:
    """Detector parameters for markers down to ``min_perimeter_px`` in a search region whose
    larger side is ``search_size_px``; ``cell_px`` (expected marker cell size) sets the
    corner refinement window (half a cell, 2–6 px)."""
    p = cv2.aruco.DetectorParameters()
    p.minMarkerPerimeterRate = float(min_perimeter_px) / max(search_size_px, 1)
    p.maxMarkerPerimeterRate = 4.0
    p.adaptiveThreshWinSizeMin = 5
    p.adaptiveThreshWinSizeMax = 25
    p.adaptiveThreshWinSizeStep = 10
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    win = 4 if cell_px is None else int(np.clip(round(cell_px / 2.0), 2, 6))
    p.cornerRefinementWinSize = win
    p.relativeCornerRefinmentWinSize = 1.0  # let the absolute window above decide
    p.cornerRefinementMaxIterations = 50
    p.cornerRefinementMinAccuracy = 0.001
    return p


def full_scale(image: NDArray[np.uint8] | NDArray[np.uint16], bits: int | None = None) -> int:
    """The white level of a grey image: 255 for uint8, ``2**bits - 1`` for uint16 holding
    ``bits`` significant bits (LSB-aligned; default 16)."""
    if image.dtype == np.uint8:
        return 255
    if image.dtype != np.uint16:
        raise ValueError(f"expected a uint8 or uint16 grey image, got {image.dtype}")
    b = 16 if bits is None else int(bits)
    if not 9 <= b <= 16:
        raise ValueError(f"a uint16 image holds 9 to 16 bits, not {b}")
    return (1 << b) - 1


def to_8bit(
    image: NDArray[np.uint8] | NDArray[np.uint16], bits: int | None = None
) -> NDArray[np.uint8]:
    """The image rounded to 8 bits (ArUco's candidate search takes 8 bits only)."""
    full = full_scale(image, bits)
    if full == 255:
        return image  # type: ignore[return-value]
    return cv2.convertScaleAbs(image, alpha=255.0 / full)  # rounded and saturated


def detect_markers(
    image: NDArray[np.uint8] | NDArray[np.uint16],
    dictionary: str,
    *,
    roi: Box | None = None,
    min_perimeter_px: float = 24.0,
    cell_px: float | None = None,
    upscale: float | None = None,
    bits: int | None = None,
) -> MarkerDetection:
    """Detect ArUco markers of ``dictionary`` in a grey image, optionally only inside ``roi``.

    Markers under ≈ 13 px a side (bit cells of ≈ 2 px) are not even proposed as candidates by
    OpenCV's contour stage; upsampling the search region (cubic) makes them detectable again.

    Parameters
    ----------
    image : ndarray, shape (h, w), uint8, or uint16 holding ``bits`` significant bits
        (detected on its 8-bit rounding, :func:`to_8bit`: only the search region is converted)
    dictionary : str
        OpenCV dictionary name.
    roi : (x0, y0, x1, y1), optional
        Search region, clipped to the image.
    min_perimeter_px : float
        Smallest marker perimeter to accept, px of the original image.
    cell_px : float, optional
        Expected size of one marker bit cell, px (sets the refinement window).
    upscale : float, optional
        Upsampling factor of the search region (1–4).  None: 1, and in a search region of at
        most 1500 px one more try at 2× when the markers found are small (median side under
        20 px) or none are found; the try that finds more markers wins.
    """
    if image.ndim != 2:
        raise ValueError(f"expected a grey image (h, w), got shape {image.shape}")
    h, w = image.shape
    x0, y0, x1, y1 = (0, 0, w, h) if roi is None else _clip_box(roi, w, h)
    box = None if roi is None else (x0, y0, x1, y1)
    sub = to_8bit(image[y0:y1, x0:x1], bits)
    empty = MarkerDetection(np.zeros(0, np.int64), np.zeros((0, 4, 2)), box)
    if sub.size == 0:
        return empty
    if upscale is not None:
        return _detect(
            sub,
            dictionary,
            (x0, y0),
            float(np.clip(upscale, 1.0, 4.0)),
            min_perimeter_px,
            cell_px,
            box,
        )
    best = _detect(sub, dictionary, (x0, y0), 1.0, min_perimeter_px, cell_px, box)
    if max(sub.shape) <= 1500:
        sides = np.linalg.norm(best.corners - np.roll(best.corners, 1, axis=1), axis=-1)
        if best.ids.size == 0 or float(np.median(sides)) < 20.0:
            up = _detect(sub, dictionary, (x0, y0), 2.0, min_perimeter_px, cell_px, box)
            if up.ids.size > best.ids.size:
                best = up
    return best


def _detect(
    sub: NDArray[np.uint8],
    dictionary: str,
    origin: tuple[int, int],
    f: float,
    min_perimeter_px: float,
    cell_px: float | None,
    box: Box | None,
) -> MarkerDetection:
    img = np.ascontiguousarray(sub)
    if f != 1.0:
        img = cv2.resize(img, None, fx=f, fy=f, interpolation=cv2.INTER_CUBIC)
    params = detector_parameters(
        min_perimeter_px * f, max(img.shape), cell_px=None if cell_px is None else cell_px * f
    )
    det = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners, ids, _ = det.detectMarkers(img)
    if ids is None or len(ids) == 0:
        return MarkerDetection(np.zeros(0, np.int64), np.zeros((0, 4, 2)), box)
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    c = (c + 0.5) / f - 0.5 + np.asarray(origin, dtype=float)  # pixel centres at integers
    return MarkerDetection(np.asarray(ids, dtype=np.int64).ravel(), c, box)


def _clip_box(box: Box, w: int, h: int) -> Box:
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    return max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)


def refine_marker_corners(
    image: NDArray[np.uint8] | NDArray[np.uint16],
    corners: F,
    *,
    bits: int | None = None,
    cell_px: F | None = None,
    to_ideal: Callable[[F], F] | None = None,
    from_ideal: Callable[[F], F] | None = None,
) -> F:
    """Sharpen marker corners by fitting straight lines to the four outer edges.

    OpenCV's sub-pixel refinement pulls the outer corner of a blurred black square ≈ 0.2 px
    towards its inside.  Here each side is located at ~16 points by the half-level crossing
    of its intensity profile (exact for a symmetric blur), a line is fitted per side in the
    ideal (undistorted) image, where straight edges stay straight, and neighbouring lines are
    intersected.

    Parameters
    ----------
    image : ndarray, shape (h, w), uint8, or uint16 holding ``bits`` significant bits: the
        edge profiles are read at the image's depth, then put on the 8-bit scale (a deeper
        camera's extra bits sharpen the edge crossings)
    corners : ndarray, shape (n, 4, 2), px
        Corners from :func:`detect_markers`.
    cell_px : ndarray, shape (n,), optional
        Marker bit-cell size, px (default: side / 6).
    to_ideal, from_ideal : callable, optional
        Pixel → undistorted coordinates and back (a camera's ``pixel_to_ray`` and its
        inverse); identity when omitted.

    Returns
    -------
    ndarray, shape (n, 4, 2), px
    """
    c = np.asarray(corners, dtype=float)
    n = c.shape[0]
    if n == 0:
        return c.copy()
    a = c
    b = np.roll(c, -1, axis=1)  # side k goes from corner k to corner k+1 (clockwise in image)
    side = b - a
    L = np.linalg.norm(side, axis=-1)  # (n, 4)
    cell = L.mean(1) / 6.0 if cell_px is None else np.asarray(cell_px, dtype=float)
    t_dir = side / L[..., None]
    nrm = np.stack([t_dir[..., 1], -t_dir[..., 0]], -1)  # points out of the marker (y down)
    m = 16
    # along-side positions: keep away from the corners by one cell
    frac = np.linspace(0.0, 1.0, m)
    marg = np.clip(cell[:, None] / L, 0.0, 0.3)  # (n, 4)
    s = marg[..., None] + (1.0 - 2.0 * marg[..., None]) * frac  # (n, 4, m)
    base = a[:, :, None, :] + s[..., None] * side[:, :, None, :]  # (n, 4, m, 2)
    half = 0.45 * cell  # profile half-length: inside the black border, inside the quiet zone
    k = 25
    u = np.linspace(-1.0, 1.0, k)[None, :] * half[:, None]  # (n, k)
    pts = base[..., None, :] + u[:, None, None, :, None] * nrm[:, :, None, None, :]  # (n,4,m,k,2)
    mx = pts[..., 0].reshape(-1, k).astype(np.float32)
    my = pts[..., 1].reshape(-1, k).astype(np.float32)
    full = full_scale(image, bits) if image.dtype != np.float32 else 255
    if full == 255:
        prof = cv2.remap(
            np.asarray(image, dtype=np.float32), mx, my, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )  # fmt: skip
    else:  # read at depth (1 DN of 4095 is 1/16 of an 8-bit level), then to the 8-bit scale
        prof = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        prof = prof.astype(np.float32) * np.float32(255.0 / full)
    prof = prof.reshape(n, 4, m, k)
    q = k // 5
    lo = prof[..., :q].mean(-1)  # inside (black border)
    hi = prof[..., -q:].mean(-1)  # outside (white)
    mid = 0.5 * (lo + hi)
    # first crossing from inside to outside, linear interpolation between samples
    above = prof >= mid[..., None]
    idx = np.argmax(above, axis=-1)  # first sample at or above mid
    idx = np.clip(idx, 1, k - 1)
    p0 = np.take_along_axis(prof, (idx - 1)[..., None], -1)[..., 0]
    p1 = np.take_along_axis(prof, idx[..., None], -1)[..., 0]
    w = np.clip((mid - p0) / np.where(p1 - p0 == 0, 1.0, p1 - p0), 0.0, 1.0)
    step = 2.0 * half / (k - 1)
    off = -half[:, None, None] + (idx - 1 + w) * step[:, None, None]  # (n, 4, m)
    good = (hi - lo) > 10.0
    edge = base + off[..., None] * nrm[:, :, None, :]  # (n, 4, m, 2)
    if to_ideal is not None:
        edge = to_ideal(edge)
    # line per side by total least squares: centroid + direction
    wts = good.astype(float)
    cnt = wts.sum(-1)
    ok_side = cnt >= 4
    cen = (edge * wts[..., None]).sum(-2) / np.maximum(cnt, 1)[..., None]
    d = (edge - cen[..., None, :]) * wts[..., None]
    S = np.einsum("nsmi,nsmj->nsij", d, d)
    _, vec = np.linalg.eigh(S)
    direc = vec[..., :, 1]  # largest eigenvalue's eigenvector
    # corner k is the intersection of side k-1 and side k
    cp, dp = np.roll(cen, 1, axis=1), np.roll(direc, 1, axis=1)
    A = np.stack([dp, -direc], -1)  # (n, 4, 2, 2)
    rhs = cen - cp
    det = np.linalg.det(A)
    okA = np.abs(det) > 1e-6
    sol = np.linalg.solve(np.where(okA[..., None, None], A, np.eye(2)), rhs[..., None])[..., 0]
    X = cp + sol[..., :1] * dp
    if from_ideal is not None:
        X = from_ideal(X)
    ok = (
        okA
        & ok_side
        & np.roll(ok_side, 1, axis=1)
        & (np.linalg.norm(X - c, axis=-1) < 0.5 * cell[:, None] + 1.0)
    )
    return np.where(ok[..., None], X, c)
