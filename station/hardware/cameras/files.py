"""A recorded image folder as the stereo pair (``--cameras files:FOLDER``), for offline runs.

The folder holds pairs named ``…_L.png`` / ``…_R.png`` (or ``.tif``/``.tiff``), as a run's
``images/`` folder does; each capture returns the next pair in name order, at the depth it
was stored (8-bit, or 16-bit holding the cell's ``pixel_format`` bits).  When the pairs run
out the capture fails in one line, as a camera that stopped would.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ....identify.errors import HardwareError, InputError
from ....vision.camera import StereoRig
from . import CameraIdentity, FrameInfo, StereoFrame
from .config import CameraConfig

SUFFIXES = (".png", ".tif", ".tiff")


def recorded_pairs(folder: Path) -> list[tuple[Path, Path]]:
    """The ``(left, right)`` files of ``folder`` in name order; refused when there is none or
    one side is missing."""
    if not folder.is_dir():
        raise InputError(f"--cameras files:{folder}: no such folder")
    lefts = sorted(
        p for p in folder.iterdir() if p.suffix.lower() in SUFFIXES and p.stem.endswith("_L")
    )
    pairs = []
    for left in lefts:
        right = left.with_name(left.stem[:-2] + "_R" + left.suffix)
        if not right.is_file():
            raise InputError(f"{left}: its right image {right.name} is missing")
        pairs.append((left, right))
    if not pairs:
        raise InputError(f"--cameras files:{folder}: no *_L.png / *_R.png image pairs")
    return pairs


class FilesStereoCamera:
    """The pairs of a recorded folder, one per capture (see the module docstring)."""

    def __init__(self, folder: str | Path, rig: StereoRig, *, bits: int = 8) -> None:
        self.folder = Path(folder)
        self.rig = rig
        self.bits = bits
        self.pairs = recorded_pairs(self.folder)
        self.next = 0
        self.identities = (
            CameraIdentity(model="recorded images", serial=f"{self.folder}/*_L"),
            CameraIdentity(model="recorded images", serial=f"{self.folder}/*_R"),
        )

    def capture(self) -> StereoFrame:
        import cv2  # OpenCV reads the files; the hardware package loads without it

        if self.next >= len(self.pairs):
            raise HardwareError(
                f"the recorded folder {self.folder} has no more image pairs "
                f"({len(self.pairs)} used)"
            )
        k = self.next
        self.next += 1
        imgs = []
        for path, cam in zip(self.pairs[k], self.rig.cameras, strict=True):
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None or img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
                raise HardwareError(f"{path}: not a grey 8- or 16-bit image")
            if (img.shape[1], img.shape[0]) != cam.image_size:
                raise HardwareError(
                    f"{path}: {img.shape[1]}×{img.shape[0]} px, the calibration is for "
                    f"{cam.image_size[0]}×{cam.image_size[1]}"
                )
            imgs.append(img)
        t = time.monotonic()
        bits = 8 if imgs[0].dtype == np.uint8 else self.bits
        return StereoFrame(
            imgs[0],
            imgs[1],
            t,
            t,
            {"files": [p.name for p in self.pairs[k]]},
            bits=bits,
            trigger="files",
            info=(FrameInfo(frame_id=k), FrameInfo(frame_id=k)),
        )

    def close(self) -> None:
        pass


def open_files(cfg: CameraConfig, rig: StereoRig, **kw: object) -> FilesStereoCamera:
    return FilesStereoCamera(cfg.folder, rig, bits=cfg.bits if cfg.bits > 8 else 16)
