"""quickhealth plan — generate the fixed measurement loop (paper Sec. 3, Fig. 3).

    quickhealth plan --cell CELL --n N [--seed S] [--optimal K [--baseline RUN_DIR]]
        [--iso9283 [CYCLES]] [--model-order K] [--strict] --out DIR
    quickhealth plan select CANDIDATES.csv --robot ROBOT --n N --out CHOSEN.csv
        [--baseline RUN_DIR]

CELL is a cell file (TOML, docs/plan.md) or the built-in name ``reference`` (a UR5 on an
optical table, the stereo camera about 2 m in front).  Writes DIR/plan.json (poses with joint
targets and leg types, every dropped candidate with its reason, the summary and a content
hash), DIR/loop.script (URScript of the loop) and the Fig. 6 plots DIR/fig6_joints.png and
DIR/fig6_targets.png.  Nothing is written when the input is refused (exit status 2).
--optimal K keeps K of the feasible targets, chosen by a design (the first by the predicted
workspace TCP error band of the model fitted later, I-optimal, the rest to represent the
feasible candidates; docs/plan.md), then orders them and checks their legs as for any plan;
--baseline RUN_DIR takes the design's prior from a fitted run (its orders, effects and
residual scatter).  --iso9283 adds the ISO 9283 cube's five poses, visited in
cycles after the loop (:mod:`~quickhealth.station.planning.iso_cube`).  The first lines say
whether the plan supports the error model it is for (--model-order, default 2; the rule:
:mod:`~quickhealth.station.planning.adequacy`): a warning when not, exit 2 with --strict.

``plan select`` picks N rows of a file of candidate joint configurations (CSV v1 joint
columns q1 … qN, deg; every other column is carried along, never read) by the same
criterion, and writes them with all their columns to CHOSEN.csv.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...identify.design import Criterion, DesignSettings
from ...identify.errors import InputError
from ...identify.linearize import InstrumentNoise
from ...identify.transforms import make_T
from .. import options
from ..formats import load_robot
from ..fsio import claim_output_folder, foreign_results, refuse_overwriting_inputs, write_atomic
from ..planning.cell import load_cell
from ..run import lock

if TYPE_CHECKING:  # the type only: the planner loads the collision library
    from ..planning.planner import PlanResult


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``plan`` to the command line."""
    p = subparsers.add_parser(
        "plan",
        help="generate the fixed measurement loop (plan.json, loop.script, plots)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    # required without a sub-command (checked in run: `plan select` has its own)
    p.add_argument("--cell", help="cell file (TOML) or built-in name 'reference' (required)")
    p.add_argument(
        "--n", type=options.PLAN_POSES, help="number of random target poses (paper: 150; required)"
    )
    p.add_argument("--seed", type=options.SEED, default=0, help="random seed (default 0)")
    p.add_argument("--out", type=Path, help="output folder (required)")
    p.add_argument(
        "--optimal",
        type=options.PLAN_POSES,
        default=None,
        metavar="K",
        help="keep K of the feasible targets, chosen by an I-optimal design",
    )
    p.add_argument(
        "--baseline",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="with --optimal: a fitted run folder whose orders, effects and residual scatter "
        "are the design's prior (default: the stated prior)",
    )
    p.add_argument(
        "--iso9283",
        type=int,
        nargs="?",
        const=5,
        default=None,
        metavar="CYCLES",
        help="add the ISO 9283 cube's five poses, visited CYCLES times after the loop (5; the "
        "standard's 30): the report's pose accuracy and repeatability, on any arm",
    )
    p.add_argument(
        "--model-order",
        type=options.ORDER,
        default=2,
        help="the Chebyshev order of the error model the plan must support (2): a plan with "
        "too few poses or too little joint coverage for it is warned about",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse (exit 2, nothing written) a plan too small for that model",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write into --out even if it holds another plan, a run or a fit",
    )
    p.set_defaults(func=run, plan_parser=p)
    sub = p.add_subparsers(dest="plan_command", metavar="SUBCOMMAND")
    s = sub.add_parser(
        "select",
        help="choose N rows of candidate joint configurations by an optimal design",
        description=(
            "Choose N rows of CANDIDATES.csv (CSV v1 joint columns q1 ... qN, deg; other "
            "columns carried along, never read) that minimise the predicted workspace TCP "
            "error band of the model fitted later (I-optimal; or D-optimal), over the error "
            "model's coefficients with a stated prior for the orders (docs/plan.md)."
        ),
    )
    s.add_argument("candidates", type=Path, help="CSV of candidate joint configurations")
    s.add_argument("--robot", required=True, help="built-in robot name or description file")
    s.add_argument("--n", required=True, type=options.PLAN_POSES, help="rows to choose")
    s.add_argument("--out", required=True, type=Path, help="CHOSEN.csv")
    s.add_argument(
        "--criterion", choices=("I", "D"), default="I", help="I-optimal (default) or D-optimal"
    )
    s.add_argument(
        "--position-only",
        action="store_true",
        help="the instrument measures positions only (a laser tracker); default: full pose",
    )
    s.add_argument(
        "--tool-mm",
        default="0,0,100",
        help="the measured point on the flange, x,y,z mm (default 0,0,100)",
    )
    s.add_argument(
        "--sigma-pos-mm", type=options.SIGMA_POS_MM, default=0.03, help="instrument noise (0.03)"
    )
    s.add_argument(
        "--sigma-rot-mrad",
        type=options.SIGMA_ROT_MRAD,
        default=0.1,
        help="instrument orientation noise (0.1)",
    )
    s.add_argument(
        "--baseline",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="a fitted run folder of this robot: its orders, effects and residual scatter are "
        "the design's prior (default: the stated prior)",
    )
    s.set_defaults(func=run_select)


@lock.holds_outputs("plan", lambda a: [a.out])
def run(args: argparse.Namespace) -> int:
    """Plan, validate the plan document, then write plan.json, loop.script and plots
    (:func:`~quickhealth.station.services.planning.plan_folder`)."""
    from ..services.planning import PLAN_FILES, plan_folder  # the planner: the collision library

    missing = [
        o for o, v in (("--cell", args.cell), ("--n", args.n), ("--out", args.out)) if v is None
    ]
    if missing:
        args.plan_parser.error(f"the following arguments are required: {', '.join(missing)}")
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    cell_file = Path(args.cell) if Path(args.cell).is_file() else None
    refuse_overwriting_inputs([("--out", out / n) for n in PLAN_FILES], [cell_file])
    claim_output_folder(out, foreign_results(out, "plan"), force=args.force)  # before the work
    if args.baseline is not None and args.optimal is None:
        args.plan_parser.error("--baseline: only with --optimal K (the design's prior)")
    cell = load_cell(args.cell)
    prior = None
    if args.baseline is not None:
        from ..services.planning import baseline_prior

        prior = baseline_prior(args.baseline, cell.robot)

    tty = sys.stderr.isatty()

    def progress(stage: str, done: int, total: int) -> None:
        # progress on a terminal only, overwritten in place: errors stay one line
        if tty and total:
            end = "\r\033[K" if done == total else "\r"
            sys.stderr.write(f"{stage}: {done}/{total}{end}")
            sys.stderr.flush()

    from ..planning.adequacy import adequacy  # the planner's result

    said: list[str] = []

    def check(plan: PlanResult) -> None:
        """The plan against the model it must support: warned, refused under --strict."""
        a = adequacy(plan, args.model_order)
        if a.adequate:
            said.append(
                f"supports the order-{a.model_order} error model: {a.kept} poses (at least "
                f"{a.needed}), every joint spanning at least 60 % of its usable range"
            )
            return
        if args.strict:
            raise InputError(f"--strict: {'; '.join(a.problems)} ({a.rule()}); nothing written")
        said.extend(f"warning: {p}" for p in a.problems)
        said.append(f"  ({a.rule()}; --strict refuses such a plan)")

    res = plan_folder(
        cell, args.n, args.seed, out, force=args.force, progress=progress,
        optimal=args.optimal, design_prior=prior, iso_cycles=args.iso9283, check=check,
    )  # fmt: skip
    if res.replacing:
        print(res.replacing, file=sys.stderr)
    for line in said:  # first: can the plan do what it is for
        print(line)
    for line in res.result.summary():
        print(line)
    iso = [p for p in res.result.poses if p.name.startswith("ISO_")]
    if iso:
        p1, p2 = iso[0].T_world_target[:3, 3], iso[1].T_world_target[:3, 3]
        side = float(np.linalg.norm(p1 - p2)) / (0.4 * np.sqrt(3.0))  # P2 is 40 % of C1–C7 in
        print(
            f"ISO 9283: a {side * 1e3:.0f} mm cube centred at "
            f"({', '.join(f'{v * 1e3:.0f}' for v in p1)}) mm (world), its five poses visited "
            f"{len(iso) // 5} times after the loop ({len(iso)} poses, ISO_P1_C01 …)"
        )
    print(f"plan {res.plan.hash}")
    print("wrote " + ", ".join(str(f) for f in res.paths))
    return 0


@lock.holds_outputs("plan select", lambda a: [a.out])
def run_select(args: argparse.Namespace) -> int:
    """``plan select``: the rows an optimal design chooses, written with all their columns."""
    from ..services.planning import select_rows  # the planner's module: the collision library

    refuse_overwriting_inputs([("--out", args.out)], [args.candidates])
    try:
        tool = np.array([float(v) for v in args.tool_mm.split(",")]) * 1e-3
    except ValueError:
        raise InputError(f"--tool-mm {args.tool_mm!r}: expected x,y,z in mm") from None
    if tool.shape != (3,) or not np.all(np.isfinite(tool)) or np.linalg.norm(tool) > 2.0:
        raise InputError(f"--tool-mm {args.tool_mm!r}: expected x,y,z in mm, within 2000 mm")
    robot = load_robot(args.robot)
    settings = DesignSettings(
        criterion=Criterion(args.criterion),
        orientation=not args.position_only,
        noise=InstrumentNoise(args.sigma_pos_mm * 1e-3, args.sigma_rot_mrad * 1e-3),
        T_flange_target=make_T(np.eye(3), tool),
    )
    if args.baseline is not None:
        from ..services.planning import baseline_prior

        settings = replace(settings, prior=baseline_prior(args.baseline, robot))
    sel = select_rows(args.candidates, robot, args.n, settings)
    write_atomic(args.out, sel.text)
    r = sel.result
    print(
        f"chose {len(sel.rows)} of {r.n_candidates} rows ({args.criterion}-optimal, "
        f"{r.n_params} coefficients; {r.n_information} by information, {r.n_spread} to "
        f"represent the candidates; prior: {r.prior_source}): predicted workspace TCP band "
        f"{r.band_mm:.4f} mm rms (median of 20 random choices of {len(sel.rows)}: "
        f"{r.random_band_mm:.4f} mm)"
    )
    if r.left_out:
        print(f"the baseline's effects left out of the design: {', '.join(r.left_out)}")
    print(f"wrote {args.out}")
    return 0
