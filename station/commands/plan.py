"""quickhealth plan — generate the fixed measurement loop (paper Sec. 3, Fig. 3).

    quickhealth plan --cell CELL --n N [--seed S] --out DIR

CELL is a cell file (TOML, docs/plan.md) or the built-in name ``reference`` (a UR5 on an
optical table, the stereo camera about 2 m in front).  Writes DIR/plan.json (poses with joint
targets and leg types, every dropped candidate with its reason, the summary and a content
hash), DIR/loop.script (URScript of the loop) and the Fig. 6 plots DIR/fig6_joints.png and
DIR/fig6_targets.png.  Nothing is written when the input is refused (exit status 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ...identify.errors import InputError
from .. import lock, options
from ..fsio import claim_output_folder, foreign_results, refuse_overwriting_inputs
from ..planning.cell import load_cell


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``plan`` to the command line."""
    p = subparsers.add_parser(
        "plan",
        help="generate the fixed measurement loop (plan.json, loop.script, plots)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cell", required=True, help="cell file (TOML) or built-in name 'reference'")
    p.add_argument(
        "--n",
        required=True,
        type=options.PLAN_POSES,
        help="number of random target poses (paper: 150)",
    )
    p.add_argument("--seed", type=options.SEED, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument(
        "--force",
        action="store_true",
        help="write into --out even if it holds another plan, a run or a fit",
    )
    p.set_defaults(func=run)


@lock.holds_outputs("plan", lambda a: [a.out])
def run(args: argparse.Namespace) -> int:
    """Plan, validate the plan document, then write plan.json, loop.script and plots
    (:func:`~quickhealth.station.services.planning.plan_folder`)."""
    from ..services.planning import PLAN_FILES, plan_folder  # the planner: the collision library

    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    cell_file = Path(args.cell) if Path(args.cell).is_file() else None
    refuse_overwriting_inputs([("--out", out / n) for n in PLAN_FILES], [cell_file])
    claim_output_folder(out, foreign_results(out, "plan"), force=args.force)  # before the work
    cell = load_cell(args.cell)

    tty = sys.stderr.isatty()

    def progress(stage: str, done: int, total: int) -> None:
        # progress on a terminal only, overwritten in place: errors stay one line
        if tty and total:
            end = "\r\033[K" if done == total else "\r"
            sys.stderr.write(f"{stage}: {done}/{total}{end}")
            sys.stderr.flush()

    res = plan_folder(cell, args.n, args.seed, out, force=args.force, progress=progress)
    if res.replacing:
        print(res.replacing, file=sys.stderr)
    for line in res.result.summary():
        print(line)
    print(f"plan {res.plan.hash}")
    print("wrote " + ", ".join(str(f) for f in res.paths))
    return 0
