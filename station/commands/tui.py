"""``quickhealth tui [--sim]``: the technician's terminal application (CONTRACTS.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ...identify.errors import InputError
from .. import options
from ..hardware.cameras.config import OPTION_HELP as CAMERAS_HELP
from ..hardware.cameras.config import parse_cameras_option

if TYPE_CHECKING:  # the type only: the App's station loads textual, the fit and the drivers
    from ..tui.facade import Facade


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "tui",
        help="the technician's terminal application (q quits)",
        description="The technician's terminal application: station, plan, run, results, "
        "diagnose, history. Keys 1-6 switch screens, q quits.",
    )
    p.add_argument("--sim", action="store_true", help="attach to the built-in simulated cell")
    p.add_argument(
        "--data",
        type=Path,
        help="open a measurement file (CSV v1) without a station: results, diagnose, history",
    )
    p.add_argument("--heldout", type=Path, help="with --data: held-out measurements for Diagnose")
    p.add_argument(
        "--cell", default="reference", help="cell file or built-in name (default: reference)"
    )
    p.add_argument("--plan", type=Path, help="plan.json to run (default: plan the cell now)")
    p.add_argument(
        "--n",
        type=options.PLAN_POSES,
        default=150,
        help="candidate targets when planning now (default 150: the tutorial's plan; the "
        "planner keeps those it can reach and see, and warns when too few remain)",
    )
    p.add_argument("--robot-ip", help="the real robot's address (without --sim)")
    p.add_argument("--motor-port", help="serial port of the pan motor (real station)")
    p.add_argument("--cameras", help=CAMERAS_HELP)
    p.add_argument("--calibration", help="stereo calibration CAL.json (real station)")
    p.add_argument(
        "--archive",
        type=Path,
        default=None,
        help="archive folder: runs and baselines (default: $QUICKHEALTH_ARCHIVE, else "
        "~/quickhealth-archive, as every command)",
    )
    p.add_argument(
        "--robot-name",
        default=None,
        help="the robot's name in the archive (default: the cell's arm, e.g. ur5-sim with --sim)",
    )
    p.add_argument(
        "--threshold-mm",
        type=options.LENGTH_MM,
        default=None,
        help="the accuracy spec (mm, workspace max TCP error) instead of the cell's spec_mm",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..tui.facade import Facade  # textual, the fit, the drivers: --help must not wait

    if args.data is not None:
        station = Facade.from_data(
            args.data,
            args.heldout,
            robot_name=args.robot_name or "ur5-sim",
            archive_root=args.archive,
            threshold_mm=args.threshold_mm,
        )
        return _run_app(station)
    if not args.sim and not args.robot_ip:
        raise InputError(
            "tui: give --sim for the simulated cell, --robot-ip IP for a real robot, "
            "or --data MEAS.csv"
        )
    if args.cameras is not None:
        parse_cameras_option(args.cameras)  # one line for a bad --cameras, before anything starts
    common = dict(
        cell=args.cell,
        cameras=args.cameras,
        plan=args.plan,
        archive=args.archive,
        robot_name=args.robot_name,
        n_poses=args.n,
        threshold_mm=args.threshold_mm,
        say=lambda line: print(f"quickhealth: {line}", file=sys.stderr, flush=True),
    )
    if args.sim:
        from ..tui.simulated import open_simulated  # the simulation, only under --sim
        from .run import SIM_SPEED_FACTOR_ENV, _sim_setting

        # the simulated hardware's clock, as run --sim reads it (a faster arm for a look)
        speed = _sim_setting(None, "--sim-speed-factor", SIM_SPEED_FACTOR_ENV, 1.0, (0.1, 100.0))
        station = open_simulated(**common, speed_factor=speed)
    else:
        station = Facade.open(
            robot_ip=args.robot_ip,
            motor_port=args.motor_port,
            calibration=args.calibration,
            **common,
        )
    return _run_app(station)


def _run_app(station: Facade) -> int:
    from ..tui.app import QuickhealthApp  # textual

    try:
        return int(QuickhealthApp(station).run() or 0)
    finally:
        station.shutdown()
