"""quickhealth check — the quick check: "unchanged" or "changed" since the baseline run.

    quickhealth check --cell CELL --plan PLAN.json (--baseline RUN_DIR | --robot NAME [--archive DIR])
                      --out DIR (--sim | --robot-ip IP) [--false-alarm 0.01] [--detect-mm 0.05]
                      [--power 0.95] [--resume] [--unattended]
    quickhealth check --replay RECORDED_RUN_DIR (--baseline RUN_DIR | --robot NAME) --out DIR

--replay backtests: a recorded full run serves as the robot; the check chooses among its
rows in its own order and decides ("would the quick check have caught this?"), with robot
time from the run's plan and journal where it has them.

Measures the plan's poses one at a time, each chosen for the information it brings on a
change per second of robot time from where the arm is, and stops as soon as a sequential test
decides "unchanged" or "changed" at the stated error rates (false alarm --false-alarm; a TCP
change of --detect-mm found with probability --power), else at the end of the plan.  The
baseline is a fitted run folder (model.json, and its measurements.csv: each pose is then
compared with the baseline's own measurement of it), or with --robot the archive's baseline
of that robot; the check is then recorded in the archive as a check (not as an assessment).

Writes DIR/check.json (verdict, poses, robot_time_s at real speed, full_loop_robot_time_s,
changes, the error rates), DIR/measurements.csv and the journal and images, as a run does.
--resume continues an interrupted check; faults stop it cleanly, as in ``run``.
Exit status: 0 unchanged, 1 changed, 2 bad input, 3 hardware or runtime failure.
See docs/monitoring.md, "The quick check".
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ...identify.errors import InputError
from ...identify.quickcheck import CheckSettings
from .. import options
from ..fsio import (
    claim_output_folder,
    foreign_results,
    make_dirs,
    open_append,
    refuse_overwriting_inputs,
)
from ..run import lock
from ..run.lock import RunLock
from .archive import add_archive_options
from .run import add_station_arguments, check_station_arguments, open_station


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``check``."""
    p = subparsers.add_parser(
        "check",
        help="the quick check: has the robot changed since its baseline? (exit 1: changed)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cell", help="cell file (TOML) or built-in name 'reference'")
    p.add_argument("--plan", type=Path, help="plan.json (the poses to choose from)")
    p.add_argument("--out", required=True, type=Path, help="check folder")
    base = p.add_mutually_exclusive_group(required=True)
    base.add_argument("--baseline", type=Path, help="the fitted baseline run folder")
    base.add_argument("--robot", help="the archive's baseline of this robot (and record the check)")
    add_archive_options(p)
    p.add_argument(
        "--false-alarm",
        type=options.FALSE_ALARM,
        default=0.01,
        help="probability of calling an unchanged robot changed (0.01)",
    )
    p.add_argument(
        "--detect-mm",
        type=options.DETECT_MM,
        default=0.05,
        help="smallest change to detect: its largest TCP displacement in the workspace (0.05)",
    )
    p.add_argument(
        "--power",
        type=options.POWER,
        default=0.95,
        help="probability of finding a change of --detect-mm (0.95)",
    )
    p.add_argument("--resume", action="store_true", help="continue the interrupted check in DIR")
    p.add_argument(
        "--unattended", action="store_true", help="never prompt; log to DIR/run.log (nightly)"
    )
    p.add_argument(
        "--robot-name", default=None, help="robot name for the journal (default: --robot)"
    )
    src = add_station_arguments(p)
    src.add_argument(
        "--replay",
        type=Path,
        metavar="RECORDED_RUN_DIR",
        help="backtest: a recorded run (its measurements.csv) serves as the robot",
    )
    p.set_defaults(func=run)


@lock.holds_outputs("check", lambda a: [a.out])
def run(args: argparse.Namespace) -> int:
    """Validate everything that can be validated without hardware, then check."""
    from ..archive import safe_name  # the archive module loads the trend's scipy.stats
    from ..planning import load_cell, load_plan  # the planner: the collision library
    from ..services import checking  # the run: OpenCV and the vision library

    out: Path = args.out
    if ".." in out.parts:
        raise InputError(f"--out {str(out)!r}: '..' is not allowed in a check folder path")
    if args.robot is not None:
        safe_name(args.robot, "robot")
    if args.robot_name is not None:
        safe_name(args.robot_name, "robot name")
    claim_output_folder(out, foreign_results(out, "run"))
    if args.replay is not None:
        return _replay(args, out, checking)
    if not args.sim and args.robot_ip is None:
        raise InputError("one of --sim, --robot-ip IP or --replay RECORDED_RUN_DIR is required")
    for name in ("cell", "plan"):
        if getattr(args, name) is None:
            raise InputError(f"--{name} is required (or --replay RECORDED_RUN_DIR)")
    refuse_overwriting_inputs(
        [("--out", out / n) for n in ("check.json", "measurements.csv", "run.json",
                                      "journal.jsonl", "run.log")],
        [p for p in (args.cell, args.plan, args.calibration) if p and Path(p).is_file()],
    )  # fmt: skip
    check_station_arguments(args)
    settings = _settings(args)
    cell = load_cell(args.cell)
    plan = load_plan(args.plan)
    if plan.cell_sha256 != cell.sha256:
        raise InputError(
            f"{args.plan}: made for cell {plan.cell_name!r} with other contents than {args.cell}: plan again"
        )
    from ..archive.db import index_url  # the archive package: SQLAlchemy, the trend

    folder = (
        args.baseline
        if args.baseline is not None
        else checking.archive_baseline(args.robot, args.archive, index_url(args.db))
    )
    baseline = checking.load_baseline(folder)
    if args.baseline is not None:
        refuse_overwriting_inputs([("--out", out / "check.json")], [folder / "model.json"])
        if Path(out).resolve() == Path(folder).resolve():
            raise InputError(f"--out {out}: is the baseline's folder: check into another folder")
    run_lock = RunLock.acquire(out)
    try:
        return _check_locked(args, plan, cell, baseline, settings, out)
    finally:
        run_lock.release()


def _settings(args: argparse.Namespace) -> CheckSettings:
    return CheckSettings(
        false_alarm=args.false_alarm, detect=args.detect_mm * 1e-3, power=args.power
    )


def _replay(args: argparse.Namespace, out: Path, checking) -> int:  # type: ignore[no-untyped-def]
    """``check --replay``: the recorded run as the robot (no station, no motion)."""
    from ..services.replay import replay_check

    if args.sim_degrade is not None:
        raise InputError("--sim-degrade changes the simulated robot: it needs --sim")
    if args.resume:
        raise InputError("--resume continues a check on a robot; a replay runs again in full")
    rec = Path(args.replay)
    refuse_overwriting_inputs(
        [("--out", out / "check.json")], [p for p in (rec / "measurements.csv",) if p.is_file()]
    )
    if rec.resolve() == out.resolve():
        raise InputError(f"--out {out}: is the recorded run's folder: check into another folder")
    folder = (
        args.baseline
        if args.baseline is not None
        else checking.archive_baseline(args.robot, args.archive, args.db)
    )
    baseline = checking.load_baseline(folder)
    # no cell lock: a replay drives no hardware (its --out is held by holds_outputs), so it runs
    # beside a station's run and beside other replays
    res = replay_check(rec, baseline, out, settings=_settings(args))
    for line in res.summary():
        print(line)
    print(f"wrote {out / 'check.json'}")
    return 1 if res.changed else 0


def _check_locked(args, plan, cell, baseline, settings, out) -> int:  # type: ignore[no-untyped-def]
    from ..run.progress import Progress  # the run: OpenCV and the vision library
    from ..services.checking import quick_check  # (the same)

    make_dirs(out)
    log = (  # never through a link planted as run.log
        os.fdopen(open_append(out / "run.log"), "a", encoding="utf-8") if args.unattended else None
    )

    def say(line: str) -> None:
        if log is not None:
            log.write(line + "\n")
            log.flush()
        else:
            print(line, flush=True)

    def progress(p: Progress) -> None:
        if p.kind in ("pose", "stop", "done", "resume", "preflight", "selfcheck"):
            tag = f"[{p.index:3d}] {p.name} " if p.index else ""
            say(f"{p.kind}: {tag}{p.status} {p.message}".rstrip())

    try:
        station = open_station(args, args.robot_name or args.robot)
        try:
            if not args.sim and not args.unattended and sys.stdin.isatty():
                input(
                    "The arm will move through up to "
                    f"{len(plan.poses)} poses. Clear the cell, then press Enter (Ctrl-C aborts). "
                )
            res = quick_check(
                station, plan, cell, baseline, out, settings=settings, resume=args.resume,
                progress=progress, say=say,
            )  # fmt: skip
        finally:
            station.close()
        for line in res.summary():
            say(line)
        if args.robot is not None:
            from .archive import open_archive  # the index, only when a robot is named

            rec = open_archive(args, create=False).add_check(args.robot, out)
            say(f"recorded as check {rec.check_id} of robot {args.robot} in {rec.root}")
        if log is not None:  # the verdict on the terminal too (cron mails it)
            print(res.summary()[0])
        print(f"wrote {out / 'check.json'}")
        return 1 if res.changed else 0
    finally:
        if log is not None:
            log.close()
