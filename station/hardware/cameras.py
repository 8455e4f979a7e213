"""Stereo cameras: two real cameras through OpenCV capture, and a simulated pair.

Both implement :class:`StereoCamera`: ``capture()`` returns a :class:`StereoFrame` (two 8-bit
grey images, each with its capture time) and ``rig`` is the calibrated
:class:`~quickhealth.vision.camera.StereoRig` the measurement uses.

- :class:`OpenCvStereoCamera` — two ``cv2.VideoCapture`` devices.  Synchronised as far as
  the hardware allows: both sensors are latched with ``grab()`` back to back, then decoded
  with ``retrieve()``; the skew between the two grabs is recorded, and a pair whose skew
  exceeds ``max_skew_s`` is captured again.  Cameras with a hardware trigger input should be
  wired to one trigger line; the grab order then only selects the frames.
- :class:`SimStereoCamera` — renders the scene (smart target at the twin's true pose with the
  pan motor's true angle, and the fixed self-check board) with the vision renderer.  The
  board is static, so its noise-free image is rendered once and fresh sensor noise is added
  to it on every capture.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.errors import HardwareError
from quickhealth.vision.boards import TargetDescription
from quickhealth.vision.camera import CameraModel, StereoRig

F = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One stereo capture.

    Attributes
    ----------
    left, right : ndarray (h, w) uint8
    t_left, t_right : float
        Capture times, s (``time.monotonic`` clock of this computer).
    meta : dict
        Extra facts (device names, exposure, skew).
    """

    left: U8
    right: U8
    t_left: float
    t_right: float
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def time(self) -> float:
        """Mid-point of the two capture times, s."""
        return 0.5 * (self.t_left + self.t_right)

    @property
    def skew(self) -> float:
        """Time between the two captures, s."""
        return abs(self.t_right - self.t_left)


@runtime_checkable
class StereoCamera(Protocol):
    """A calibrated stereo pair that captures on request."""

    rig: StereoRig

    def capture(self) -> StereoFrame:
        """Capture both images now (raises HardwareError when a camera fails)."""
        ...

    def close(self) -> None:
        """Release the devices."""
        ...


class OpenCvStereoCamera:
    """Two cameras through OpenCV's VideoCapture.

    Parameters
    ----------
    left, right : int or str
        Device index or path/URL of each camera.
    rig : StereoRig
        Their calibration (``quickhealth vision calibrate``).
    max_skew_s : float
        Largest accepted time between the two grabs; captured again when exceeded.
    """

    def __init__(
        self,
        left: int | str,
        right: int | str,
        rig: StereoRig,
        *,
        max_skew_s: float = 0.005,
        attempts: int = 3,
    ) -> None:
        import cv2

        self.rig = rig
        self.max_skew_s = max_skew_s
        self.attempts = attempts
        self._names = (str(left), str(right))
        self._caps = []
        for dev, cam in ((left, rig.left), (right, rig.right)):
            cap = cv2.VideoCapture(dev)
            if not cap.isOpened():
                self.close()
                raise HardwareError(f"camera {dev!r} does not open: check its cable and power")
            w, h = cam.image_size
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, w)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            self._caps.append(cap)

    def capture(self) -> StereoFrame:
        import cv2

        for _ in range(self.attempts):
            t0 = time.monotonic()
            ok0 = self._caps[0].grab()
            t1 = time.monotonic()
            ok1 = self._caps[1].grab()
            if not (ok0 and ok1):
                continue
            if t1 - t0 > self.max_skew_s:
                continue
            imgs = []
            for cap, cam in zip(self._caps, self.rig.cameras, strict=True):
                ok, img = cap.retrieve()
                if not ok:
                    break
                if img.ndim == 3:
                    img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                if (img.shape[1], img.shape[0]) != cam.image_size:
                    raise HardwareError(
                        f"camera gives {img.shape[1]}×{img.shape[0]} px images, the calibration "
                        f"is for {cam.image_size[0]}×{cam.image_size[1]}: recalibrate"
                    )
                imgs.append(img)
            if len(imgs) == 2:
                return StereoFrame(
                    imgs[0], imgs[1], t0, t1, {"devices": self._names, "skew_s": t1 - t0}
                )
        raise HardwareError(
            f"cameras {self._names[0]}/{self._names[1]} gave no synchronised pair in "
            f"{self.attempts} attempts: check their cables and trigger"
        )

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []


# The scene of the simulated camera: (T_left_object, description) of everything in view.
Scene = Callable[[], Sequence[tuple[F, TargetDescription]]]


def scaled_rig(rig: StereoRig, factor: float) -> StereoRig:
    """The rig on sensors resampled by ``factor`` (smaller, faster simulated images)."""
    if factor == 1.0:
        return rig
    return StereoRig(rig.left.scaled(factor), rig.right.scaled(factor), rig.T_left_right)


class SimStereoCamera:
    """A simulated stereo pair that renders its scene with the vision renderer.

    Parameters
    ----------
    rig : StereoRig
        The simulated cameras (use :func:`scaled_rig` for small fast images).
    target : Scene
        Callable returning the moving objects now: ``[(T_left_target, description)]``.
    static : sequence of (T_left_object, description)
        Objects that never move (the self-check board): rendered once without noise.
    seed : int
        Sensor noise seed.
    """

    def __init__(
        self,
        rig: StereoRig,
        target: Scene,
        static: Sequence[tuple[F, TargetDescription]] = (),
        *,
        seed: int = 0,
        imaging: Any = None,
    ) -> None:
        from quickhealth.vision.render import Imaging

        self.rig = rig
        self._scene = target
        self._imaging = imaging or Imaging()
        self._quiet = Imaging(**{**self._imaging.__dict__, "noise_dn": 0.0})
        self._rng = np.random.default_rng(seed)
        self._static = [
            self._render_static(cam, [(self._to_cam(i, T), d) for T, d in static])
            for i, cam in enumerate(rig.cameras)
        ]
        self.n_captures = 0

    def _to_cam(self, i: int, T_left: F) -> F:
        return T_left if i == 0 else self.rig.T_right_left @ T_left

    def _render_static(
        self, cam: CameraModel, objs: list[tuple[F, TargetDescription]]
    ) -> tuple[U8, NDArray[np.bool_]] | None:
        from quickhealth.vision.render import render_target

        img: U8 | None = None
        mask = np.zeros((cam.image_size[1], cam.image_size[0]), dtype=bool)
        for T, d in objs:
            m = _plate_mask(cam, T, d)
            if not m.any():
                continue
            r = render_target(cam, T, d, imaging=self._quiet, rng=self._rng)
            img = r if img is None else np.where(m, r, img)
            mask |= m
        return None if img is None else (img, mask)

    def capture(self) -> StereoFrame:
        from quickhealth.vision.render import render_target

        objs = list(self._scene())
        out: list[U8] = []
        times: list[float] = []
        for i, cam in enumerate(self.rig.cameras):
            times.append(time.monotonic())
            w, h = cam.image_size
            img: U8 | None = None
            tmask = np.zeros((h, w), dtype=bool)
            for T, d in objs:
                Tc = self._to_cam(i, T)
                m = _plate_mask(cam, Tc, d)
                if not m.any():
                    continue
                r = render_target(cam, Tc, d, imaging=self._imaging, rng=self._rng)
                img = r if img is None else np.where(m, r, img)
                tmask |= m
            if img is None:  # nothing moving in view: the background alone
                img = self._background(h, w)
            st = self._static[i]
            if st is not None:
                simg, smask = st
                m = smask & ~tmask
                noisy = simg.astype(np.float32) + self._rng.normal(
                    0.0, self._imaging.noise_dn, simg.shape
                ).astype(np.float32)
                img = np.where(m, np.clip(np.rint(noisy), 0, 255).astype(np.uint8), img)
            out.append(img)
        self.n_captures += 1
        return StereoFrame(out[0], out[1], times[0], times[1], {"simulated": True})

    def _background(self, h: int, w: int) -> U8:
        im = self._imaging
        level = im.dark_dn + im.background * (im.white_dn - im.dark_dn) * im.gain
        noise = self._rng.normal(0.0, im.noise_dn, (h, w))
        return np.clip(np.rint(level + noise), 0, 255).astype(np.uint8)

    def close(self) -> None:
        pass


def _plate_mask(cam: CameraModel, T_cam_obj: F, d: TargetDescription) -> NDArray[np.bool_]:
    """Pixels covered by the object's plate (its outline projected), False when not in view."""
    import cv2

    w, h = cam.image_size
    mask = np.zeros((h, w), dtype=np.uint8)
    (x0, y0), (x1, y1) = d.plate
    pl = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)
    p = pl @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    if np.any(p[:, 2] <= 0.05):
        return mask.astype(bool)
    px = cam.project(p)
    if (
        np.all(px[:, 0] < 0)
        or np.all(px[:, 0] >= w)
        or np.all(px[:, 1] < 0)
        or np.all(px[:, 1] >= h)
    ):
        return mask.astype(bool)
    cv2.fillConvexPoly(mask, np.round(px).astype(np.int32), 1)
    mask = cv2.dilate(mask, np.ones((5, 5), np.uint8))
    return mask.astype(bool)
