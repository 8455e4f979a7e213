"""The built-in simulated cell (``--sim``): controller simulator, emulated pan motor, cameras.

:func:`start_sim_cell` starts the UR controller simulator in its own process, the pan-motor
emulator on a pseudo-terminal, and connects the *real* drivers to them:
:class:`~quickhealth.station.hardware.robot.UrRobot` on ur-rtde and
:class:`~quickhealth.station.hardware.motor.SerialPanMotor` on pyserial.  The simulated
stereo camera renders what is really there: it asks the controller simulator for the arm's
true target pose (the digital twin at the actual joints) and the motor emulator for the
true pan angle.  :func:`sim_station` wraps it all in a run's
:class:`~quickhealth.station.station.Station`.  :func:`inprocess_sim_station` is the same cell in
this process (the pure-Python :class:`~.fake_robot.FakeRobot` for the controller simulator):
fast, for the TUI's tests and demos.

The simulator uses the drivers, never the reverse: nothing in
:mod:`quickhealth.station.hardware`, :mod:`quickhealth.station.station` or
:mod:`quickhealth.station.run` imports this package.

SYNOPSIS
    >>> with start_sim_cell(image_scale=0.25) as cell:          # doctest: +SKIP
    ...     cell.robot.move(q); cell.motor.move_to(0.2); frame = cell.camera.capture()
    >>> station, cell = sim_station("reference", image_scale=0.5)  # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...identify.errors import InputError
from ...identify.transforms import inv_T
from ...vision.render import Imaging
from ..hardware.cameras import StereoCamera
from ..hardware.cameras.config import CameraConfig, CameraSpec, Trigger
from ..hardware.cameras.registry import open_cameras
from ..hardware.line_trigger import line_trigger
from ..hardware.motor import PanMotor, SerialPanMotor
from ..hardware.robot import Robot, UrRobot
from ..hardware.target import T_target_plate
from ..planning import load_cell
from ..planning.cell import Cell
from ..station import Station
from .arm import controller_arm
from .cable import Cable
from .cameras import EmulatorFeed, SimStereoCamera, scaled_rig
from .fake_robot import FakeRobot
from .motor_emulator import MotorEmulator
from .process import SimControllerHandle, start_sim_controller
from .wire import CONTROL_PORT
from .world import SimWorld, build_world


@dataclass
class SimCell:
    """Everything of a running simulated cell; :meth:`close` stops it all."""

    world: SimWorld
    controller: SimControllerHandle
    emulator: MotorEmulator
    robot: UrRobot
    motor: SerialPanMotor
    camera: StereoCamera  # the renderer, or the backend that sees it (emulated cameras)
    extra: dict[str, Any] = field(default_factory=dict)
    cable: Cable | None = None  # trigger = "line": the controller's output to the cameras

    def true_plate(self) -> np.ndarray:
        """True ``T_instr_plate`` right now (arm and pan as they really are)."""
        _, T0 = self.controller.truth()
        return T0 @ T_target_plate(math.radians(self.emulator.position_deg()))

    def close(self) -> None:
        """Disconnect the drivers first (ur-rtde must never outlive its server), then stop."""
        for f in (self.motor.close, self.camera.close):
            try:
                f()
            except Exception:  # noqa: BLE001 - best effort while tearing down
                pass
        self.stop_simulators()

    def stop_simulators(self) -> None:
        """Close the robot's client, then stop the controller simulator and the motor emulator.

        A :class:`~quickhealth.station.station.Station` built by :func:`sim_station` calls this
        after its device owners closed the pan motor and the camera."""
        for f in (self.robot.close, *([self.cable.close] if self.cable else [])):
            try:
                f()
            except Exception:  # noqa: BLE001 - best effort while tearing down
                pass
        self.controller.stop()
        self.emulator.stop()

    def __enter__(self) -> SimCell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_sim_cell(
    cell: str = "reference",
    *,
    twin_seed: int = 1,
    image_scale: float = 0.5,
    q0_deg: list[float] | None = None,
    control_port: int = CONTROL_PORT,
    camera_seed: int = 0,
    speed_factor: float = 1.0,
    degrade: dict[str, float] | None = None,
    sim_options: dict[str, Any] | None = None,
    cameras: CameraConfig | None = None,
) -> SimCell:
    """Start the simulated cell and connect the real drivers to it.

    Parameters
    ----------
    cell : str
        Cell name or file (camera and board placement).
    twin_seed : int
        The digital twin's seed (its true errors).
    image_scale : float
        Simulated sensor size relative to the reference cameras (1 = 4000×3000 px).
    degrade : dict, optional
        Changes of the twin's true error coefficients (``{"j2.ex.c0": 5e-4}``, m or rad).
    sim_options : dict, optional
        More options of the controller simulator (:func:`~.process.start_sim_controller`):
        ``calibration``, ``delays`` (short ones for tests: ``states.TESTING.spec()``),
        ``controller_version``, ``powered_off``, ``programs``, ``payload_kg``.
    cameras : CameraConfig, optional
        The camera backend the station sees through (:func:`emulated_cameras`); None: the
        rendered pair directly.  With ``trigger = "line"`` the robot's digital output fires
        the emulated cameras through the cell's trigger cable (:mod:`.cable`).
    """
    world = build_world(cell, twin_seed=twin_seed, degrade=degrade)
    sim = start_sim_controller(
        control_port=control_port,
        q0_deg=q0_deg,
        twin_seed=twin_seed,
        cell=cell,
        speed_factor=speed_factor,
        degrade=degrade,
        **(sim_options or {}),
    )
    emu = MotorEmulator().start()
    robot = motor = cable = None
    try:
        arm = controller_arm(world.twin.robot)  # the cell's arm, its own limits, its rate
        robot = UrRobot(sim.host, model=arm, frequency=arm.control_hz or 125.0)
        motor = SerialPanMotor(emu.port)
        rig = scaled_rig(world.rig, image_scale)

        def scene() -> list[tuple[np.ndarray, Any]]:
            _, T0 = sim.truth()
            pan = math.radians(emu.position_deg())
            return [(T0 @ T_target_plate(pan), world.target)]

        renderer = SimStereoCamera(
            rig,
            scene,
            static=[(world.T_instr_board, world.board)],
            seed=camera_seed,
            imaging=Imaging(bits=cameras.bits) if cameras is not None else None,
        )
        camera: StereoCamera = renderer
        if cameras is not None:
            if cameras.trigger is Trigger.LINE:
                cable = Cable(sim, cameras.robot_output)
            camera = emulated_cameras(
                cameras, renderer, fire=line_trigger(robot, cameras), cable=cable
            )
    except BaseException:
        if cable is not None:
            cable.close()
        if robot is not None:
            robot.close()
        if motor is not None:
            motor.close()
        sim.stop()
        emu.stop()
        raise
    return SimCell(world, sim, emu, robot, motor, camera, cable=cable)


def emulated_cameras(
    cfg: CameraConfig,
    renderer: SimStereoCamera,
    *,
    fire: Callable[[], dict[str, Any] | None] | None = None,
    cable: Cable | None = None,
) -> StereoCamera:
    """The simulated cell seen through a real camera backend: the renderer's pair is put in
    front of the SDK's own emulated cameras (:class:`~.cameras.EmulatorFeed`), which the
    backend triggers and checks as real ones (``pylon``: pypylon's camera emulation;
    ``aravis``: Aravis' in-process fake cameras, which speak its GenICam protocol without a
    network), or a recorded folder (``files``).  The camera faults of
    :class:`~.cameras.EmulatorFeed` act on pylon's emulated cameras.

    ``trigger = "line"`` (pylon only): ``fire`` pulses the robot's digital output
    (:class:`~quickhealth.station.hardware.line_trigger.LineTrigger`) and ``cable`` carries its
    rising edge to both emulated cameras' trigger input."""
    if cfg.backend == "opencv":
        raise InputError("--sim cannot see through webcams: choose pylon, aravis or files")
    if cfg.backend == "files":
        return open_cameras(cfg, renderer.rig)
    if cfg.trigger is Trigger.LINE and cfg.backend == "aravis":
        raise InputError(
            "--sim: trigger = 'line' reaches pylon's emulated cameras only (Aravis' in-process "
            "fake cameras run free, they have no trigger input): choose --cameras pylon"
        )
    if cfg.trigger is Trigger.LINE and (fire is None or cable is None):
        raise InputError(
            "--sim: trigger = 'line' needs the simulated controller's digital output and the "
            "cell's trigger cable (quickhealth run --sim)"
        )
    if cfg.backend == "pylon":
        os.environ.setdefault("PYLON_CAMEMU", "2")  # before pylon lists its cameras
    feed = EmulatorFeed(renderer)
    if cfg.backend == "aravis":  # Aravis' in-process fake cameras (no network)
        from ..hardware.cameras.aravis import AravisDevice, FakeScreen

        screens = (FakeScreen("QH-SIM-L"), FakeScreen("QH-SIM-R"))

        def fake(spec: CameraSpec) -> AravisDevice:
            dev = AravisDevice(spec, camera=screens[spec.index].camera())
            dev.screen = screens[spec.index]
            return dev

        return open_cameras(
            cfg, renderer.rig, prepare=feed, wrap_open=lambda _: feed.open_device(fake)
        )
    if cable is not None:  # the cameras' trigger input on the cable
        return open_cameras(
            cfg,
            renderer.rig,
            prepare=feed,
            fire=fire,
            wrap_open=lambda opener: feed.open_device(cable.plug(opener)),
        )
    return open_cameras(cfg, renderer.rig, prepare=feed, wrap_open=feed.open_device)


def sim_station(
    cell: str = "reference",
    *,
    twin_seed: int = 1,
    image_scale: float = 0.5,
    q0_deg: list[float] | None = None,
    speed_factor: float = 1.0,
    degrade: dict[str, float] | None = None,
    camera_seed: int = 0,
    sim_options: dict[str, Any] | None = None,
    cameras: CameraConfig | None = None,
) -> tuple[Station, SimCell]:
    """A run's :class:`~quickhealth.station.station.Station` on the built-in simulated cell, and
    the :class:`SimCell` behind it.

    ``station.close()`` stops the simulators too.  ``degrade`` changes the twin's true
    error coefficients (``{"j2.ex.c0": 5e-4}``, m or rad): a worn robot for demos and tests.
    """
    c = load_cell(cell)
    if q0_deg is None and getattr(c, "home", None) is not None:
        q0_deg = [float(v) for v in np.degrees(c.home)]
    sc = start_sim_cell(
        cell,
        twin_seed=twin_seed,
        image_scale=image_scale,
        q0_deg=q0_deg,
        speed_factor=speed_factor,
        degrade=degrade,
        camera_seed=camera_seed,
        sim_options=sim_options,
        cameras=cameras,
    )
    w = sc.world
    through = "" if cameras is None else f" through {cameras.describe()}"
    st = station_in_world(
        c,
        w,
        sc.robot,
        sc.motor,
        sc.camera,
        instrument=f"simulated stereo camera ({w.rig.left.image_size[0] * image_scale:.0f} px wide)"
        + through,
        robot_name=sim_robot_name(c),
        closers=[sc.stop_simulators],
    )
    return st, sc


def station_in_world(
    cell: Cell,
    world: SimWorld,
    robot: Robot,
    motor: PanMotor,
    camera: StereoCamera,
    *,
    instrument: str = "simulated stereo camera",
    robot_name: str | None = None,
    closers: list[Callable[[], None]] | None = None,
) -> Station:
    """A run's :class:`~quickhealth.station.station.Station` in the simulated ``world`` of ``cell``.

    The nominal geometry comes from the cell file; the target and the self-check board from
    the world.  Used by ``--sim``, the TUI's in-process cell and the tests.
    """
    return Station(
        robot=robot,
        motor=motor,
        camera=camera,
        target=world.target,
        T_instr_base=inv_T(cell.T_world_cam_left) @ cell.T_world_base,
        T_flange_target=cell.T_flange_target,
        board=world.board,
        T_instr_board=world.T_instr_board,
        cell_name=cell.name,
        cell_sha256=cell.sha256,
        spec_mm=cell.spec_mm,
        instrument=instrument,
        robot_name=robot_name or sim_robot_name(cell),
        closers=list(closers or []),
    )


def sim_robot_name(cell: Cell) -> str:
    """The simulated robot's name in journals and archives: ``sim-`` and the cell's arm
    (``sim-ur5`` on the reference cell)."""
    return f"sim-{cell.robot.name}"


def inprocess_sim_station(
    cell_name: str = "reference",
    *,
    twin_seed: int = 1,
    image_scale: float = 0.3,
    time_scale: float = 20.0,
) -> tuple[Station, Cell]:
    """A run's :class:`~quickhealth.station.station.Station` on the simulated cell without the
    controller subprocess.

    FakeRobot (same motion model and faults as the controller simulator), the pan-motor
    emulator behind the real serial driver, and simulated cameras that render the twin's
    true plate pose at the robot's actual joints and the motor's true angle.
    Returns ``(station, cell)``.
    """
    cell = load_cell(cell_name)
    world = build_world(cell_name, twin_seed=twin_seed)
    robot = FakeRobot(time_scale=time_scale, model=cell.robot)
    emu = MotorEmulator().start()
    try:
        # The emulator answers from a thread of this process, which shares the interpreter with
        # the UI and the renderer: give it the time a busy GIL can take.
        motor = SerialPanMotor(emu.port, timeout=1.0)
    except BaseException:
        emu.stop()
        raise

    def scene() -> list[tuple[np.ndarray, Any]]:
        pan = math.radians(emu.position_deg())
        js = robot.joint_sensors()  # a hidden warm-up or torque effect acts at the arm's state
        T = world.T_instr_plate(robot.joints(), pan, None, js.temperature, js.torque)
        return [(T, world.target)]

    camera = SimStereoCamera(
        scaled_rig(world.rig, image_scale), scene, static=[(world.T_instr_board, world.board)]
    )
    hw = station_in_world(
        cell,
        world,
        robot,
        motor,
        camera,
        instrument=f"simulated stereo camera ({image_scale:g} × reference sensor)",
        closers=[emu.stop, motor.close, camera.close, robot.close],
    )
    return hw, cell
