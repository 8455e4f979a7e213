"""The triggered stereo pair of two GenICam cameras (pylon and aravis share it).

:class:`TriggeredStereoCamera` drives two :class:`GenICamDevice` adapters: one event
triggers both (a software trigger sent to each camera back to back, the robot's digital
output on both cameras' trigger line, or an external master), and every pair is checked
before anyone measures it:

1. frames waiting *before* the trigger were exposed by an edge nobody asked for: they are
   discarded and the pair counts as out of step (recaptured);
2. each camera must deliver within ``timeout_s`` of the trigger, else a
   :class:`FrameTimeout` (a missing edge, an unplugged or rebooting camera);
3. an incomplete frame (lost packets) is a dropped frame: recaptured;
4. each camera's frame counter must advance by exactly one per trigger, and the two
   cameras' timestamps (where they report them) must keep their offset within
   ``max_skew_s``: else the pair is out of step and recaptured;
5. a frame already waiting *after* the pair means a camera exposed twice: recaptured.

After ``attempts`` captures without a good pair the capture raises a HardwareError in one
line (what, which camera, what to do); the run then stops cleanly and ``--resume``
continues.  A camera that stopped answering (unplugged, rebooting) is reopened by serial
number on the next capture, so a resumed run finds it again.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from ....identify.errors import HardwareError
from ....vision.camera import StereoRig
from . import CameraIdentity, FrameInfo, Image, StereoFrame
from .config import CameraConfig, CameraSpec, Trigger

log = logging.getLogger(__name__)


class CameraFault(HardwareError):
    """A camera did not deliver a usable frame (``camera``: left or right)."""

    def __init__(self, camera: str, message: str) -> None:
        super().__init__(message)
        self.camera = camera


class FrameTimeout(CameraFault):
    """No frame within the time-out after a trigger."""

    @classmethod
    def after(cls, camera: str, timeout_s: float) -> FrameTimeout:
        """The one line for ``camera`` (left or right) silent for ``timeout_s``."""
        return cls(
            camera,
            f"no frame from the {camera} camera within {timeout_s * 1e3:.0f} ms of the "
            "trigger (a missing trigger edge?)",
        )


class DeviceLost(CameraFault):
    """The camera is gone (unplugged, rebooting, powered off)."""


class DroppedFrame(CameraFault):
    """The frame arrived incomplete (lost packets) or was reported failed."""


@dataclass(frozen=True)
class RawFrame:
    """One frame as a device adapter returns it."""

    image: Image
    info: FrameInfo
    t_host: float  # time.monotonic() when it was received


class GenICamDevice(Protocol):
    """One GenICam camera as :class:`TriggeredStereoCamera` needs it (an SDK adapter)."""

    identity: CameraIdentity
    #: Its frame counter counts exposures and its timestamps mark them (a real camera's do;
    #: Aravis' fake cameras count clock ticks): the pair check uses them only then.
    counts_exposures: bool

    def configure(self, spec: CameraSpec, cfg: CameraConfig, size: tuple[int, int]) -> None:
        """Image size (the calibration's, px), pixel format, exposure, gain, trigger mode and
        source."""
        ...

    def start(self) -> None:
        """Start acquisition: from now on each trigger exposes one frame."""
        ...

    def stop(self) -> None: ...

    def trigger(self) -> None:
        """A software trigger."""
        ...

    def retrieve(self, timeout_s: float) -> RawFrame:
        """The next frame; FrameTimeout, DroppedFrame or DeviceLost."""
        ...

    def pending(self) -> bool:
        """A frame is waiting to be retrieved."""
        ...

    def set_exposure(self, exposure_us: float) -> None: ...

    def close(self) -> None: ...


class TriggeredStereoCamera:
    """Two GenICam cameras triggered as one stereo pair (see the module docstring).

    Parameters
    ----------
    open_device : callable
        ``open_device(spec) -> GenICamDevice``: opens (or reopens) one camera by its id.
    rig : StereoRig
    cfg : CameraConfig
    fire : callable, optional
        Makes the edge on the trigger line (``Trigger.LINE``: the robot's digital output,
        :class:`~quickhealth.station.hardware.line_trigger.LineTrigger`); what it returns (the
        edge as the robot confirmed it) goes into the frame's ``meta["edge"]``.
    prepare : callable, optional
        Called before each trigger (the simulated cell puts the scene in front of the
        emulated cameras here).
    wrap_open : callable, optional
        Wraps ``open_device`` (the simulated cell's emulated bus, where a camera can be
        unplugged).
    """

    def __init__(
        self,
        open_device: Callable[[CameraSpec], GenICamDevice],
        rig: StereoRig,
        cfg: CameraConfig,
        *,
        fire: Callable[[], dict[str, Any] | None] | None = None,
        prepare: Callable[[tuple[GenICamDevice, GenICamDevice]], None] | None = None,
        wrap_open: Callable[
            [Callable[[CameraSpec], GenICamDevice]], Callable[[CameraSpec], GenICamDevice]
        ]
        | None = None,
    ) -> None:
        if cfg.trigger is Trigger.LINE and fire is None:
            raise HardwareError(
                "cameras: trigger = 'line' needs the robot's digital output to fire it"
            )
        self.rig = rig
        self.cfg = cfg
        self._open = open_device if wrap_open is None else wrap_open(open_device)
        self._fire = fire
        self._prepare = prepare
        self._devices: list[GenICamDevice | None] = [None, None]
        self._last_id: list[int | None] = [None, None]
        self._offset_ns: int | None = None
        self.stats = {"pairs": 0, "out_of_step": 0, "dropped": 0, "timeouts": 0, "reopened": 0}
        try:
            for i in range(2):
                self._device(i)
        except BaseException:
            self.close()
            raise
        self.identities = tuple(d.identity for d in self._devices if d is not None)
        #: The cell leaves the exposure to the search at the first pose (:mod:`...run.exposure`).
        self.auto_exposure = any(c.exposure_us is None for c in cfg.cameras)

    # -- devices ------------------------------------------------------------------------
    def _device(self, i: int) -> GenICamDevice:
        dev = self._devices[i]
        if dev is None:
            spec = self.cfg.cameras[i]
            dev = self._open(spec)
            try:
                dev.configure(spec, self.cfg, self.rig.cameras[i].image_size)
                dev.start()
            except BaseException:
                dev.close()
                raise
            self._devices[i] = dev
            self._last_id[i] = None
            self._offset_ns = None
        return dev

    def _drop_device(self, i: int) -> None:
        dev, self._devices[i] = self._devices[i], None
        if dev is not None:
            try:
                dev.close()
            except Exception:  # noqa: BLE001 - it is gone already
                pass

    @property
    def devices(self) -> tuple[GenICamDevice, GenICamDevice]:
        return (self._device(0), self._device(1))

    @property
    def exposure_us(self) -> float | None:
        """The left camera's exposure now (µs; None: it does not say)."""
        return getattr(self.devices[0], "exposure_us", None)

    def set_exposure(self, exposure_us: float) -> None:
        """Both cameras' exposure (µs), e.g. as the exposure search found it; a camera opened
        again (after a fault) gets it too."""
        for dev in self.devices:
            dev.set_exposure(exposure_us)
        e = float(exposure_us)
        self.cfg = replace(
            self.cfg,
            left=replace(self.cfg.left, exposure_us=e),
            right=replace(self.cfg.right, exposure_us=e),
        )

    # -- one pair -----------------------------------------------------------------------
    def capture(self) -> StereoFrame:
        problems: list[str] = []
        for _ in range(self.cfg.attempts):
            try:
                devs = self.devices  # reopens a camera that was lost
            except HardwareError as exc:
                problems.append(str(exc))
                self.stats["reopened"] += 1
                time.sleep(min(self.cfg.timeout_s, 0.5))
                continue
            got = self._one_pair(devs, problems)
            if got is not None:
                self.stats["pairs"] += 1
                return got
        last = problems[-1] if problems else "no pair"
        for i in range(2):  # opened and configured again at the next capture (a camera that
            self._drop_device(i)  # rebooted has lost its settings)
        raise HardwareError(
            f"cameras gave no good stereo pair in {self.cfg.attempts} attempts ({last}): "
            "check the cameras' cables, power and trigger wiring, then rerun with --resume"
        )

    def _one_pair(
        self, devs: tuple[GenICamDevice, GenICamDevice], problems: list[str]
    ) -> StereoFrame | None:
        cfg = self.cfg
        try:
            if self._prepare is not None:
                self._prepare(devs)
            stray = self._drain(devs)
            if any(getattr(d, "free_running", False) for d in devs):
                stray = 0  # frames come by themselves: a waiting one is no evidence
            t_trig = time.monotonic()
            edge = None
            if cfg.trigger is Trigger.SOFTWARE:
                for d in devs:
                    d.trigger()
            elif cfg.trigger is Trigger.LINE:
                assert self._fire is not None
                edge = self._fire()  # a refused pulse (the arm not at rest) stops the capture
        except DeviceLost as exc:
            problems.append(str(exc))
            self._drop_device(0 if exc.camera == "left" else 1)
            return None
        if stray:
            self.stats["out_of_step"] += 1
            problems.append(f"{stray} stray frame(s) before the trigger: pair out of step")
            self._resync()
        frames: list[RawFrame | None] = [None, None]
        for i, d in enumerate(devs):
            try:
                frames[i] = d.retrieve(cfg.timeout_s)
            except FrameTimeout as exc:
                self.stats["timeouts"] += 1
                problems.append(str(exc))
            except DroppedFrame as exc:
                self.stats["dropped"] += 1
                problems.append(str(exc))
            except DeviceLost as exc:
                problems.append(str(exc))
                self._drop_device(i)
        if frames[0] is None or frames[1] is None:
            if (frames[0] is None) != (frames[1] is None):
                self._resync()  # one camera exposed, the other did not: counters disagree
            return None
        fl, fr = frames[0], frames[1]
        why = self._out_of_step(devs, fl, fr)
        if why:
            self.stats["out_of_step"] += 1
            problems.append(why)
            self._resync()
            return None
        self._last_id = [fl.info.frame_id, fr.info.frame_id]
        return StereoFrame(
            fl.image,
            fr.image,
            fl.t_host,
            fr.t_host,
            {
                "trigger_to_frame_s": max(fl.t_host, fr.t_host) - t_trig,
                "attempt_problems": problems[:],
                **({"edge": edge} if edge else {}),
            },
            bits=cfg.bits,
            trigger=cfg.trigger.value,
            info=(fl.info, fr.info),
        )

    def _drain(self, devs: tuple[GenICamDevice, GenICamDevice]) -> int:
        n = 0
        for d in devs:
            while d.pending():
                try:
                    d.retrieve(0.05)
                except HardwareError:
                    break
                n += 1
        return n

    def _resync(self) -> None:
        self._last_id = [None, None]
        self._offset_ns = None

    def _out_of_step(
        self, devs: tuple[GenICamDevice, GenICamDevice], fl: RawFrame, fr: RawFrame
    ) -> str:
        if not all(getattr(d, "counts_exposures", True) for d in devs):
            return self._extra_frame(devs)
        for side, last, f in (("left", self._last_id[0], fl), ("right", self._last_id[1], fr)):
            fid = f.info.frame_id
            if last is not None and fid is not None and not _next_id(last, fid):
                return (
                    f"{side} camera frame {fid} after {last}: a frame was skipped, pair out of step"
                )
        tl, tr = fl.info.timestamp_ns, fr.info.timestamp_ns
        if tl and tr:
            off = tl - tr
            if (
                self._offset_ns is not None
                and abs(off - self._offset_ns) > self.cfg.max_skew_s * 1e9
            ):
                return (
                    f"the cameras' clocks moved {abs(off - self._offset_ns) / 1e6:.3f} ms apart "
                    "between two pairs: pair out of step"
                )
            self._offset_ns = off
        return self._extra_frame(devs)

    def _extra_frame(self, devs: tuple[GenICamDevice, GenICamDevice]) -> str:
        if any(getattr(d, "free_running", False) for d in devs):
            return ""
        if any(d.pending() for d in devs):
            self._drain(devs)
            return "a camera delivered an extra frame: pair out of step"
        return ""

    def close(self) -> None:
        for i in range(2):
            dev = self._devices[i]
            if dev is not None:
                try:
                    dev.stop()
                except Exception:  # noqa: BLE001 - closing anyway
                    pass
            self._drop_device(i)


def _next_id(last: int, fid: int) -> bool:
    """``fid`` follows ``last`` (GigE Vision's 16-bit block ids wrap to 1, skipping 0)."""
    return fid == last + 1 or (last == 0xFFFF and fid in (0, 1))


def to_host_bits(image: np.ndarray, bits: int) -> Image:
    """An SDK's image as the station keeps it: uint8 at 8 bits, uint16 LSB-aligned above."""
    if bits <= 8:
        return np.ascontiguousarray(image, dtype=np.uint8)
    return np.ascontiguousarray(image, dtype=np.uint16)
