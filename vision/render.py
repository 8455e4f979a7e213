"""Synthetic camera images of smart targets and calibration boards.

The printed pattern (:class:`~quickhealth.vision.boards.Layer` grids) is drawn through the
full camera model, lens distortion included, by mapping every sub-pixel sample back onto the
plate (exact inverse distortion, then the plate's homography).  Each sample is box-filtered
analytically over its own footprint on the plate, and ``supersample``² samples are averaged
per pixel, so edges and corners land where the model projects them (better than 0.01 px
without blur and noise; see tests/vision/test_render.py).  Then optics and sensor: Gaussian
blur, lighting (gain and a linear fall-off across the image), Gaussian read noise, 8-bit
quantisation.

SYNOPSIS
    >>> rig = reference_rig(); tgt = reference_target()
    >>> T = make_T(np.eye(3), [0.0, 0.0, 2.0])
    >>> left, right = render_stereo(rig, T, tgt, rng=np.random.default_rng(0))
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .boards import BoardSpec, Layer, TargetDescription, pan_transform
from .camera import CameraModel, StereoRig

F = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class Imaging:
    """Optics, lighting and sensor of a synthetic image.

    Attributes
    ----------
    blur_px : float
        Standard deviation of the Gaussian point-spread function, px (0 = none).
    noise_dn : float
        Standard deviation of additive read noise, digital numbers (0 = none).
    white_dn, dark_dn : float
        Signal of white paper and of black (zero reflectance) at gain 1.
    gain : float
        Overall lighting level (1 = nominal).
    gradient : tuple of float
        Relative lighting change per image width along x and y (e.g. (0.3, 0) = 30 % brighter
        at the right edge than at the left).
    background : float
        Reflectance of the scene around the plate.
    supersample : int
        Samples per pixel along each axis.
    bits : int
        The sensor's depth: 8 gives uint8 images; 10 to 16 give uint16 images with that many
        significant bits (LSB-aligned), the same scene with finer steps (``white_dn``,
        ``dark_dn`` and ``noise_dn`` stay on the 8-bit scale).
    """

    blur_px: float = 0.7
    noise_dn: float = 2.0
    white_dn: float = 215.0
    dark_dn: float = 12.0
    gain: float = 1.0
    gradient: tuple[float, float] = (0.0, 0.0)
    background: float = 0.35
    supersample: int = 2
    bits: int = 8

    @property
    def full_scale(self) -> int:
        """The sensor's largest value (255 at 8 bits, 4095 at 12)."""
        return (1 << self.bits) - 1


def render_target(
    camera: CameraModel,
    T_cam_target: F,
    target: TargetDescription,
    *,
    pan: float = 0.0,
    imaging: Imaging = Imaging(),
    rng: np.random.Generator | None = None,
) -> U8:
    """Image of the smart target seen by ``camera``.

    Parameters
    ----------
    camera : CameraModel
    T_cam_target : ndarray, shape (4, 4), m
        Pose of the target frame in the camera frame at pan angle 0.
    target : TargetDescription
    pan : float, rad
        Turn the plate by this angle about the target's pan axis first: the plate is drawn at
        ``T_cam_target @ pan_transform(target, pan)`` (leave 0 when ``T_cam_target`` already
        includes the pan).
    imaging : Imaging
    rng : numpy Generator, optional
        Source of the sensor noise (None: a fixed seed, so images are reproducible).

    Returns
    -------
    ndarray, shape (height, width), uint8
    """
    T = np.asarray(T_cam_target, dtype=float)
    if pan:
        T = T @ pan_transform(target, pan)
    return render_layers(camera, T, target.layers(), target.plate, imaging, rng)


def render_board(
    camera: CameraModel,
    T_cam_board: F,
    board: BoardSpec,
    *,
    imaging: Imaging = Imaging(),
    rng: np.random.Generator | None = None,
) -> U8:
    """Image of a calibration board (chessboard or ChArUco) seen by ``camera``."""
    lo, hi = board.plate()
    return render_layers(camera, T_cam_board, board.layers(), np.array([lo, hi]), imaging, rng)


def render_stereo(
    rig: StereoRig,
    T_left_target: F,
    target: TargetDescription | BoardSpec,
    *,
    pan: float = 0.0,
    imaging: Imaging = Imaging(),
    rng: np.random.Generator | None = None,
) -> tuple[U8, U8]:
    """(left, right) images of a target or board posed at ``T_left_target`` in the left frame
    (for a target, at pan angle ``pan`` about its pan axis, as in :func:`render_target`)."""
    rng = np.random.default_rng(0) if rng is None else rng
    out = []
    for cam, T in ((rig.left, T_left_target), (rig.right, rig.T_right_left @ T_left_target)):
        if isinstance(target, BoardSpec):
            out.append(render_board(cam, T, target, imaging=imaging, rng=rng))
        else:
            out.append(render_target(cam, T, target, pan=pan, imaging=imaging, rng=rng))
    return out[0], out[1]


def render_layers(
    camera: CameraModel,
    T_cam_plate: F,
    layers: list[Layer],
    plate: F,
    im: Imaging,
    rng: np.random.Generator | None,
) -> U8:
    """One camera image of printed ``layers`` on a plate (extent ``plate``, plate frame)
    seen from pose ``T_cam_plate``; the engine under :func:`render_target` and
    :func:`render_board`."""
    rng = np.random.default_rng(0) if rng is None else rng
    T_cam_plate = np.asarray(T_cam_plate, dtype=float)
    w, h = camera.image_size
    xs = (np.arange(w, dtype=np.float32) - w / 2) / w
    ys = (np.arange(h, dtype=np.float32) - h / 2) / w
    gain = np.float32(im.gain * (im.white_dn - im.dark_dn))

    def shade(x: slice, y: slice) -> NDArray[np.float32]:
        return gain * (1.0 + im.gradient[0] * xs[None, x] + im.gradient[1] * ys[y, None])

    # the scene around the plate is uniform: its blurred image is its shaded image
    img = np.float32(im.dark_dn) + shade(slice(None), slice(None)) * np.float32(im.background)
    margin = int(np.ceil(4 * im.blur_px)) + 2
    bbox = _plate_bbox(camera, T_cam_plate, plate, margin=margin)
    if bbox is not None:
        x0, y0, x1, y1 = bbox
        refl = _render_patch(camera, T_cam_plate, layers, plate, bbox, im)
        patch = np.float32(im.dark_dn) + shade(slice(x0, x1), slice(y0, y1)) * refl
        if im.blur_px > 0:
            patch = cv2.GaussianBlur(patch, (0, 0), im.blur_px, borderType=cv2.BORDER_REPLICATE)
        img[y0:y1, x0:x1] = patch
    if im.noise_dn > 0:
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(im.noise_dn)
    return quantize(img, im.bits)


def quantize(img: NDArray[np.float32], bits: int = 8) -> U8:
    """A float image on the 8-bit scale as a ``bits``-deep sensor reads it out (rounded,
    clipped; uint8 at 8 bits, uint16 above).  Changes ``img``."""
    if bits == 8:
        np.rint(img, out=img)
        np.clip(img, 0, 255, out=img)
        return img.astype(np.uint8)
    if not 9 <= bits <= 16:
        raise ValueError(f"a sensor of {bits} bits: 8 to 16 only")
    full = (1 << bits) - 1
    img *= np.float32(full / 255.0)
    np.rint(img, out=img)
    np.clip(img, 0, full, out=img)
    return img.astype(np.uint16)  # type: ignore[return-value]


def _plate_bbox(
    camera: CameraModel, T: F, plate: F, margin: int
) -> tuple[int, int, int, int] | None:
    """Pixel box (x0, y0, x1, y1) around the plate's image, clipped; None if not in view."""
    (ux0, uy0), (ux1, uy1) = plate
    t = np.linspace(0.0, 1.0, 41)
    edge = np.concatenate([
        np.stack([ux0 + (ux1 - ux0) * t, np.full_like(t, uy0)], -1),
        np.stack([ux0 + (ux1 - ux0) * t, np.full_like(t, uy1)], -1),
        np.stack([np.full_like(t, ux0), uy0 + (uy1 - uy0) * t], -1),
        np.stack([np.full_like(t, ux1), uy0 + (uy1 - uy0) * t], -1),
    ])  # fmt: skip
    p = edge @ T[:3, :2].T + T[:3, 3]
    if np.any(p[:, 2] <= 1e-3):
        raise ValueError("the plate crosses the camera's image plane (z ≤ 0): not renderable")
    px = camera.project(p)
    w, h = camera.image_size
    x0 = max(int(np.floor(px[:, 0].min())) - margin, 0)
    y0 = max(int(np.floor(px[:, 1].min())) - margin, 0)
    x1 = min(int(np.ceil(px[:, 0].max())) + margin + 1, w)
    y1 = min(int(np.ceil(px[:, 1].max())) + margin + 1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _plate_coords(
    camera: CameraModel, T_cam_plate: F, bbox: tuple[int, int, int, int], ss: int, grid: int = 4
) -> F:
    """Plate (x, y) of every sub-pixel sample in ``bbox``, shape (H·ss, W·ss, 2).

    Exact on a lattice of pixel corners every ``grid`` px (inverse distortion + homography),
    bilinear in between: the mapping is smooth, so for the lenses here the interpolation
    error is below 1e-3 px (tests/vision/test_render.py checks edges to 0.01 px).
    """
    x0, y0, x1, y1 = bbox
    W, H_ = x1 - x0, y1 - y0
    nx, ny = -(-W // grid), -(-H_ // grid)
    gx = x0 - 0.5 + grid * np.arange(nx + 1, dtype=float)
    gy = y0 - 0.5 + grid * np.arange(ny + 1, dtype=float)
    X, Y = np.meshgrid(gx, gy)
    xn = camera.pixel_to_ray(np.stack([X, Y], -1))
    H = np.linalg.inv(np.column_stack([T_cam_plate[:3, 0], T_cam_plate[:3, 1], T_cam_plate[:3, 3]]))
    ray = np.concatenate([xn, np.ones((*xn.shape[:2], 1))], -1)
    q = ray @ H.T
    # rays that meet the plate's plane behind the camera: push them far away
    q[..., 2] = np.where(q[..., 2] <= 0, 1e-12, q[..., 2])
    uv = q[..., :2] / q[..., 2:3]
    n = grid * ss
    f = (np.arange(n) + 0.5) / n  # sample positions inside a lattice cell, from its corner
    A = uv[:-1, :-1]
    B = uv[:-1, 1:]
    C = uv[1:, :-1]
    D = uv[1:, 1:]
    fy = f[None, :, None, None, None]
    fx = f[None, None, None, :, None]
    out = (
        A[:, None, :, None] * (1 - fy) * (1 - fx)
        + B[:, None, :, None] * (1 - fy) * fx
        + C[:, None, :, None] * fy * (1 - fx)
        + D[:, None, :, None] * fy * fx
    )
    out = out.reshape(ny * n, nx * n, 2)
    return out[: H_ * ss, : W * ss]


def _box_grid(s: F, ws: F, t: F, wt: F, cells: F, outside: float) -> F:
    """Box-filtered value of a cell grid at local coordinates (s, t) (cell units) with
    footprint half-widths (ws, wt); ``outside`` beyond the grid."""
    nv, nu = cells.shape
    pad = np.full((nv + 2, nu + 2), outside)
    pad[1:-1, 1:-1] = cells

    def weights(c: F, wc: F) -> tuple[NDArray[np.int64], F]:
        wc = np.clip(wc, 1e-6, 0.5)
        i0 = np.floor(c - wc)
        w0 = np.clip(i0 + 1.0 - (c - wc), 0.0, 2 * wc) / (2 * wc)
        return i0.astype(np.int64), w0

    i0, a0 = weights(s, ws)
    j0, b0 = weights(t, wt)
    i0p = np.clip(i0 + 1, 0, nu + 1)
    i1p = np.clip(i0 + 2, 0, nu + 1)
    j0p = np.clip(j0 + 1, 0, nv + 1)
    j1p = np.clip(j0 + 2, 0, nv + 1)
    return b0 * (a0 * pad[j0p, i0p] + (1 - a0) * pad[j0p, i1p]) + (1 - b0) * (
        a0 * pad[j1p, i0p] + (1 - a0) * pad[j1p, i1p]
    )


def _render_patch(
    camera: CameraModel,
    T_cam_plate: F,
    layers: list[Layer],
    plate: F,
    bbox: tuple[int, int, int, int],
    im: Imaging,
) -> NDArray[np.float32]:
    ss = int(im.supersample)
    # float32 is ample here (1e-5 px) and halves the memory traffic
    uv = _plate_coords(camera, T_cam_plate, bbox, ss).astype(np.float32)
    # footprint of one sample on the plate: bounding box of its parallelogram (symmetric, so
    # edges are not shifted)
    du_i, du_j = np.gradient(uv[..., 0])
    dv_i, dv_j = np.gradient(uv[..., 1])
    hu = 0.5 * (np.abs(du_i) + np.abs(du_j))
    hv = 0.5 * (np.abs(dv_i) + np.abs(dv_j))
    (px0, py0), (px1, py1) = plate
    # plate: one white cell on the background
    refl = _box_grid(
        (uv[..., 0] - px0) / (px1 - px0), hu / (px1 - px0),
        (uv[..., 1] - py0) / (py1 - py0), hv / (py1 - py0),
        np.ones((1, 1)), im.background,
    )  # fmt: skip
    for L in layers:
        A = np.column_stack([L.axis_u, L.axis_v])
        Ai = np.linalg.inv(A).astype(np.float32)
        # samples that may touch this layer (its corners' range in plate coords, plus a margin)
        nv, nu = L.cells.shape
        e = np.linspace(0.0, 1.0, 9)
        cu = np.concatenate([e * nu, e * nu, np.zeros(9), np.full(9, nu)])
        cv = np.concatenate([np.zeros(9), np.full(9, nv), e * nv, e * nv])
        corners = L.origin + cu[:, None] * L.axis_u + cv[:, None] * L.axis_v
        pc = camera.project(corners @ T_cam_plate[:3, :2].T + T_cam_plate[:3, 3])
        x0, y0 = bbox[0], bbox[1]
        i0 = max(int(np.floor((pc[:, 0].min() - x0 + 0.5) * ss)) - 2 * ss, 0)
        i1 = min(int(np.ceil((pc[:, 0].max() - x0 + 0.5) * ss)) + 2 * ss, uv.shape[1])
        j0 = max(int(np.floor((pc[:, 1].min() - y0 + 0.5) * ss)) - 2 * ss, 0)
        j1 = min(int(np.ceil((pc[:, 1].max() - y0 + 0.5) * ss)) + 2 * ss, uv.shape[0])
        if i1 <= i0 or j1 <= j0:
            continue
        sl = (slice(j0, j1), slice(i0, i1))
        d = uv[sl] - L.origin.astype(np.float32)
        st = d @ Ai.T
        # footprint half-widths in cell units
        hs = np.abs(Ai[0, 0]) * hu[sl] + np.abs(Ai[0, 1]) * hv[sl]
        ht = np.abs(Ai[1, 0]) * hu[sl] + np.abs(Ai[1, 1]) * hv[sl]
        refl[sl] *= _box_grid(st[..., 0], hs, st[..., 1], ht, L.cells, 1.0)
    nh, nw = refl.shape[0] // ss, refl.shape[1] // ss
    return refl.reshape(nh, ss, nw, ss).mean(axis=(1, 3)).astype(np.float32)
