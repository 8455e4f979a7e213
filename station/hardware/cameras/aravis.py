"""Any GigE Vision or USB3 Vision camera through Aravis (``--cameras aravis``).

:func:`open_aravis` returns a :class:`~.genicam.TriggeredStereoCamera` on two
:class:`AravisDevice` adapters (GObject introspection: ``gi.repository.Aravis`` 0.8, the
Debian packages ``gir1.2-aravis-0.8`` and ``aravis-tools``, PyGObject in the venv:
``make aravis``).  A camera is found by serial number, user id or Aravis device id
(``Basler-40012345``) after :func:`Aravis.update_device_list` — without that call a camera
opens but its stream never delivers; without ids, the first two cameras by serial number.

Aravis' fake cameras (the in-process ``Fake`` interface, or ``arv-fake-gv-camera-0.8`` on
loopback: two need two addresses, two on 127.0.0.1 collide silently) speak the same
protocol; they have Mono8 and Mono16, no Mono12.  :class:`FakeScreen` puts an image in front
of an in-process fake camera (its fill-pattern callback), for the simulated cell.
"""

from __future__ import annotations

import atexit
import ctypes
import time
import weakref
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

N_BUFFERS = 4


def _aravis() -> Any:
    try:
        import gi  # PyGObject: `make aravis` builds it against the system's introspection

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise HardwareError(
            f"--cameras aravis needs Aravis 0.8 and PyGObject ({exc}): "
            "apt-get install gir1.2-aravis-0.8, then make aravis"
        ) from None
    return Aravis


def list_devices() -> list[tuple[str, CameraIdentity]]:
    """Every camera Aravis sees: (device id, identity), by serial number."""
    Aravis = _aravis()
    Aravis.update_device_list()
    out = []
    for i in range(Aravis.get_n_devices()):
        out.append(
            (
                Aravis.get_device_id(i),
                CameraIdentity(
                    vendor=Aravis.get_device_vendor(i) or "",
                    model=Aravis.get_device_model(i) or "",
                    serial=Aravis.get_device_serial_nbr(i) or "",
                ),
            )
        )
    return sorted(out, key=lambda d: d[1].serial)


class AravisDevice:
    """One camera through Aravis (a :class:`~.genicam.GenICamDevice`).

    ``camera``: an ``Aravis.Camera`` already made (the simulated cell's fake cameras);
    otherwise the camera ``spec`` names is looked up and opened."""

    def __init__(self, spec: CameraSpec, camera: Any = None) -> None:
        Aravis = self._A = _aravis()
        self.side = spec.side
        self.screen: FakeScreen | None = None
        if camera is None:
            devices = list_devices()
            if spec.id:
                match = [d for d, c in devices if spec.id in (d, c.serial, c.user_id)]
            else:
                match = [d for d, _ in devices][spec.index : spec.index + 1]
            if not match:
                seen = ", ".join(d for d, _ in devices) or "none"
                raise DeviceLost(
                    spec.side,
                    f"{spec.side} camera {spec.id or '#' + str(spec.index)} not found by Aravis "
                    f"(cameras seen: {seen}): check its cable and power",
                )
            try:
                camera = Aravis.Camera.new(match[0])
            except Exception as exc:  # noqa: BLE001 - GLib.Error: one line
                raise DeviceLost(spec.side, f"{spec.side} camera does not open: {exc}") from None
        self.cam = camera
        dev = camera.get_device()
        self.identity = CameraIdentity(
            vendor=camera.get_vendor_name() or "",
            model=camera.get_model_name() or "",
            serial=camera.get_device_serial_number() or "",
            firmware=_feature(dev, "DeviceFirmwareVersion") or _feature(dev, "DeviceVersion"),
            user_id=_feature(dev, "DeviceUserID"),
        )
        # Aravis' fake cameras number their frames by clock tick, not by exposure
        fake = self.identity.vendor == "Aravis" and self.identity.model == "Fake"
        self.counts_exposures = not fake
        #: Frames come without a trigger: Aravis 0.8's in-process fake stream ignores the
        #: trigger mode (its GigE Vision fake honours it), so the pair check cannot take a
        #: frame waiting in the queue as evidence of a stray edge.
        self.free_running = fake and self.cam.get_device().__class__.__name__ == "FakeDevice"
        self.stream: Any = None
        self._bits = 8
        self._exposure: float | None = None
        self._gain: float | None = None

    @property
    def exposure_us(self) -> float | None:
        return self._exposure

    def configure(self, spec: CameraSpec, cfg: CameraConfig, size: tuple[int, int]) -> None:
        fmt = cfg.pixel_format
        try:
            formats = self.cam.dup_available_pixel_formats_as_strings()
            if fmt not in formats:
                raise HardwareError(
                    f"{self.side} camera has no {fmt} (it has {', '.join(formats)})"
                )
            self.cam.set_pixel_format_from_string(fmt)
            self._bits = cfg.bits
            self.cam.set_region(0, 0, size[0], size[1])
            if cfg.trigger is Trigger.FREE:
                self.cam.clear_triggers()
            elif cfg.trigger is Trigger.SOFTWARE:
                self.cam.set_trigger("Software")
            else:
                self.cam.set_trigger(cfg.trigger_line)
            if spec.exposure_us is not None:
                self.set_exposure(spec.exposure_us)
            else:
                self._exposure = float(self.cam.get_exposure_time())
            if self.cam.is_gain_available():
                self.cam.set_gain(spec.gain_db)
                self._gain = spec.gain_db
        except HardwareError:
            raise
        except Exception as exc:  # noqa: BLE001 - GLib.Error: one line
            raise HardwareError(f"{self.side} camera refused a setting: {exc}") from None

    def set_exposure(self, exposure_us: float) -> None:
        self.cam.set_exposure_time(float(exposure_us))
        self._exposure = float(exposure_us)

    def start(self) -> None:
        if self.stream is not None:
            return
        try:
            self.stream = self.cam.create_stream(None, None)
            size = self.cam.get_payload()
            for _ in range(N_BUFFERS):
                self.stream.push_buffer(self._A.Buffer.new_allocate(size))
            self.cam.start_acquisition()
        except Exception as exc:  # noqa: BLE001 - GLib.Error
            raise DeviceLost(self.side, f"{self.side} camera does not stream: {exc}") from None

    def stop(self) -> None:
        if self.stream is not None:
            try:
                self.cam.stop_acquisition()
            except Exception:  # noqa: BLE001 - a lost camera
                pass
            self.stream = None

    def trigger(self) -> None:
        try:
            self.cam.software_trigger()
        except Exception as exc:  # noqa: BLE001 - GLib.Error
            raise DeviceLost(self.side, f"{self.side} camera lost: {exc}") from None

    def pending(self) -> bool:
        if self.stream is None:
            return False
        _, n_out = self.stream.get_n_buffers()
        return n_out > 0

    def retrieve(self, timeout_s: float) -> RawFrame:
        if self.stream is None:
            raise DeviceLost(self.side, f"{self.side} camera is not streaming")
        deadline = time.monotonic() + timeout_s
        while True:
            left_us = max(1, int((deadline - time.monotonic()) * 1e6))
            buf = self.stream.timeout_pop_buffer(left_us)
            if buf is None or self.screen is None or self.screen.current(buf.get_frame_id()):
                break
            self.stream.push_buffer(buf)  # a fake camera's frame of the image shown before
        if buf is None:
            raise FrameTimeout.after(self.side, timeout_s)
        try:
            t = time.monotonic()
            status = buf.get_status()
            if status != self._A.BufferStatus.SUCCESS:
                raise DroppedFrame(
                    self.side,
                    f"{self.side} camera frame {buf.get_frame_id()} dropped ({status.value_nick})",
                )
            w, h = buf.get_image_width(), buf.get_image_height()
            dtype = np.uint8 if self._bits <= 8 else np.uint16
            raw = np.frombuffer(buf.get_data(), dtype=dtype)
            if raw.size < w * h:
                raise DroppedFrame(self.side, f"{self.side} camera frame arrived short")
            img = to_host_bits(raw[: w * h].reshape(h, w).copy(), self._bits)
            info = FrameInfo(
                frame_id=int(buf.get_frame_id()),
                timestamp_ns=int(buf.get_timestamp()) or None,
                exposure_us=self._exposure,
                gain_db=self._gain,
                temperature_c=self.temperature(),
            )
        finally:
            self.stream.push_buffer(buf)
        return RawFrame(img, info, t)

    def temperature(self) -> float | None:
        dev = self.cam.get_device()
        for name in ("DeviceTemperature",):
            try:
                if dev.is_feature_available(name):
                    return float(dev.get_float_feature_value(name))
            except Exception:  # noqa: BLE001 - not readable on this camera
                return None
        return None

    def show(self, image: np.ndarray) -> None:
        """An in-process fake camera only: serve ``image`` from the next trigger on."""
        if self.screen is None:
            raise HardwareError("show() is for Aravis' in-process fake cameras only")
        self.screen.show(image)

    def close(self) -> None:
        if self.screen is not None:
            self.screen.detach()
        self.stop()
        self.cam = None


def _feature(dev: Any, name: str) -> str:
    try:
        if dev.is_feature_available(name):
            return str(dev.get_string_feature_value(name) or "")
    except Exception:  # noqa: BLE001 - not on this camera
        pass
    return ""


def open_aravis(cfg: CameraConfig, rig: StereoRig, **kw: Any) -> TriggeredStereoCamera:
    """The stereo pair of ``cfg`` through Aravis (``fire``, ``prepare``, ``wrap_open``: as
    :class:`~.genicam.TriggeredStereoCamera` takes them)."""
    return TriggeredStereoCamera(AravisDevice, rig, cfg, **kw)


# ---------------------------------------------------------------------------------------
# Aravis' in-process fake cameras, fed an image
# ---------------------------------------------------------------------------------------

_FILL = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32
)
#: ArvBuffer's private part (Aravis 0.8): ``received_size`` (size_t) at this offset; the fill
#: callback must set it, as Aravis' own test pattern does.  Checked on every fake camera made.
_PRIV_OFFSET, _RECEIVED_OFFSET = 24, 48


_LIVE: weakref.WeakSet[FakeScreen] = weakref.WeakSet()


@atexit.register
def _detach_all() -> None:
    """Before the interpreter goes: no fake camera calls back into it."""
    for screen in list(_LIVE):
        screen.detach()


def _lib() -> ctypes.CDLL:
    lib = ctypes.CDLL("libaravis-0.8.so.0")
    lib.arv_buffer_get_data.restype = ctypes.c_void_p
    lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL, ctypes.c_void_p]
    lib.arv_fake_camera_set_fill_pattern.restype = None
    lib.arv_buffer_get_frame_id.restype = ctypes.c_uint64
    lib.arv_buffer_get_frame_id.argtypes = [ctypes.c_void_p]
    return lib


def _address(obj: Any) -> int:
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype = ctypes.c_void_p
    get.argtypes = [ctypes.py_object, ctypes.c_char_p]
    return int(get(obj.__gpointer__, None))


class FakeScreen:
    """The image in front of one in-process Aravis fake camera (``Aravis.FakeDevice``).

    Aravis fills a fake camera's frames through a callback; PyGObject frees the callback as
    soon as it is set (its annotation is ``scope call``), so it is set through ``ctypes`` and
    kept here.  The callback copies the image shown into the frame and sets the frame's
    received size, as Aravis' own pattern does."""

    def __init__(self, serial: str) -> None:
        Aravis = _aravis()
        self._lib = _lib()
        self.generation = 0  # images shown so far
        self._frames: dict[int, int] = {}  # frame id -> the generation it shows
        self.device = Aravis.FakeDevice.new(serial)
        self.fake = self.device.get_fake_camera()
        self.image: np.ndarray | None = None
        self._cb = _FILL(self._fill)
        self._lib.arv_fake_camera_set_fill_pattern(_address(self.fake), self._cb, None)
        _LIVE.add(self)

    def detach(self) -> None:
        """Aravis' own pattern again: no call into Python from its stream thread any more
        (a fake camera stopped or collected while our callback waits for the interpreter
        would deadlock or abort)."""
        self._lib.arv_fake_camera_set_fill_pattern(_address(self.fake), _FILL(), None)
        _LIVE.discard(self)

    def camera(self) -> Any:
        return _aravis().Camera.new_with_device(self.device)

    def show(self, image: np.ndarray) -> None:
        self.image = np.ascontiguousarray(image)
        self.generation += 1

    def current(self, frame_id: int) -> bool:
        """The frame shows the image shown last (not one filled before it)."""
        return self._frames.get(int(frame_id)) == self.generation

    def _fill(self, buffer: int, data: int, exposure: int, gain: int, fmt: int) -> None:
        img, gen = self.image, self.generation
        if img is None:
            return
        fid = int(self._lib.arv_buffer_get_frame_id(buffer))
        self._frames[fid] = gen
        if len(self._frames) > 256:
            self._frames.pop(next(iter(self._frames)))
        size = ctypes.c_size_t()
        dst = self._lib.arv_buffer_get_data(buffer, ctypes.byref(size))
        priv = ctypes.c_void_p.from_address(buffer + _PRIV_OFFSET).value
        allocated = ctypes.c_size_t.from_address(priv).value
        n = min(img.nbytes, allocated)
        ctypes.memmove(dst, img.ctypes.data, n)
        ctypes.c_size_t.from_address(priv + _RECEIVED_OFFSET).value = n
