"""The technician's App on the built-in simulated cell (``quickhealth tui --sim``, tests, demos).

The App's real path (:mod:`.app`, :mod:`.facade`, the screens) never imports the simulation;
this module builds a :class:`~.facade.Station` on a simulated cell of
:mod:`quickhealth.station.sim.cell` instead of the real hardware:

- :func:`open_simulated`: the UR controller simulator in its own process behind the real
  ur-rtde client, the pan-motor emulator behind the real serial driver, rendered cameras;
- :func:`in_process`: the same cell in this process with the pure-Python simulated arm
  (fast; for tests).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ..planning.planfile import Plan
from ..run import RunSettings
from ..sim.cell import inprocess_sim_station, sim_station
from .facade import Station, cell_and_plan, make_plan, new_run_id


def open_simulated(
    *,
    cell: str = "reference",
    plan: Path | None = None,
    archive: Path = Path("archive"),
    robot_name: str = "ur5-sim",
    n_poses: int = 40,
    threshold_mm: float = 2.0,
    run_id: str | None = None,
    say: Callable[[str], None] | None = None,
    speed_factor: float = 1.0,
    image_scale: float = 0.3,
) -> Station:
    """The station for ``quickhealth tui --sim``: controller simulator subprocess, emulated pan
    motor, rendered cameras.  ``say`` receives a line before each slow step."""
    tell = say or (lambda line: None)
    c, the_plan = cell_and_plan(cell, plan, n_poses, tell)
    tell("starting the simulated cell (UR controller simulator, pan motor, cameras)…")
    hw, simcell = sim_station(cell, image_scale=image_scale, speed_factor=speed_factor)
    station = Station(
        robot=c.robot,
        robot_name=robot_name,
        archive_root=Path(archive),
        run_id=run_id or new_run_id(),
        cell_name=c.name,
        threshold_mm=threshold_mm,
        sim=True,
        hardware=hw,
        plan=the_plan,
        plan_path=plan,
        cell_spec=c,
    )
    station.simcell = simcell  # the simulated cell's handles (controller, emulator)
    return station


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
    threshold_mm: float = 2.0,
    max_order: int | None = None,
) -> Station:
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
    return Station(
        robot=cell.robot,
        robot_name=robot_name,
        archive_root=Path(archive_root),
        run_id=run_id,
        cell_name=cell.name,
        threshold_mm=threshold_mm,
        sim=True,
        hardware=hw,
        plan=plan,
        run_settings=RunSettings(settle_window_s=0.03 * time_scale),
        cell_spec=cell,
        **({} if max_order is None else {"max_order": max_order}),
    )
