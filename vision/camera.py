"""Camera models: a pinhole with OpenCV's (k1, k2, p1, p2, k3) lens distortion, and a stereo rig.

Conventions: pixel coordinates have their origin at the centre of the top-left pixel (OpenCV).
Points in a camera frame are in metres, z along the optical axis.  ``T_left_right`` maps
points from the right camera's frame into the left camera's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quickhealth.identify.transforms import inv_T

F = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class CameraModel:
    """One calibrated camera.

    Attributes
    ----------
    K : ndarray, shape (3, 3), px
        Camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    dist : ndarray, shape (5,)
        OpenCV distortion (k1, k2, p1, p2, k3); shorter inputs are zero-padded.
    image_size : tuple of int
        (width, height) in pixels.
    """

    K: F
    dist: F
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3×3, got shape {K.shape}")
        d = np.zeros(5)
        dd = np.asarray(self.dist, dtype=float).ravel()
        if dd.size > 5:
            if np.any(dd[5:] != 0):
                raise ValueError(
                    "only the 5-coefficient OpenCV model (k1 k2 p1 p2 k3) is supported"
                )
            dd = dd[:5]
        d[: dd.size] = dd
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "image_size", (int(self.image_size[0]), int(self.image_size[1])))

    @property
    def fx(self) -> float:
        """Focal length along x, px."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along y, px."""
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        """Principal point x, px."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y, px."""
        return float(self.K[1, 2])

    def distort(self, xn: ArrayLike) -> F:
        """Normalised ideal coordinates ``(..., 2)`` → distorted normalised coordinates."""
        xn = np.asarray(xn, dtype=float)
        k1, k2, p1, p2, k3 = self.dist
        x, y = xn[..., 0], xn[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xd: ArrayLike, *, n_iter: int = 20) -> F:
        """Inverse of :meth:`distort` by Newton iteration (accurate to ~1e-12 in normalised units)."""
        xd = np.asarray(xd, dtype=float)
        if not np.any(self.dist):
            return xd.copy()
        k1, k2, p1, p2, k3 = self.dist
        x = xd.copy()
        for _ in range(n_iter):
            u, v = x[..., 0], x[..., 1]
            r2 = u * u + v * v
            rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d rad / d r2
            f = self.distort(x) - xd
            # Jacobian of distort
            a = rad + 2.0 * u * u * drad + 2.0 * p1 * v + 6.0 * p2 * u
            b = 2.0 * u * v * drad + 2.0 * p1 * u + 2.0 * p2 * v
            c = 2.0 * u * v * drad + 2.0 * p1 * u + 2.0 * p2 * v
            d = rad + 2.0 * v * v * drad + 6.0 * p1 * v + 2.0 * p2 * u
            det = a * d - b * c
            dx = (d * f[..., 0] - b * f[..., 1]) / det
            dy = (-c * f[..., 0] + a * f[..., 1]) / det
            x = x - np.stack([dx, dy], axis=-1)
            if np.max(np.abs(dx)) < 1e-14 and np.max(np.abs(dy)) < 1e-14:
                break
        return x

    def project(self, p_cam: ArrayLike) -> F:
        """Points in the camera frame ``(..., 3)``, m → pixels ``(..., 2)``."""
        p = np.asarray(p_cam, dtype=float)
        xn = p[..., :2] / p[..., 2:3]
        xd = self.distort(xn)
        return np.stack(
            [self.K[0, 0] * xd[..., 0] + self.K[0, 1] * xd[..., 1] + self.K[0, 2],
             self.K[1, 1] * xd[..., 1] + self.K[1, 2]],
            axis=-1,
        )  # fmt: skip

    def pixel_to_ray(self, px: ArrayLike) -> F:
        """Pixels ``(..., 2)`` → undistorted normalised coordinates ``(..., 2)`` (ray = (x, y, 1))."""
        px = np.asarray(px, dtype=float)
        yd = (px[..., 1] - self.K[1, 2]) / self.K[1, 1]
        xd = (px[..., 0] - self.K[0, 2] - self.K[0, 1] * yd) / self.K[0, 0]
        return self.undistort(np.stack([xd, yd], axis=-1))

    def scaled(self, factor: float) -> CameraModel:
        """The same lens on a sensor resampled by ``factor`` (for downscaled fixture images)."""
        K = self.K.copy()
        K[:2, :2] *= factor
        K[:2, 2] = (K[:2, 2] + 0.5) * factor - 0.5
        w, h = self.image_size
        return CameraModel(K, self.dist.copy(), (round(w * factor), round(h * factor)))


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two calibrated cameras and the transform between them.

    Attributes
    ----------
    left, right : CameraModel
    T_left_right : ndarray, shape (4, 4), m
        Maps points from the right camera's frame into the left camera's frame.  The
        instrument frame of the 7D measurements is the left camera's frame.
    """

    left: CameraModel
    right: CameraModel
    T_left_right: F

    def __post_init__(self) -> None:
        T = np.asarray(self.T_left_right, dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"T_left_right must be 4×4, got {T.shape}")
        object.__setattr__(self, "T_left_right", T)

    @property
    def T_right_left(self) -> F:
        """Maps points from the left camera's frame into the right camera's frame."""
        return inv_T(self.T_left_right)

    @property
    def baseline(self) -> float:
        """Distance between the optical centres, m."""
        return float(np.linalg.norm(self.T_left_right[:3, 3]))

    @property
    def cameras(self) -> tuple[CameraModel, CameraModel]:
        """(left, right)."""
        return (self.left, self.right)

    def T_cam_left(self, i: int) -> F:
        """Transform from the left camera frame into camera ``i`` (0 left, 1 right)."""
        return np.eye(4) if i == 0 else self.T_right_left
