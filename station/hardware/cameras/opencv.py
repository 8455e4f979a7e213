"""Webcams through OpenCV (``--cameras opencv``, or ``LEFT,RIGHT``).

- :class:`OpenCvStereoCamera` — two ``cv2.VideoCapture`` devices.  Synchronised as far as
  the hardware allows: both sensors are latched with ``grab()`` back to back, then decoded
  with ``retrieve()``; the skew between the two grabs is recorded, and a pair whose skew
  exceeds ``max_skew_s`` is captured again.  Cameras with a hardware trigger input should be
  wired to one trigger line; the grab order then only selects the frames.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from ....identify.errors import HardwareError
from ....vision.camera import StereoRig
from . import CameraIdentity, StereoFrame
from .config import CameraConfig

F = NDArray[np.float64]
U8 = NDArray[np.uint8]


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
        import cv2  # the real cameras only: the hardware package loads without OpenCV

        self.rig = rig
        self.max_skew_s = max_skew_s
        self.attempts = attempts
        self._names = (str(left), str(right))
        self.identities = tuple(
            CameraIdentity(model="OpenCV VideoCapture", serial=n) for n in self._names
        )
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
        import cv2  # as above

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
                    imgs[0],
                    imgs[1],
                    t0,
                    t1,
                    {"devices": self._names, "skew_s": t1 - t0},
                    trigger="free",
                )
        raise HardwareError(
            f"cameras {self._names[0]}/{self._names[1]} gave no synchronised pair in "
            f"{self.attempts} attempts: check their cables and trigger"
        )

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []


def open_opencv(cfg: CameraConfig, rig: StereoRig, **kw: object) -> OpenCvStereoCamera:
    """The pair of ``cfg`` through OpenCV (ids: device indices or paths)."""
    dev = [int(i) if i.isdigit() else i for i in cfg.ids]
    return OpenCvStereoCamera(
        dev[0], dev[1], rig, max_skew_s=max(cfg.max_skew_s, 0.005), attempts=cfg.attempts
    )
