"""The simulated stereo pair: renders the scene with the vision renderer (``--sim`` only).

:class:`SimStereoCamera` implements :class:`~quickhealth.station.hardware.cameras.StereoCamera`.
It renders the smart target at the digital twin's true pose with the pan motor's true angle,
and the fixed self-check board.  The board is static, so its noise-free image is rendered once
and fresh sensor noise is added to it on every capture.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from ...vision.boards import TargetDescription
from ...vision.camera import CameraModel, StereoRig
from ...vision.render import Imaging, quantize, render_target
from ..hardware.cameras import CameraIdentity, StereoFrame
from ..hardware.cameras.config import CameraSpec
from ..hardware.cameras.genicam import DeviceLost, GenICamDevice

F = NDArray[np.float64]
U8 = NDArray[np.uint8]

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
        imaging: Imaging | None = None,
    ) -> None:
        self.rig = rig
        self._scene = target
        self._imaging = imaging or Imaging()
        self._quiet = replace(self._imaging, noise_dn=0.0)
        self._rng = np.random.default_rng(seed)
        self._static_objs = list(static)
        self._static = [
            self._render_static(cam, [(self._to_cam(i, T), d) for T, d in static])
            for i, cam in enumerate(rig.cameras)
        ]
        self.n_captures = 0
        self.identities = (
            CameraIdentity(model="simulated renderer", serial="sim-left"),
            CameraIdentity(model="simulated renderer", serial="sim-right"),
        )

    def set_gain(self, gain: float) -> None:
        """The scene's brightness relative to nominal (an exposure change of the emulated
        cameras): the static board is rendered again when it changes."""
        if abs(gain - self._imaging.gain) < 1e-9:
            return
        self._imaging = replace(self._imaging, gain=float(gain))
        self._quiet = replace(self._imaging, noise_dn=0.0)
        self._static = [
            self._render_static(cam, [(self._to_cam(i, T), d) for T, d in self._static_objs])
            for i, cam in enumerate(self.rig.cameras)
        ]

    def _to_cam(self, i: int, T_left: F) -> F:
        return T_left if i == 0 else self.rig.T_right_left @ T_left

    def _render_static(
        self, cam: CameraModel, objs: list[tuple[F, TargetDescription]]
    ) -> tuple[U8, NDArray[np.bool_]] | None:
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
                scale = np.float32(255.0 / self._imaging.full_scale)
                noisy = simg.astype(np.float32) * scale + self._rng.normal(
                    0.0, self._imaging.noise_dn, simg.shape
                ).astype(np.float32)
                img = np.where(m, quantize(noisy, self._imaging.bits), img)
            out.append(img)
        self.n_captures += 1
        return StereoFrame(
            out[0],
            out[1],
            times[0],
            times[1],
            {"simulated": True},
            bits=self._imaging.bits,
            trigger="software",
        )

    def _background(self, h: int, w: int) -> U8:
        im = self._imaging
        level = im.dark_dn + im.background * (im.white_dn - im.dark_dn) * im.gain
        noise = self._rng.normal(0.0, im.noise_dn, (h, w)).astype(np.float32)
        return quantize(noise + np.float32(level), im.bits)

    def close(self) -> None:
        pass


def _plate_mask(cam: CameraModel, T_cam_obj: F, d: TargetDescription) -> NDArray[np.bool_]:
    """Pixels covered by the object's plate (its outline projected), False when not in view."""
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


#: The emulated cameras' exposure that gives the renderer's nominal brightness (µs).
NOMINAL_EXPOSURE_US = 10_000.0


#: Camera faults the simulated cell can give its emulated cameras (:meth:`EmulatorFeed.inject`).
CAMERA_FAULTS = ("unplug", "timeout", "dropped_frame", "out_of_step", "reboot")


class EmulatorFeed:
    """Puts the rendered scene in front of a camera SDK's emulated cameras, and gives them the
    faults real cameras have.

    The ``prepare`` hook of :class:`~quickhealth.station.hardware.cameras.genicam.TriggeredStereoCamera`:
    before each trigger it renders the pair (:class:`SimStereoCamera`, at the brightness of
    the emulated cameras' exposure) and hands each image to its emulated device
    (``device.show(image)``), which serves it on the trigger.  ``shown`` keeps the last pair
    put in front of the cameras (a test compares the delivered frames with it).

    :meth:`inject` queues a fault; it acts at the next capture, on the thread that owns the
    cameras (never from outside it):

    - ``dropped_frame``: the emulator fails the right camera's next buffer (lost packets);
    - ``out_of_step``: an edge only the left camera sees (a frame nobody asked for);
    - ``timeout``: the left camera's trigger never reaches it (a trigger cable off; the
      emulator exposes on any software trigger, so the trigger is lost before it) until
      :meth:`clear`;
    - ``unplug``: the left camera is gone (closed, and not found when the backend looks for
      it) until :meth:`clear`;
    - ``reboot``: the left camera is gone for ``reboot_s`` and comes back by itself.

    :meth:`open_device` wraps the backend's device opener so an unplugged camera is not found.
    """

    def __init__(self, renderer: SimStereoCamera, reboot_s: float = 1.0) -> None:
        self.renderer = renderer
        self.shown: tuple[np.ndarray, np.ndarray] | None = None
        self.n = 0
        self.reboot_s = reboot_s
        self._queued: list[str] = []
        self._away_until = 0.0  # the left camera is not on the bus until then (inf: unplugged)
        self._no_edge = False
        self._lock = threading.Lock()

    def inject(self, kind: str) -> None:
        if kind not in CAMERA_FAULTS:
            raise ValueError(f"unknown camera fault {kind!r} (known: {', '.join(CAMERA_FAULTS)})")
        with self._lock:
            self._queued.append(kind)

    @property
    def queued(self) -> bool:
        """A fault waits for the next capture."""
        with self._lock:
            return bool(self._queued)

    def clear(self) -> None:
        """The technician's fix: the camera plugged back, its trigger cable seated."""
        with self._lock:
            self._queued.clear()
            self._away_until = 0.0
            self._no_edge = False

    def open_device(
        self, opener: Callable[[CameraSpec], GenICamDevice]
    ) -> Callable[[CameraSpec], GenICamDevice]:
        def open_(spec: CameraSpec) -> GenICamDevice:
            if spec.index == 0 and time.monotonic() < self._away_until:
                raise DeviceLost(spec.side, f"{spec.side} camera not found: unplugged?")
            return opener(spec)

        return open_

    def __call__(self, devices: Sequence[GenICamDevice]) -> None:
        with self._lock:
            queued, self._queued = self._queued, []
        for kind in queued:  # what happens to the camera itself: before the scene is shown
            self._act(kind, devices)
        if self._no_edge:  # also on a camera opened (and configured) again since
            devices[0].trigger = _lost_trigger  # type: ignore[method-assign]
        exposure = getattr(devices[0], "exposure_us", None)
        self.renderer.set_gain(1.0 if not exposure else float(exposure) / NOMINAL_EXPOSURE_US)
        frame = self.renderer.capture()
        for dev, img in zip(devices, (frame.left, frame.right), strict=True):
            dev.show(img)  # type: ignore[attr-defined]
        self.shown = (frame.left, frame.right)
        self.n += 1
        if "dropped_frame" in queued:  # after show (showing restarts the acquisition)
            _force_failed_buffer(devices[1])
        if "out_of_step" in queued:  # after show: a stray edge on the left camera alone
            left = devices[0]
            left.trigger()
            t0 = time.monotonic()
            while not left.pending() and time.monotonic() - t0 < 2.0:
                time.sleep(0.002)

    def _act(self, kind: str, devices: Sequence[GenICamDevice]) -> None:
        if kind == "timeout":
            self._no_edge = True
        elif kind in ("unplug", "reboot"):
            self._away_until = math.inf if kind == "unplug" else time.monotonic() + self.reboot_s
            _pull(devices[0])


def _lost_trigger() -> None:
    """A trigger that never reaches the camera."""


def _force_failed_buffer(dev: GenICamDevice) -> None:
    cam = dev.cam  # type: ignore[attr-defined]
    cam.ForceFailedBufferCount.Value = 1
    cam.ForceFailedBuffer.Execute()


def _pull(dev: GenICamDevice) -> None:
    """The cable out: the device disappears under the driver (its next call fails)."""
    cam = dev.cam  # type: ignore[attr-defined]
    try:
        cam.StopGrabbing()
        cam.DestroyDevice()
    except Exception:  # noqa: BLE001 - already gone
        pass
