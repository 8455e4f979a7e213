"""``quickhealth demo``: the whole loop on the built-in simulated cell."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...identify.errors import InputError
from .. import options


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``demo``."""
    p = subparsers.add_parser(
        "demo",
        help="the whole loop on the simulated cell: plan, runs, fit, diagnosis, trend, reports",
        description=(
            "Plans the fixed loop for the paper's reference cell (or --cell CELL, e.g. ur10e), "
            "runs it three times on the simulated cell (UR controller simulator driven by the real ur-rtde client, "
            "emulated pan motor, rendered stereo images) — a baseline, a healthy repeat and a "
            "worn robot a month later — fits, diagnoses, archives, trends and writes an HTML "
            "report per run.  Exit 0 when the trend flags the worn run (and only it), else 1."
        ),
    )
    p.add_argument("--out", default="demo-output", help="output folder (default %(default)s)")
    p.add_argument(
        "--cell",
        default="reference",
        help="cell file or built-in name whose arm is simulated (default %(default)s: the "
        "paper's UR5; ur10e: the built-in UR10e cell)",
    )
    p.add_argument(
        "--n", type=options.PLAN_POSES, default=150, help="candidate targets to plan (default 150)"
    )
    p.add_argument("--seed", type=options.SEED, default=0, help="planner seed")
    p.add_argument(
        "--speed-factor",
        type=float,
        default=20.0,
        help="simulated arm runs this many times faster than life (default %(default)s)",
    )
    p.add_argument(
        "--image-scale",
        type=float,
        default=0.5,
        help="simulated sensor size relative to 4000x3000 px (default %(default)s)",
    )
    p.add_argument(
        "--degrade",
        default="j2.ex.c0=5e-4",
        help="the wear of the month-later run (m or rad; default %(default)s)",
    )
    p.set_defaults(func=_demo)


def _demo(args: argparse.Namespace) -> int:
    from rich.console import Console  # the demo's screen: only when it runs
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TimeRemainingColumn

    from ..demo import run_demo  # the whole station and the simulated cell
    from ..planning.cell import load_cell  # the planner's cell reader
    from ..sim.world import parse_degradation  # the simulated world: OpenCV, the twin

    if args.n < 1:
        raise InputError(f"--n must be at least 1, got {args.n}")
    if not 0.1 <= args.speed_factor <= 100:
        raise InputError(f"--speed-factor must be in 0.1..100, got {args.speed_factor}")
    if not 0.05 <= args.image_scale <= 1:
        raise InputError(f"--image-scale must be in 0.05..1, got {args.image_scale}")
    degrade = parse_degradation(args.degrade)
    load_cell(args.cell)  # a bad cell is one line before anything is written
    console = Console(highlight=False)
    bars = Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )
    tasks: dict[str, TaskID] = {}

    def pose_progress(run_id: str, done: int, total: int) -> None:
        if run_id not in tasks:
            tasks[run_id] = bars.add_task(f"run {run_id}: poses measured", total=total)
        bars.update(tasks[run_id], completed=done)

    with bars:
        res = run_demo(
            Path(args.out),
            cell=args.cell,
            n_candidates=args.n,
            seed=args.seed,
            speed_factor=args.speed_factor,
            image_scale=args.image_scale,
            degrade=degrade,
            say=console.print,
            pose_progress=pose_progress,
        )
    console.print("")
    console.print(f"demo finished in {res.seconds:.0f} s; everything is in {res.out}/")
    console.print(f"  {'run':<10} {'mean mm':>8} {'std mm':>8} {'max mm':>8}  trend     report")
    for r in res.runs:
        f = r.figures_mm
        console.print(
            f"  {r.run.run_id:<10} {f['mean']:8.3f} {f['std']:8.3f} {f['max']:8.3f}  "
            f"{r.verdict:<9} {r.report_html or '-'}"
        )
    console.print(
        f"  archive: {res.out / 'archive'}   log of every command: {res.out / 'demo.log'}"
    )
    if res.expected_flag_ok:
        console.print(
            f"the trend flagged the worn run, naming the fault it carries first "
            f"({', '.join(res.worn_faults)}), and only it."
        )
        return 0
    console.print("[bold red]the trend did not single out the worn run as expected[/]")
    return 1
