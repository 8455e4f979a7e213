"""The camera backends by name: the one place a backend is registered.

Each entry names the module and the function that opens a pair,
``open(cfg: CameraConfig, rig: StereoRig, **kw) -> StereoCamera``; the module is imported only
when its backend is chosen, so a station without a camera SDK still runs the others.
Adding a backend: its module (``station/hardware/cameras/NAME.py``), one line here, its name
in :data:`.config.BACKENDS`, its tests (docs/station.md, "Adding a camera backend").
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from ....vision.camera import StereoRig
from . import StereoCamera
from .config import BACKENDS, CameraConfig

REGISTRY: dict[str, tuple[str, str]] = {
    "pylon": ("pylon", "open_pylon"),
    "aravis": ("aravis", "open_aravis"),
    "opencv": ("opencv", "open_opencv"),
    "files": ("files", "open_files"),
}
assert set(REGISTRY) == set(BACKENDS)


def open_cameras(cfg: CameraConfig, rig: StereoRig, **kw: Any) -> StereoCamera:
    """Open the stereo pair ``cfg`` names (``kw``: the backend's extras, e.g. ``fire``)."""
    module, func = REGISTRY[cfg.backend]
    opener = getattr(import_module(f"{__package__}.{module}"), func)
    camera: StereoCamera = opener(cfg, rig, **kw)
    return camera
