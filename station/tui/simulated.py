"""The technician's App on the built-in simulated cell (``quickhealth tui --sim``, tests, demos).

The App's real path (:mod:`.app`, :mod:`.facade`, the screens) never imports the simulation;
this module builds a :class:`~.facade.Facade` on a simulated cell of
:mod:`quickhealth.station.sim.cell` instead of the real hardware:

- :func:`open_simulated`: the UR controller simulator in its own process behind the real
  ur-rtde client, the pan-motor emulator behind the real serial driver, rendered cameras;
- :func:`in_process`: the same cell in this process with the pure-Python simulated arm
  (fast; for tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..hardware.cameras.config import for_simulation
from ..hardware.target import reference_target
from ..planning.cell import Cell
from ..planning.planfile import Plan
from ..run.settings import RunSettings
from ..sim.cell import inprocess_sim_station, sim_station
from .facade import Facade, cell_and_plan, make_plan, new_run_id, spec_for


def open_simulated(
    *,
    cell: str = "reference",
    plan: Path | None = None,
    archive: Path | None = None,
    robot_name: str | None = None,
    n_poses: int = 150,
    threshold_mm: float | None = None,
    run_id: str | None = None,
    say: Callable[[str], None] | None = None,
    speed_factor: float = 1.0,
    image_scale: float | None = None,
    cameras: str | None = None,
) -> Facade:
    """The station for ``quickhealth tui --sim``: controller simulator subprocess, emulated pan
    motor, rendered cameras.  ``say`` receives a line before each slow step.  The simulated
    sensor is ``image_scale`` of the reference one, by default :func:`sensor_scale` of the
    plan.  The arm is the
    cell's (``[robot] model``), carrying the cell's smart target; ``robot_name`` defaults to
    ``<arm>-sim`` (``ur5-sim`` on the reference cell)."""
    tell = say or (lambda line: None)
    c, the_plan = cell_and_plan(cell, plan, n_poses, tell)
    tell("starting the simulated cell (UR controller simulator, pan motor, cameras)…")
    scale = sensor_scale(c, the_plan) if image_scale is None else image_scale
    hw, simcell = sim_station(
        cell,
        image_scale=scale,
        speed_factor=speed_factor,
        cameras=for_simulation(c.cameras, cameras),  # as run --sim: one parser for every door
    )
    station = Facade(
        robot=c.robot_with_target(),
        robot_name=robot_name or f"{c.robot.name}-sim",
        archive_root=archive,
        run_id=run_id or new_run_id(),
        cell_name=c.name,
        spec=spec_for(c, threshold_mm),
        sim=True,
        hardware=hw,
        plan=the_plan,
        plan_path=plan,
        cell_spec=c,
    )
    station.simcell = simcell  # the simulated cell's handles (controller, emulator)
    return station


#: The smallest simulated sensor (× the reference 4000 px) and the marker width, in pixels,
#: the plan's farthest target must keep on it (the detector loses 24 mm markers below about
#: 10 px: measured on the UR10e cell at 1000 px wide, lost beyond 3.1 m).
MIN_SENSOR_SCALE = 0.3
MIN_MARKER_PX = 14.0


def sensor_scale(cell: Cell, plan: Plan) -> float:
    """The simulated sensor size for ``plan`` in ``cell``: 0.3 of the reference sensor (fast),
    larger in 0.05 steps until the farthest target's marker spans ``MIN_MARKER_PX`` (the
    paper's UR5 cell stays at 0.3; the UR10e cell, targets up to 3.6 m away, takes 0.45)."""
    cams = np.stack([cell.T_world_cam_left[:3, 3], cell.T_world_cam_right[:3, 3]])
    p = np.array([(cell.T_world_base @ pose.T_base_target)[:3, 3] for pose in plan.poses])
    far = float(np.linalg.norm(p[:, None, :] - cams[None], axis=-1).max())
    marker = float(np.ptp(reference_target().corners[0], axis=0).max())  # edge length, m
    need = MIN_MARKER_PX * far / (marker * cell.camera.fx)
    return max(MIN_SENSOR_SCALE, round(math.ceil(need / 0.05 - 1e-9) * 0.05, 2))


def in_process(
    archive_root: str | Path,
    *,
    n_candidates: int = 40,
    plan_seed: int = 0,
    plan: Plan | None = None,
    twin_seed: int = 1,
    image_scale: float = 0.3,
    time_scale: float = 20.0,
    run_id: str = "sim-run-1",
    robot_name: str = "sim-ur5",
    threshold_mm: float | None = None,
    max_order: int | None = None,
) -> Facade:
    """The built-in simulated cell, in this process (fast; for tests and demos).

    The arm is the pure-Python :class:`~quickhealth.station.sim.fake_robot.FakeRobot`
    (``time_scale`` times faster than real), the pan motor the serial emulator on a
    pseudo-terminal behind the real serial driver, and the cameras render the digital
    twin's true target pose (:func:`~quickhealth.station.sim.world.build_world`) at
    ``image_scale`` of the reference sensor.  The plan is made now from ``n_candidates``
    random targets unless ``plan`` is given.  ``max_order``: the fit's (default: every door's).
    """
    hw, cell = inprocess_sim_station(
        twin_seed=twin_seed, image_scale=image_scale, time_scale=time_scale
    )
    if plan is None:
        plan = make_plan(cell, n_candidates, plan_seed)
    return Facade(
        robot=cell.robot_with_target(),
        robot_name=robot_name,
        archive_root=Path(archive_root),
        run_id=run_id,
        cell_name=cell.name,
        spec=spec_for(cell, threshold_mm),
        sim=True,
        hardware=hw,
        plan=plan,
        run_settings=RunSettings(settle_window_s=0.03 * time_scale),
        cell_spec=cell,
        **({} if max_order is None else {"max_order": max_order}),
    )
