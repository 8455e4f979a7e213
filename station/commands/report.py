"""``quickhealth report``: the run's self-contained HTML report and its verdict.

quickhealth report RUN_DIR [--out report.html] [--archive DIR --robot NAME] [--threshold-mm X]
    report.html (docs/monitoring.md, "The report") and report.json gains the report's sections,
    its verdict and the ``run`` object, keeping its schema (:func:`~quickhealth.station.
    services.report.report_run`, as the TUI and ``reprocess --report`` write them).  Prints the
    verdict's lines first (the words every door shows), then where the report is.
    --threshold-mm sets the run's accuracy spec (recorded in report.json; default: the spec
    the run's cell or robot file states).  A verdict that differs from the one report.json
    carried is said so, never turned around silently.

Refused (one line, exit 2, nothing written): a folder without model.json or report.json (fit
it first), a report.json that is not a complete fit report of its schema, an --out that is one
of the files the report reads.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ...identify.errors import InputError
from .. import options
from ..fsio import refuse_overwriting_inputs
from ..reporting.verdict import Spec, ThresholdFigure
from ..run import lock
from ..services.options import ReportOptions
from .archive import add_archive_options, open_archive

if TYPE_CHECKING:  # the type only: the archive loads SQLAlchemy
    from ..archive import Archive


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``report``."""
    r = subparsers.add_parser("report", help="the run's self-contained HTML report")
    r.add_argument("run_dir")
    r.add_argument("--out", default=None, help="HTML file (default RUN_DIR/report.html)")
    r.add_argument("--robot", default=None, help="the robot in the archive (trend section)")
    r.add_argument("--run-id", default=None, help="the run's id in the archive")
    r.add_argument(
        "--threshold-mm",
        type=options.LENGTH_MM,
        default=None,
        help="the accuracy spec (mm) to judge the run against and record (default: the run's "
        "cell or robot file spec_mm)",
    )
    r.add_argument(
        "--figure",
        choices=[f.value for f in ThresholdFigure],
        default=ThresholdFigure.MAX.value,
        help="figure the spec applies to (max)",
    )
    r.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis if missing")
    add_archive_options(r)
    r.set_defaults(func=_report)


@lock.holds_outputs("report", lambda a: [a.run_dir, a.out])
def _report(args: argparse.Namespace) -> int:
    from ..services.report import report_run  # matplotlib, the fit's library, the archive

    d = Path(args.run_dir)
    if not d.is_dir():
        raise InputError(f"{d}: not a run folder")
    for name in ("model.json", "report.json"):  # before the archive is searched for its model
        if not (d / name).is_file():
            raise InputError(
                f"{d}: no {name} (fit the run first: quickhealth identify fit "
                f"{d / 'measurements.csv'} --robot ROBOT --out {d})"
            )
    out = Path(args.out) if args.out else d / "report.html"
    reads = ("model.json", "report.json", "measurements.csv", "plan.json", "run.json")
    reads += ("diagnosis.json", "journal.jsonl")
    refuse_overwriting_inputs([("--out", out)], [d / n for n in reads if (d / n).exists()])
    notes: list[str] = []
    arch, robot = (open_archive(args), args.robot) if args.robot else _archived_as(args, d, notes)
    spec = (
        None
        if args.threshold_mm is None
        else Spec(args.threshold_mm, ThresholdFigure(args.figure), "--threshold-mm")
    )
    res = report_run(
        d,
        archive=arch,
        robot=robot,
        run_id=args.run_id,
        options=ReportOptions(accuracy_spec=spec, diagnose_if_missing=not args.no_diagnose),
        html=out,
    )
    for line in res.report.judgement.lines():
        print(line)
    turned = res.turned_words()
    if turned:
        print(turned)
    for line in notes:
        print(line)
    print(
        f"wrote {out} ({len(res.report.page.plots)} plots), {res.pdf} (one page) and updated "
        f"{res.report_json}"
    )
    return 0


def _archived_as(
    args: argparse.Namespace, d: Path, notes: list[str]
) -> tuple[Archive | None, str | None]:
    """The archive and robot under which run folder ``d`` was archived (``archive add``), if
    it was: a run of the folder's run id whose archived model.json is this folder's, under one
    robot only.  An archive that does not exist is not created.  What it found, or why it
    left the trend out, goes to ``notes`` (printed after the verdict)."""
    from ..archive import Archive, NoArchive, default_root, run_metadata  # SQLAlchemy
    from ..archive.db import index_url

    root = Path(args.archive) if args.archive else default_root()
    url = index_url(args.db)
    if url is None and not (root / "index.sqlite").is_file():
        notes.append(f"no archive at {root}: the run is judged without a baseline")
        return None, None
    try:
        arch = Archive.open(root, url, create=False, timeout_s=args.db_timeout)
    except NoArchive:
        return None, None
    rid = args.run_id or run_metadata(d).get("run_id") or d.resolve().name
    model = (d / "model.json").read_bytes()
    found, refitted = [], []
    for robot in arch.robots():
        for rec in arch.runs(robot):
            if rec.run_id == rid:
                mp = arch.folder(rec) / "model.json"
                same = mp.is_file() and mp.read_bytes() == model
                (found if same else refitted).append(robot)
    if len(found) != 1:
        if not found and refitted:
            notes.append(
                f"note: run {rid} of robot {', '.join(refitted)} in the archive {arch.root} has "
                f"another model.json than {d} (refitted since archive add?): no trend section; "
                "give --robot to report against it anyway"
            )
        elif not found:
            notes.append(f"{d} is not in the archive {arch.root}: judged without a baseline")
        return None, None
    notes.append(f"{d} is run {rid} of robot {found[0]} in the archive {arch.root}")
    return arch, found[0]
