"""Basler cameras through pypylon (``--cameras pylon``): GigE Vision and USB3 Vision.

:func:`open_pylon` returns a :class:`~.genicam.TriggeredStereoCamera` on two
:class:`PylonDevice` adapters.  A camera is found by serial number or user id
(``DeviceUserID``); without ids the first two cameras the SDK lists, by serial number.

pypylon is one wheel with no system packages (its version: ``importlib.metadata``).  Its
camera emulation (``PYLON_CAMEMU=2``: two cameras ``0815-0000``, ``0815-0001``) has the full
trigger feature set and serves images from files (``ImageFilename``, ``ImageFileMode=On``,
``TestImageSelector=Off`` — the test image otherwise replaces the files), bit for bit: a
16-bit file is served MSB-aligned, so a 12-bit image goes in as ``value << 4``.  It reads
its files when acquisition starts, so :meth:`PylonDevice.show_files` restarts acquisition.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ....identify.errors import HardwareError
from ....vision.camera import StereoRig
from . import CameraIdentity, FrameInfo
from .config import CameraConfig, CameraSpec, Trigger
from .genicam import (
    DeviceLost,
    DroppedFrame,
    FrameTimeout,
    RawFrame,
    TriggeredStereoCamera,
    to_host_bits,
)


def _pylon() -> Any:
    try:
        from pypylon import genicam, pylon  # the SDK: only when a pylon camera is opened
    except ImportError as exc:  # pragma: no cover - pypylon is in the lock
        raise HardwareError(f"--cameras pylon needs pypylon ({exc})") from None
    return pylon, genicam


def list_devices() -> list[CameraIdentity]:
    """Every camera pylon sees (emulated ones included when ``PYLON_CAMEMU`` is set)."""
    pylon, _ = _pylon()
    out = []
    for d in pylon.TlFactory.GetInstance().EnumerateDevices():
        out.append(
            CameraIdentity(
                vendor=d.GetVendorName(),
                model=d.GetModelName(),
                serial=d.GetSerialNumber(),
                user_id=d.GetUserDefinedName(),
            )
        )
    return sorted(out, key=lambda c: c.serial)


class PylonDevice:
    """One camera through pypylon's InstantCamera (a :class:`~.genicam.GenICamDevice`)."""

    def __init__(self, spec: CameraSpec) -> None:
        pylon, genicam = _pylon()
        self._pylon, self._genicam = pylon, genicam
        tl = pylon.TlFactory.GetInstance()
        devices = sorted(tl.EnumerateDevices(), key=lambda d: d.GetSerialNumber())
        if spec.id:
            match = [d for d in devices if spec.id in (d.GetSerialNumber(), d.GetUserDefinedName())]
        else:
            match = devices[spec.index : spec.index + 1]
        if not match:
            seen = ", ".join(d.GetSerialNumber() for d in devices) or "none"
            raise DeviceLost(
                spec.side,
                f"{spec.side} camera {spec.id or '#' + str(spec.index)} not found by pylon "
                f"(cameras seen: {seen}): check its cable and power",
            )
        try:
            self.cam = pylon.InstantCamera(tl.CreateDevice(match[0]))
            self.cam.Open()
        except genicam.GenericException as exc:
            raise DeviceLost(
                spec.side, f"{spec.side} camera does not open: {_one_line(exc)}"
            ) from None
        self.side = spec.side
        self.emulated = match[0].GetModelName() == "Emulation"
        self.identity = CameraIdentity(
            vendor=self._read("DeviceVendorName"),
            model=self._read("DeviceModelName"),
            serial=match[0].GetSerialNumber(),
            firmware=self._read("DeviceFirmwareVersion"),
            user_id=self._read("DeviceUserID"),
        )
        self.counts_exposures = True
        self._bits = 8
        self._exposure: float | None = None
        self._show_dir: Path | None = None
        self._shown = 0
        self._last_shown: Path | None = None
        if self.emulated:  # the emulator's default exposure (µs), as a real camera has one
            v = self._read("ExposureTimeAbs") or self._read("ExposureTime")
            self._exposure = float(v) if v else None
        self._gain: float | None = None

    def _read(self, name: str) -> str:
        node = self.cam.GetNodeMap().GetNode(name)
        try:
            return (
                str(node.GetValue()) if node is not None and self._genicam.IsReadable(node) else ""
            )
        except self._genicam.GenericException:
            return ""

    def _set(self, name: str, value: object) -> bool:
        node = self.cam.GetNodeMap().GetNode(name)
        if node is None or not self._genicam.IsWritable(node):
            return False
        node.SetValue(value)
        return True

    def configure(self, spec: CameraSpec, cfg: CameraConfig, size: tuple[int, int]) -> None:
        g = self._genicam
        try:
            if (self.cam.Width.Value, self.cam.Height.Value) != tuple(size):
                self._set("OffsetX", 0)
                self._set("OffsetY", 0)
                self._set("Width", int(size[0]))
                self._set("Height", int(size[1]))
            self._set("PixelFormat", cfg.pixel_format)
            self._bits = cfg.bits
            for sel in ("FrameStart",):
                self._set("TriggerSelector", sel)
            if cfg.trigger is Trigger.FREE:
                self._set("TriggerMode", "Off")
            else:
                self._set("TriggerMode", "On")
                src = "Software" if cfg.trigger is Trigger.SOFTWARE else cfg.trigger_line
                self._set("TriggerSource", src)
                self._set("TriggerActivation", "RisingEdge")
                if cfg.trigger is not Trigger.SOFTWARE:  # a GPIO line (Line3/4) may be an output
                    self._set("LineSelector", cfg.trigger_line)
                    self._set("LineMode", "Input")
            self._set("ExposureAuto", "Off")
            self._set("GainAuto", "Off")
            if spec.exposure_us is not None:
                self.set_exposure(spec.exposure_us)
            if not (self._set("Gain", spec.gain_db) or self._set("GainAbs", spec.gain_db)):
                pass  # cameras with raw gain only keep theirs
            self._gain = spec.gain_db
            self._set("AcquisitionFrameRateEnable", False)
        except g.GenericException as exc:
            raise HardwareError(f"{self.side} camera refused a setting: {_one_line(exc)}") from None

    def set_exposure(self, exposure_us: float) -> None:
        restart = self.cam.IsGrabbing()
        if restart:
            self.cam.StopGrabbing()
        if not (
            self._set("ExposureTime", float(exposure_us))
            or self._set("ExposureTimeAbs", float(exposure_us))
        ):
            raise HardwareError(f"{self.side} camera: exposure time is not settable")
        self._exposure = float(exposure_us)
        if restart:
            self.start()

    def show_files(self, path: Path) -> None:
        """Emulated camera only: serve the image file ``path`` from the next trigger on."""
        if not self.emulated:
            raise HardwareError("show_files is for pylon's emulated cameras only")
        try:
            self._show_files(path)
        except self._genicam.GenericException as exc:
            raise DeviceLost(self.side, f"{self.side} camera lost: {_one_line(exc)}") from None

    def _show_files(self, path: Path) -> None:
        self.cam.StopGrabbing()
        import cv2  # reads the size of the file the emulator will serve

        h, w = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).shape[:2]
        if (self.cam.Width.Value, self.cam.Height.Value) != (w, h):
            self._set("OffsetX", 0)
            self._set("OffsetY", 0)
            self._set("Width", w)
            self._set("Height", h)
        self._set("TestImageSelector", "Off")
        self._set("ImageFileMode", "On")
        self.cam.ImageFilename.Value = str(path)
        self.start()

    def show(self, image: np.ndarray) -> None:
        """Emulated camera only: put ``image`` (the cell's depth, LSB-aligned) in front of
        it; the next trigger exposes it, bit for bit.  The emulator serves 16-bit files
        MSB-aligned: a 12-bit image goes in shifted left by 4."""
        import cv2  # writes the file the emulator reads

        if self._show_dir is None:
            self._show_dir = Path(tempfile.mkdtemp(prefix="qh-pylon-emu-"))
        self._shown += 1
        path = self._show_dir / f"{self.identity.serial}_{self._shown:06d}.png"
        data = image if self._bits <= 8 else (image.astype(np.uint16) << (16 - self._bits))
        if not cv2.imwrite(str(path), data, [cv2.IMWRITE_PNG_COMPRESSION, 0]):
            raise HardwareError(f"cannot write the emulated {self.side} camera's image")
        self.show_files(path)
        if self._last_shown is not None:
            self._last_shown.unlink(missing_ok=True)
        self._last_shown = path

    @property
    def exposure_us(self) -> float | None:
        return self._exposure

    def start(self) -> None:
        if not self.cam.IsGrabbing():
            self.cam.StartGrabbing(self._pylon.GrabStrategy_OneByOne)

    def stop(self) -> None:
        if self.cam.IsGrabbing():
            self.cam.StopGrabbing()

    def trigger(self) -> None:
        g = self._genicam
        try:
            if self.cam.WaitForFrameTriggerReady(1000, self._pylon.TimeoutHandling_Return):
                self.cam.ExecuteSoftwareTrigger()
            else:
                raise FrameTimeout(self.side, f"{self.side} camera is not ready for a trigger")
        except g.GenericException as exc:
            raise DeviceLost(self.side, f"{self.side} camera lost: {_one_line(exc)}") from None

    def pending(self) -> bool:
        try:
            return int(self.cam.NumReadyBuffers.Value) > 0
        except Exception:  # noqa: BLE001 - a lost device has no queue
            return False

    def retrieve(self, timeout_s: float) -> RawFrame:
        g, pylon = self._genicam, self._pylon
        try:
            res = self.cam.RetrieveResult(
                max(1, int(timeout_s * 1000)), pylon.TimeoutHandling_Return
            )
        except g.GenericException as exc:
            raise DeviceLost(self.side, f"{self.side} camera lost: {_one_line(exc)}") from None
        if res is None or not res.IsValid():
            if self.cam.IsCameraDeviceRemoved():
                raise DeviceLost(self.side, f"{self.side} camera was unplugged or rebooted")
            raise FrameTimeout.after(self.side, timeout_s)
        try:
            t = time.monotonic()
            if not res.GrabSucceeded():
                raise DroppedFrame(
                    self.side,
                    f"{self.side} camera frame {res.GetID()} dropped: {res.GetErrorDescription()}",
                )
            img = to_host_bits(res.GetArray(), self._bits)
            ts = int(res.GetTimeStamp())
            info = FrameInfo(
                frame_id=int(res.GetID()),
                timestamp_ns=ts or None,
                exposure_us=self._exposure,
                gain_db=self._gain,
                temperature_c=self.temperature(),
            )
        finally:
            res.Release()
        return RawFrame(img, info, t)

    def temperature(self) -> float | None:
        for name in ("DeviceTemperature", "TemperatureAbs"):
            v = self._read(name)
            if v:
                try:
                    return float(v)
                except ValueError:
                    return None
        return None

    def close(self) -> None:
        """Stop, close and release the device (a camera opened again later gets a fresh
        one: two InstantCameras on one device must never coexist)."""
        try:
            self.stop()
            self.cam.Close()
        except Exception:  # noqa: BLE001 - closing a lost camera
            pass
        try:
            self.cam.DestroyDevice()
        except Exception:  # noqa: BLE001 - already gone (unplugged)
            pass
        if self._show_dir is not None:
            shutil.rmtree(self._show_dir, ignore_errors=True)
            self._show_dir = None


def open_pylon(cfg: CameraConfig, rig: StereoRig, **kw: Any) -> TriggeredStereoCamera:
    """The stereo pair of ``cfg`` through pypylon (see :class:`~.genicam.TriggeredStereoCamera`
    for ``fire`` and ``prepare``)."""
    return TriggeredStereoCamera(PylonDevice, rig, cfg, **kw)


def _one_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
