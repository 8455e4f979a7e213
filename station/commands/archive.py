"""``quickhealth archive``: copy runs into the archive, set a robot's baseline, list runs.

quickhealth archive add RUN_DIR --robot NAME [--run-id ID] [--time ISO] [--baseline] ...
    The run's verdict (healthy or not: the baseline is the first healthy run unless one is set)
    is the one its report.json carries (:func:`quickhealth.station.reporting.verdict.healthy_of`), unless
    --healthy or --unhealthy says otherwise.
quickhealth archive baseline ROBOT RUN_ID | ROBOT --clear
quickhealth archive list [ROBOT]

Every monitoring command takes --archive DIR (default $QUICKHEALTH_ARCHIVE, else
~/quickhealth-archive) and --db URL (an SQLAlchemy URL, e.g. postgresql+psycopg://host/db,
for a shared index): :func:`add_archive_options`.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ...identify.errors import InputError
from .. import options

if TYPE_CHECKING:  # the type only: the archive loads SQLAlchemy (seconds), --help must not wait
    from ..archive import Archive


def add_archive_options(p: argparse.ArgumentParser) -> None:
    """``--archive DIR``, ``--db URL`` and ``--db-timeout S``, as every monitoring command
    takes them."""
    p.add_argument(
        "--archive",
        default=None,
        help="archive folder (default $QUICKHEALTH_ARCHIVE, else ~/quickhealth-archive)",
    )
    p.add_argument(
        "--db",
        default=None,
        help="SQLAlchemy URL of a shared index (default $QUICKHEALTH_DB, else the first line "
        "of the file $QUICKHEALTH_DB_FILE, else the archive's SQLite; a password given here "
        "shows in ps to every user of the machine)",
    )
    p.add_argument(
        "--db-timeout",
        type=options.TIMEOUT_S,
        default=None,
        help="seconds to connect to the index and for each index operation "
        "(default $QUICKHEALTH_DB_TIMEOUT, else 10)",
    )


def open_archive(args: argparse.Namespace, create: bool = False) -> Archive:
    """The archive ``--archive`` and ``--db`` name; only ``archive add`` creates a missing one."""
    from ..archive import Archive  # SQLAlchemy: only for the commands that use the archive
    from ..archive.db import index_url

    return Archive.open(
        args.archive,
        index_url(args.db),
        create=create,
        timeout_s=getattr(args, "db_timeout", None),
    )


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``archive add``, ``archive baseline`` and ``archive list``."""
    p = subparsers.add_parser("archive", help="archive runs; set a robot's baseline; list runs")
    sub = p.add_subparsers(dest="archive_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
    a = sub.add_parser("add", help="copy a run folder into the archive and index it")
    a.add_argument("run_dir")
    a.add_argument("--robot", required=True, help="robot name (letters, digits, . _ -)")
    a.add_argument("--run-id", default=None, help="default: the run's metadata or folder name")
    a.add_argument("--time", default=None, help="ISO 8601 UTC time of the run")
    for k in ("plan-hash", "cell", "calibration-id", "software-version"):
        a.add_argument(f"--{k}", default=None, help=f"override the run's {k.replace('-', ' ')}")
    h = a.add_mutually_exclusive_group()
    h.add_argument("--healthy", dest="healthy", action="store_const", const=True, default=None)
    h.add_argument("--unhealthy", dest="healthy", action="store_const", const=False)
    a.add_argument("--baseline", action="store_true", help="make this run the robot's baseline")
    add_archive_options(a)
    a.set_defaults(func=_archive_add)
    b = sub.add_parser("baseline", help="set (or --clear) a robot's baseline run")
    b.add_argument("robot")
    b.add_argument("run_id", nargs="?")
    b.add_argument("--clear", action="store_true", help="back to the first healthy run")
    add_archive_options(b)
    b.set_defaults(func=_archive_baseline)
    c = sub.add_parser(
        "add-check", help="record a quick check's folder (quickhealth check) as a check"
    )
    c.add_argument("check_dir")
    c.add_argument("--robot", required=True, help="robot name (letters, digits, . _ -)")
    c.add_argument("--check-id", default=None, help="default: the check's run id or folder name")
    add_archive_options(c)
    c.set_defaults(func=_archive_add_check)
    ls = sub.add_parser("list", help="robots, or one robot's runs (and its quick checks)")
    ls.add_argument("robot", nargs="?")
    add_archive_options(ls)
    ls.set_defaults(func=_archive_list)


def _archive_add(args: argparse.Namespace) -> int:
    from ..archive import prepare_run  # numpy and the index: not for --help

    meta = {
        k: v
        for k, v in (
            ("plan_hash", args.plan_hash),
            ("cell", args.cell),
            ("calibration_id", args.calibration_id),
            ("software_version", args.software_version),
        )
        if v is not None
    }
    # the run is checked before the archive is opened: a refused run creates nothing
    prep = prepare_run(
        args.robot,
        args.run_dir,
        run_id=args.run_id,
        time_utc=args.time,
        meta=meta,
        healthy=args.healthy,
    )
    arch = open_archive(args, create=True)
    try:
        rec = arch.add_prepared(prep)
    except BaseException:
        arch.undo_creation()
        raise
    if args.baseline:
        arch.set_baseline(rec.robot, rec.run_id)
    print(f"archived {rec.robot}/{rec.run_id} ({rec.time_utc}) in {arch.folder(rec)}")
    return 0


def _archive_add_check(args: argparse.Namespace) -> int:
    arch = open_archive(args, create=False)  # a check needs the robot's baseline run there
    arch.runs(args.robot)  # unknown robot: one line
    rec = arch.add_check(args.robot, args.check_dir, check_id=args.check_id)
    print(
        f"archived check {rec.robot}/{rec.check_id} ({rec.time_utc}, {rec.verdict}) in {rec.path}"
    )
    return 0


def _archive_baseline(args: argparse.Namespace) -> int:
    arch = open_archive(args)
    if args.clear == (args.run_id is not None):
        raise InputError("give either a RUN_ID or --clear")
    arch.set_baseline(args.robot, None if args.clear else args.run_id)
    b = arch.baseline(args.robot)
    print(f"baseline of {args.robot}: {b.run_id if b else '(none)'}")
    return 0


def _archive_list(args: argparse.Namespace) -> int:
    arch = open_archive(args)
    if args.robot is None:
        for last, n, b in arch.fleet():  # three index queries, however large the fleet
            print(f"{last.robot}: {n} runs, baseline {b or '-'}, latest {last.run_id}")
        return 0
    print(
        f"{'run':<24} {'time (UTC)':<21} {'mean':>7} {'std':>7} {'max':>7}  plan / cell / calibration"
    )
    for x in arch.runs(args.robot):
        mark = "*" if x.baseline else " "
        print(
            f"{mark}{x.run_id:<23} {x.time_utc:<21} {x.mean_mm:7.3f} {x.std_mm:7.3f} "
            f"{x.max_mm:7.3f}  {x.plan_hash[:12]} / {x.cell} / {x.calibration_id}"
        )
    from ..archive import check_lines  # numpy and the index: not for --help

    for line in check_lines(arch.checks(args.robot)):
        print(line)
    return 0
