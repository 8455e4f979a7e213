"""``quickhealth reprocess``: refit (and re-detect) archived runs, in parallel or on Dask.

quickhealth reprocess [ROBOT] [--runs IDS] [--calibration CAL.json] [--orders keep|select]
    [--scheduler ADDRESS] [--workers N] [--report [--threshold-mm X]] [--update-index]
    Each run's fit goes to RUN/reprocessed/TAG (:mod:`quickhealth.station.reprocess`); with
    --report each is also judged against the archive as ``quickhealth report`` judges it.
    Exit 3 when a run failed.
"""

from __future__ import annotations

import argparse
import sys
import time

from ...identify.assess import MAX_ORDER, WORKSPACE_SAMPLES
from ...identify.errors import InputError
from .. import options, workers
from ..reporting.verdict import Spec, ThresholdFigure
from .archive import add_archive_options, open_archive


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``reprocess``."""
    rp = subparsers.add_parser(
        "reprocess", help="refit (and re-detect) archived runs, in parallel or on Dask"
    )
    rp.add_argument("robot", nargs="?", help="default: every robot")
    add_archive_options(rp)
    rp.add_argument("--runs", default=None, help="comma-separated run ids (default all)")
    rp.add_argument("--calibration", default=None, help="new camera calibration: re-detect")
    rp.add_argument("--orders", choices=("keep", "select"), default="keep")
    rp.add_argument(
        "--max-order",
        type=options.ORDER,
        default=MAX_ORDER,
        help=f"cap of every series' order with --orders select ({MAX_ORDER})",
    )
    rp.add_argument("--tag", default="reprocessed", help="output folder name in each run")
    rp.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786)")
    rp.add_argument(
        "--scheduler-timeout",
        type=options.TIMEOUT_S,
        default=10.0,
        help="seconds to reach the scheduler and find a worker (10)",
    )
    for opt, what in (
        ("--tls-ca-file", "the fleet's CA certificate (PEM)"),
        ("--tls-cert", "this machine's certificate (PEM)"),
        ("--tls-key", "this machine's private key (PEM)"),
    ):
        rp.add_argument(opt, default=None, help=f"with a tls:// --scheduler: {what}")
    rp.add_argument(
        "--workers", type=options.WORKERS, default=None, help="local processes (CPU count)"
    )
    rp.add_argument("--workspace-samples", type=options.SAMPLES, default=WORKSPACE_SAMPLES)
    rp.add_argument(
        "--update-index",
        action="store_true",
        help="replace the indexed figures (and, with --report, the verdict) with the "
        "reprocessed ones",
    )
    rp.add_argument(
        "--report",
        action="store_true",
        help="also judge each run: the report's sections and verdict in its report.json "
        "(runs the diagnosis: slower)",
    )
    rp.add_argument(
        "--threshold-mm",
        type=options.LENGTH_MM,
        default=None,
        help="with --report: the accuracy spec (mm) instead of each run's own",
    )
    rp.add_argument(
        "--figure",
        choices=[f.value for f in ThresholdFigure],
        default=ThresholdFigure.MAX.value,
        help="figure the spec applies to (max)",
    )
    rp.set_defaults(func=_reprocess)


@workers.owns_workers
def _reprocess(args: argparse.Namespace) -> int:
    from ..reprocess import (  # the fit, the archive
        ReprocessResult,
        check_scheduler,
        jobs_for_archive,
        reprocess,
        scheduler_security,
    )

    security = None
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
        security = scheduler_security(args.scheduler, args.tls_ca_file, args.tls_cert, args.tls_key)
    elif args.tls_ca_file or args.tls_cert or args.tls_key:
        raise InputError("--tls-ca-file, --tls-cert and --tls-key need a tls:// --scheduler")
    arch = open_archive(args)
    runs = None if args.runs is None else [r.strip() for r in args.runs.split(",") if r.strip()]
    jobs = jobs_for_archive(
        arch,
        args.robot,
        run_ids=runs,
        tag=args.tag,
        calibration=args.calibration,
        orders=args.orders,
        max_order=args.max_order,
        workspace_samples=args.workspace_samples,
        report=args.report,
        spec=None
        if args.threshold_mm is None
        else Spec(args.threshold_mm, ThresholdFigure(args.figure), "--threshold-mm"),
    )
    if args.scheduler_timeout <= 0:
        raise InputError(f"--scheduler-timeout must be > 0, got {args.scheduler_timeout}")
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else "local processes"
    print(f"reprocessing {len(jobs)} runs on {where}", file=sys.stderr, flush=True)
    t0 = time.monotonic()

    def progress(k: int, n: int, r: ReprocessResult) -> None:
        el = time.monotonic() - t0
        left = el / k * (n - k)
        print(
            f"  [{k}/{n}] {r.robot}/{r.run_id} {'ok' if r.ok else 'FAILED'} "
            f"({el:.0f} s, about {left:.0f} s left)",
            file=sys.stderr,
            flush=True,
        )

    results = reprocess(
        jobs,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=progress,
        scheduler_timeout_s=args.scheduler_timeout,
        index_url=arch.url,  # local workers only; a Dask worker reads its own environment
        security=security,
    )
    for r in results:
        print(r.line())
        if r.ok and args.update_index:
            arch.update_figures(r.robot, r.run_id, r.figures_mm)
            if r.fit_as_baseline is not None:  # --report: the reprocessed run's verdict
                arch.set_healthy(r.robot, r.run_id, r.fit_as_baseline)
    failed = sum(not r.ok for r in results)
    if failed:
        print(f"{failed} of {len(results)} runs failed", file=sys.stderr)
        return 3
    return 0
