"""Stereo cameras: the :class:`StereoCamera` interface and its backends.

A camera implements :class:`StereoCamera`: ``capture()`` returns a :class:`StereoFrame` (two
grey images of the cameras' bit depth, 8 to 16 bits, each with its capture time and what the
cameras reported about it) and ``rig`` is the calibrated
:class:`~quickhealth.vision.camera.StereoRig` the measurement uses; ``identities`` names the
cameras (vendor, model, serial number, firmware) for the run's records.

Backends, one module each, chosen by name (:mod:`.registry`; the cell file's ``[cameras]``
section or ``--cameras``, :mod:`.config`):

- ``pylon`` (:mod:`.pylon`): Basler cameras through pypylon;
- ``aravis`` (:mod:`.aravis`): any GigE Vision / USB3 Vision camera through Aravis;
- ``opencv`` (:mod:`.opencv`): webcams through ``cv2.VideoCapture``;
- ``files`` (:mod:`.files`): a recorded image folder, for offline runs.

The two GenICam backends share the triggered pair (:mod:`.genicam`): one event triggers both
cameras, and each pair is checked for synchrony before it is measured.

The simulated pair (rendered images of the digital twin's true poses) is
:class:`quickhealth.station.sim.cameras.SimStereoCamera`: real hardware never imports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ....vision.camera import StereoRig

F = NDArray[np.float64]
Image = NDArray[np.uint8] | NDArray[np.uint16]


@dataclass(frozen=True)
class CameraIdentity:
    """Who a camera is, as its SDK reports it."""

    vendor: str = ""
    model: str = ""
    serial: str = ""
    firmware: str = ""
    user_id: str = ""

    def describe(self) -> str:
        """``Basler acA2440-20gm s/n 40012345 fw 1.2``."""
        words = [w for w in (self.vendor, self.model) if w]
        if self.serial:
            words.append(f"s/n {self.serial}")
        if self.firmware:
            words.append(f"fw {self.firmware}")
        return " ".join(words) or "unknown camera"

    def to_json(self) -> dict[str, str]:
        return {k: v for k, v in self.__dict__.items() if v}


@dataclass(frozen=True)
class FrameInfo:
    """What one camera reported about one frame (None: the camera does not report it).

    Attributes
    ----------
    frame_id : int or None
        The camera's frame counter.
    timestamp_ns : int or None
        The camera's clock at exposure (ns; comparable between the two cameras only when they
        share a clock, e.g. PTP).
    exposure_us, gain_db, temperature_c : float or None
    """

    frame_id: int | None = None
    timestamp_ns: int | None = None
    exposure_us: float | None = None
    gain_db: float | None = None
    temperature_c: float | None = None

    def to_json(self) -> dict[str, float | int]:
        return {k: v for k, v in self.__dict__.items() if v is not None}


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One stereo capture.

    Attributes
    ----------
    left, right : ndarray (h, w) uint8 or uint16
        Grey images; uint16 holds ``bits`` significant bits (LSB-aligned: a 12-bit camera's
        white is 4095).
    t_left, t_right : float
        Capture times, s (``time.monotonic`` clock of this computer).
    meta : dict
        Extra facts (device names, skew, recaptures).
    bits : int
        Significant bits per pixel (8 for uint8 images).
    trigger : str
        What triggered the pair (``software``, ``line``, ``external``, ``free``).
    info : (FrameInfo, FrameInfo)
        What each camera reported about its frame.
    """

    left: Image
    right: Image
    t_left: float
    t_right: float
    meta: dict[str, Any] = field(default_factory=dict)
    bits: int = 8
    trigger: str = "free"
    info: tuple[FrameInfo, FrameInfo] = (FrameInfo(), FrameInfo())

    @property
    def time(self) -> float:
        """Mid-point of the two capture times, s."""
        return 0.5 * (self.t_left + self.t_right)

    @property
    def skew(self) -> float:
        """Time between the two captures, s."""
        return abs(self.t_right - self.t_left)

    @property
    def full_scale(self) -> int:
        """The white level (255 at 8 bits, 4095 at 12)."""
        return (1 << self.bits) - 1


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


def identities(camera: object) -> tuple[CameraIdentity, ...]:
    """The cameras' identities when the backend reports them (empty otherwise)."""
    got = getattr(camera, "identities", ())
    return tuple(got) if got else ()
