"""quickhealth run — execute a plan on the cell; quickhealth sim-controller — the UR simulator.

    quickhealth run --cell CELL --plan PLAN.json --out RUN_DIR (--sim | --robot-ip IP)
                    [--unattended] [--resume]

Writes RUN_DIR/measurements.csv (CSV v1, execution order), RUN_DIR/images/ (both cameras'
images of every pose), RUN_DIR/journal.jsonl (the crash-safe journal) and RUN_DIR/run.json
(summary: failed poses with reasons, instrument self-check drift).  --sim runs the built-in
simulated cell: the UR controller simulator (a separate process the real ur-rtde client
talks to), the emulated pan motor on a pseudo-terminal and rendered stereo images of the
digital twin.  --resume continues an interrupted run with no pose lost or repeated.
--unattended never prompts, holds the single-run lock (a second run exits at once) and logs
to RUN_DIR/run.log.  --archive DIR (with --robot-name) fits the finished run and registers it
in the archive, so a nightly cron line is one command.  Exit status: 0 all poses recorded, 2 bad input, 3 hardware or runtime
failure (the run stopped cleanly: everything captured is kept; the message says what to do).

    quickhealth sim-controller [--control-port PORT] [--twin-seed N] [--cell CELL]
                               [--controller-version V] [--calibration factory|nominal|FILE]
                               [--delays SPEC] [--powered-off] [--programs DIR]

Runs the UR controller simulator in the foreground on 127.0.0.1 (RTDE 30004, dashboard 29999,
primary 30001, secondary 30002, realtime 30003, JSON control port 30090) until interrupted.
See docs/station.md.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ...identify.errors import HardwareError, InputError, QuickhealthError
from .. import options
from ..formats import check_poses_for_fit, load_robot, one_line, read_measurements
from ..fsio import (
    claim_output_folder,
    foreign_results,
    make_dirs,
    open_append,
    refuse_overwriting_inputs,
    result_files,
)
from ..hardware.cameras.config import OPTION_HELP as CAMERAS_HELP
from ..hardware.cameras.config import for_simulation, parse_cameras_option
from ..run import lock
from ..run.lock import RunLock
from ..services.fitting import fit_folder
from ..sim.process import add_arguments as add_sim_arguments
from ..sim.process import run_from_args

if TYPE_CHECKING:  # the types only: the planner loads the collision library, run the drivers
    from ..planning.planfile import Plan
    from ..station import HardwareConfig, Station


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``run`` and ``sim-controller``."""
    p = subparsers.add_parser(
        "run",
        help="execute a plan on the cell (real robot or --sim) into a run folder",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cell", required=True, help="cell file (TOML) or built-in name 'reference'")
    p.add_argument("--plan", required=True, type=Path, help="plan.json from 'quickhealth plan'")
    p.add_argument("--out", required=True, type=Path, help="run folder")
    p.add_argument(
        "--unattended",
        action="store_true",
        help="never prompt; hold the run lock; log to RUN_DIR/run.log",
    )
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in RUN_DIR")
    p.add_argument(
        "--force",
        action="store_true",
        help="run into an --out folder that holds a plan or a fit of other data",
    )
    p.add_argument(
        "--archive",
        default=None,
        help="after a complete run: fit it (identify fit) and register it in this archive "
        "under --robot-name (nightly use)",
    )
    p.add_argument(
        "--robot-name", default=None, help="robot name for the journal and archive (plain name)"
    )
    add_station_arguments(p)
    p.set_defaults(func=run)

    s = subparsers.add_parser(
        "sim-controller",
        help="run the UR controller simulator on 127.0.0.1 (RTDE, dashboard, script ports)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_sim_arguments(s)
    s.set_defaults(func=sim_controller)


def add_station_arguments(
    p: argparse.ArgumentParser, required: bool = True
) -> argparse._MutuallyExclusiveGroup:
    """The cell's hardware options, shared by ``run`` and ``check``: the simulated cell
    (``--sim`` and its settings) or a real one (``--robot-ip``, motor, cameras, calibration).
    Returns the ``--sim | --robot-ip`` group (``check`` adds ``--replay`` to it)."""
    src = p.add_mutually_exclusive_group(required=required)
    src.add_argument("--sim", action="store_true", help="the built-in simulated cell")
    src.add_argument("--robot-ip", help="address of the UR controller")
    p.add_argument("--motor-port", default="/dev/ttyUSB0", help="pan motor serial port (real cell)")
    p.add_argument("--cameras", default=None, help=CAMERAS_HELP)
    p.add_argument("--calibration", default=None, help="stereo CAL.json (real cell)")
    # the simulated hardware's size and clock; None: QUICKHEALTH_SIM_IMAGE_SCALE /
    # QUICKHEALTH_SIM_SPEED_FACTOR from the environment, else 0.5 and 1 (docs/station.md)
    p.add_argument("--sim-image-scale", type=float, default=None, help=argparse.SUPPRESS)
    p.add_argument("--twin-seed", type=options.SEED, default=1, help=argparse.SUPPRESS)
    p.add_argument("--sim-speed-factor", type=float, default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--sim-degrade",
        default=None,
        help="--sim only: change the simulated robot's true errors, e.g. j2.ex.c0=5e-4 (m or rad)",
    )
    p.add_argument(
        "--sim-pick-place-kg",
        type=options.PAYLOAD_KG,
        default=None,
        help="--sim only: the simulated arm picks and places parts of up to this mass between "
        "poses (a payload that changes, in the joint torques)",
    )
    return src


def check_station_arguments(args: argparse.Namespace) -> None:
    """Settle and check :func:`add_station_arguments`' options before anything runs."""
    args.sim_image_scale = _sim_setting(
        args.sim_image_scale, "--sim-image-scale", SIM_IMAGE_SCALE_ENV, 0.5, (0.05, 1.0)
    )
    args.sim_speed_factor = _sim_setting(
        args.sim_speed_factor, "--sim-speed-factor", SIM_SPEED_FACTOR_ENV, 1.0, (0.1, 100.0)
    )
    if not args.sim and args.calibration is None:
        raise InputError("--robot-ip needs --calibration CAL.json (quickhealth vision calibrate)")
    # the folder's name is the run id, the calibration names the instrument: both become
    # '# key: value' lines of measurements.csv and rows of the archive (before anything moves)
    one_line(Path(args.out).name, "--out: the run folder's name (its run id)")
    if args.calibration is not None:
        one_line(args.calibration, "--calibration")
    if args.cameras is not None:
        parse_cameras_option(args.cameras)  # a bad --cameras is one line before anything starts
    if args.sim_degrade is not None and not args.sim:
        raise InputError("--sim-degrade changes the simulated robot: it needs --sim")
    if args.sim_pick_place_kg is not None and not args.sim:
        raise InputError("--sim-pick-place-kg changes the simulated robot: it needs --sim")


def hardware_config(args: argparse.Namespace, robot_name: str | None) -> HardwareConfig:
    """The typed hardware configuration of :func:`add_station_arguments`' options."""
    from ..station import HardwareConfig  # the drivers' types: OpenCV-free, but numpy

    return HardwareConfig.from_options(
        args.cell,
        robot_ip=None if args.sim else args.robot_ip,
        motor_port=args.motor_port,
        cameras=args.cameras,
        calibration=args.calibration,
        robot_name=robot_name,
    )


def open_station(args: argparse.Namespace, robot_name: str | None) -> Station:
    """The station of :func:`add_station_arguments`' options (simulated or real)."""
    config = hardware_config(args, robot_name)
    if args.sim:
        from ..sim.cell import sim_station  # the simulation (and the twin), only under --sim
        from ..sim.world import parse_degradation  # (the same)

        station, _ = sim_station(
            args.cell,
            twin_seed=args.twin_seed,
            image_scale=args.sim_image_scale,
            speed_factor=args.sim_speed_factor,
            degrade=parse_degradation(args.sim_degrade),
            cameras=for_simulation(config.cell.cameras, args.cameras),
            sim_options={"pick_place_kg": args.sim_pick_place_kg}
            if args.sim_pick_place_kg
            else None,
        )
        if robot_name:
            station.robot_name = robot_name
        return station
    from ..station import real_station  # the drivers: ur-rtde, the camera SDK

    return real_station(config)


def sim_controller(args: argparse.Namespace) -> int:
    """Serve the simulator in the foreground."""
    return run_from_args(args)


@lock.holds_outputs("run", lambda a: [a.out])
def run(args: argparse.Namespace) -> int:
    """Validate everything that can be validated without hardware, then run."""
    from ..archive import safe_name  # the archive module loads the trend's scipy.stats
    from ..planning import load_cell, load_plan  # the planner: the collision library

    out: Path = args.out
    if ".." in out.parts:
        raise InputError(f"--out {str(out)!r}: '..' is not allowed in a run folder path")
    if args.robot_name is not None:
        safe_name(args.robot_name, "robot name")
    # a run folder holds one run (and, later, its fit): never a plan, nor a fit of other data
    foreign = foreign_results(out, "run")
    if args.resume and result_files(out)["run"]:
        foreign = [f for f in foreign if not f.startswith("a fit")]  # this run's own fit
    forced = claim_output_folder(out, foreign, force=args.force)
    if forced:
        print(f"--force: running into {out}, which holds {forced}", file=sys.stderr)
    refuse_overwriting_inputs(  # the run's own files never replace the plan, cell or calibration
        [("--out", out / n) for n in ("measurements.csv", "run.json", "journal.jsonl", "run.log")],
        [p for p in (args.cell, args.plan, args.calibration) if p and Path(p).is_file()],
    )
    check_station_arguments(args)
    cell = load_cell(args.cell)
    plan = load_plan(args.plan)
    if plan.cell_sha256 != cell.sha256:
        raise InputError(
            f"{args.plan}: made for cell {plan.cell_name!r} with other contents than {args.cell}: plan again"
        )
    if args.archive is not None and args.robot_name is None:
        raise InputError("--archive needs --robot-name (the robot's name in the archive)")
    lock = RunLock.acquire(out)
    try:
        return _run_locked(args, plan, out)
    finally:
        lock.release()


SIM_IMAGE_SCALE_ENV = "QUICKHEALTH_SIM_IMAGE_SCALE"
SIM_SPEED_FACTOR_ENV = "QUICKHEALTH_SIM_SPEED_FACTOR"


def _sim_setting(
    value: float | None, option: str, env: str, default: float, bounds: tuple[float, float]
) -> float:
    """A simulated-cell setting: the option, else the environment variable, else the default.

    The simulated cell's image size and clock are properties of the simulated hardware, not
    of the command, so a test or a quick look can run the README's commands exactly as
    written on a faster simulated arm.  Refused (one line) unless finite and in
    ``[lo, hi]``.
    """
    where = option
    if value is None:
        text = os.environ.get(env)
        if text is None:
            return default
        where = f"{env}={text!r}"
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"{where}: not a number") from None
    lo, hi = bounds
    if not (math.isfinite(value) and lo <= value <= hi):
        raise InputError(f"{where}: must be in {lo:g}..{hi:g}")
    return float(value)


def _run_locked(args: argparse.Namespace, plan: Plan, out: Path) -> int:
    from ..run.loop import run_plan  # the drivers: ur-rtde, OpenCV
    from ..run.progress import Progress

    make_dirs(out)  # an unwritable --out is one line, exit 2
    log = (  # never through a link planted as run.log
        os.fdopen(open_append(out / "run.log"), "a", encoding="utf-8") if args.unattended else None
    )

    def progress(p: Progress) -> None:
        if p.kind in ("pose", "measured", "stop", "done", "resume", "preflight", "selfcheck"):
            tag = f"[{p.index:3d}/{p.n_poses}] {p.name} " if p.index else ""
            line = f"{p.kind}: {tag}{p.status} {p.message}".rstrip()
            if log is not None:
                log.write(line + "\n")
                log.flush()
            else:
                print(line, flush=True)

    try:
        station = open_station(args, args.robot_name)
        if not args.sim:
            if not args.unattended and sys.stdin.isatty():
                input(
                    f"The arm will move through {len(plan.poses)} poses. Clear the cell, then press Enter (Ctrl-C aborts). "
                )
        try:
            res = run_plan(station, plan, out, resume=args.resume, progress=progress)
        finally:
            station.close()
        if res.stopped:
            raise HardwareError(f"run stopped after {res.n_measured} measured poses: {res.stopped}")
        summary = (
            f"{res.n_measured} of {res.n_poses} poses measured, {res.n_failed} failed; "
            f"wrote {res.measurements}"
        )
        if res.selfcheck_ok is False:
            summary += (
                f"; WARNING instrument drift {res.selfcheck_drift_mm:.3f} mm / "
                f"{res.selfcheck_drift_deg:.4f}° during the run (self-check board): the camera moved"
            )
        if args.archive is not None:
            summary += "; " + _register(out, args, plan)
        if log is not None:
            log.write(summary + "\n")
        print(summary)
        return 0
    finally:
        if log is not None:
            log.close()


def _register(out: Path, args: argparse.Namespace, plan: Plan) -> str:
    """Fit the finished run and add it to the archive, as ``identify fit`` and ``archive add``
    do (:func:`~quickhealth.station.services.fitting.fit_folder`, :class:`Archive`)."""
    from ..archive import Archive  # SQLAlchemy: only when archiving

    csv = out / "measurements.csv"
    try:
        from ..planning import load_cell  # the planner: the collision library

        cell = load_cell(args.cell)  # the cell's arm carrying its smart target
        robot = cell.robot_with_target(load_robot(cell.robot.name))
        meas = read_measurements(csv, robot.n_joints)
        check_poses_for_fit(meas, robot, csv)
        fit_folder(meas, robot, out, source=str(csv))
        Archive.open(args.archive).add_run(
            args.robot_name, out, meta={"plan_hash": plan.hash, "cell": plan.cell_name}
        )
    except QuickhealthError as exc:
        last = (str(exc).strip().splitlines() or ["?"])[-1]
        raise HardwareError(f"the run is complete but could not be archived: {last}") from None
    return f"fitted and archived for robot {args.robot_name} in {args.archive}"
