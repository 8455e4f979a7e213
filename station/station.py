"""The station: the cell's hardware and nominal geometry, as a run needs it.

:class:`Station` holds the robot, the pan motor and the stereo camera (each behind its
interface and, but for the robot, behind one owner thread: :mod:`.hardware.owner`), the smart
target and the self-check board, and where the cell file puts them.  :func:`real_station`
assembles it on real hardware; the simulated cell (:mod:`.sim.cell`) assembles the same class
on its simulators.

SYNOPSIS
    >>> config = HardwareConfig.from_options("cell.toml", robot_ip="192.168.0.10",
    ...     cameras="pylon", calibration="cal.json")                     # doctest: +SKIP
    >>> station = real_station(config)                                    # doctest: +SKIP
    >>> station.close()                                                   # doctest: +SKIP
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..identify.errors import InputError
from ..identify.robot import builtin_robot
from ..identify.transforms import inv_T
from ..vision.boards import TargetDescription
from .formats.vision import read_rig
from .hardware.cameras import CameraIdentity, StereoCamera
from .hardware.cameras import identities as camera_identities
from .hardware.cameras.config import CameraConfig
from .hardware.cameras.config import choose as choose_cameras
from .hardware.cameras.registry import open_cameras
from .hardware.line_trigger import line_trigger
from .hardware.motor import PanMotor, SerialPanMotor
from .hardware.owner import DeviceOwner, owned
from .hardware.robot import Robot, UrRobot
from .hardware.target import T_target_plate, reference_board, reference_target
from .planning.cell import Cell, load_cell

F = NDArray[np.float64]
log = logging.getLogger(__name__)
DEVICE_CLOSE_TIMEOUT_S = 5.0  # s a device's owner may take to finish its jobs and close it


@dataclass
class Station:
    """The cell's hardware and nominal geometry, as a run needs it.

    Attributes
    ----------
    robot, motor, camera :
        Behind :class:`~.hardware.robot.Robot`, :class:`~.hardware.motor.PanMotor`,
        :class:`~.hardware.cameras.StereoCamera`.
    target : TargetDescription
        The smart target's printed plate.
    T_instr_base : ndarray (4, 4)
        Nominal robot base in the instrument frame (for the search regions).
    T_flange_target : ndarray (4, 4)
        Nominal target frame (pan 0) on the flange.
    board : TargetDescription or None
        The self-check board (None: no self-check).
    T_instr_board : ndarray (4, 4) or None
        Its nominal pose (search region).
    cell_name, cell_sha256 : str
        The cell this station is (pre-flight checks the plan against it).
    spec_mm : float or None
        The cell's accuracy spec (``spec_mm``: the TCP error the application accepts, mm),
        which every run records for its verdict; None when the cell states none.
    instrument : str
        For the CSV metadata.
    camera_ids : tuple of CameraIdentity
        The cameras that take the images (vendor, model, serial number, firmware) for the
        run's records; empty when the backend does not say.
    """

    robot: Robot
    motor: PanMotor
    camera: StereoCamera
    target: TargetDescription
    T_instr_base: F
    T_flange_target: F
    board: TargetDescription | None = None
    T_instr_board: F | None = None
    cell_name: str = ""
    cell_sha256: str = ""
    spec_mm: float | None = None
    instrument: str = "stereo camera"
    robot_name: str = ""
    closers: list[Callable[[], None]] = field(default_factory=list)
    camera_ids: tuple[CameraIdentity, ...] = ()

    def __post_init__(self) -> None:
        if not self.camera_ids:
            self.camera_ids = camera_identities(self.camera)
        # One owner per device: the run, the pre-flight and the TUI's polls all go through a
        # worker thread and its queue (the robot's owner is its client process).
        self.motor = owned(self.motor, "pan motor")
        self.camera = owned(self.camera, "stereo camera")

    def predicted_plate(self, q: F, pan: float) -> F:
        """Nominal ``T_instr_plate`` at joints ``q`` and pan angle ``pan``."""
        return (
            self.T_instr_base @ self.robot.model.fk(q) @ self.T_flange_target @ T_target_plate(pan)
        )

    def close(self) -> None:
        """Release all hardware (robot last: it stops the arm).

        The pan motor and the camera are closed by their owners' workers, never from here: a
        worker still inside its device after :data:`DEVICE_CLOSE_TIMEOUT_S` leaves the device
        open (a warning says which), and a closer that would close such a device directly
        (``motor.close`` in ``closers``) is skipped."""
        owners = [d for d in (self.motor, self.camera) if isinstance(d, DeviceOwner)]
        for dev in owners:
            try:
                closed = dev.close(DEVICE_CLOSE_TIMEOUT_S)
            except Exception as exc:  # noqa: BLE001 - keep closing the rest
                log.warning("closing the %s failed: %s", dev.name, exc)
                continue
            if not closed:
                inside = dev.busy()
                log.warning(
                    "the %s is still inside %s() after %.0f s: left open (its owner thread "
                    "alone may touch it; the process exit releases it)",
                    dev.name,
                    inside[0] if inside else "a call",
                    DEVICE_CLOSE_TIMEOUT_S,
                )
        for f in reversed(self.closers):
            if any(getattr(f, "__self__", None) is dev.device for dev in owners):
                continue  # that device was closed by its owner (or is left to it)
            try:
                f()
            except Exception:  # noqa: BLE001 - keep closing the rest
                pass
        self.closers.clear()


@dataclass(frozen=True)
class HardwareConfig:
    """The cell's hardware as every door configures it: built once from the cell file and the
    command line's options (:meth:`from_options`), then given to :func:`real_station` or to
    the simulated cell (:func:`quickhealth.station.sim.cell.sim_station`).

    Attributes
    ----------
    cell : Cell
        The cell file, loaded and checked.
    cameras : CameraConfig
        The stereo pair: the cell's ``[cameras]`` section changed by ``--cameras``.
    robot_ip : str or None
        The UR controller (None: the simulated cell).
    motor_port : str
        The pan motor's serial port.
    calibration : Path or None
        The stereo calibration (real cameras).
    robot_name : str or None
        The robot's name in the journal and the archive.
    """

    cell: Cell
    cameras: CameraConfig
    robot_ip: str | None = None
    motor_port: str = "/dev/ttyUSB0"
    calibration: Path | None = None
    robot_name: str | None = None

    @property
    def simulated(self) -> bool:
        return self.robot_ip is None

    @classmethod
    def from_options(
        cls,
        cell: str | Cell,
        *,
        robot_ip: str | None = None,
        motor_port: str | None = None,
        cameras: str | None = None,
        calibration: str | Path | None = None,
        robot_name: str | None = None,
    ) -> HardwareConfig:
        """The configuration of the doors' options (``--robot-ip``, ``--motor-port``,
        ``--cameras``, ``--calibration``): one line (InputError) for what cannot work."""
        c = cell if isinstance(cell, Cell) else load_cell(cell)
        cams = choose_cameras(c.cameras, cameras)
        if robot_ip is not None and calibration is None:
            raise InputError(
                "--robot-ip needs --calibration CAL.json (quickhealth vision calibrate)"
            )
        return cls(
            cell=c,
            cameras=cams,
            robot_ip=robot_ip,
            motor_port=motor_port or "/dev/ttyUSB0",
            calibration=None if calibration is None else Path(calibration),
            robot_name=robot_name,
        )


def real_station(config: HardwareConfig) -> Station:
    """A :class:`Station` on real hardware: UR robot, serial pan motor, the configured stereo
    pair (any backend of :mod:`.hardware.cameras.registry`)."""
    c = config.cell
    if config.robot_ip is None or config.calibration is None:
        raise InputError("a real station needs --robot-ip and --calibration")
    rig = read_rig(config.calibration)
    closers: list[Callable[[], None]] = []
    try:
        arm = builtin_robot(c.robot.name)  # the cell's arm with its own limits; its stream rate
        robot = UrRobot(config.robot_ip, model=arm, frequency=arm.control_hz or 125.0)
        closers.append(robot.close)
        motor = SerialPanMotor(config.motor_port)
        closers.append(motor.close)
        # trigger = "line": the robot's digital output fires both cameras
        camera = open_cameras(config.cameras, rig, fire=line_trigger(robot, config.cameras))
        closers.append(camera.close)
    except BaseException:
        for f in reversed(closers):
            f()
        raise
    return Station(
        robot=robot,
        motor=motor,
        camera=camera,
        target=reference_target(),
        T_instr_base=inv_T(c.T_world_cam_left) @ c.T_world_base,
        T_flange_target=c.T_flange_target,
        board=reference_board(),
        T_instr_board=None,
        cell_name=c.name,
        cell_sha256=c.sha256,
        spec_mm=c.spec_mm,
        instrument=f"stereo camera {config.calibration} ({config.cameras.describe()})",
        robot_name=config.robot_name or f"ur-{config.robot_ip}",
        closers=closers,
    )
