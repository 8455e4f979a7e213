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

from quickhealth.station import lock, options


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


def _write(path: Path, data: bytes) -> None:
    from quickhealth.station.fsio import write_atomic

    write_atomic(path, data, durable=True)


@lock.holds_outputs("plan", lambda a: [a.out])
def run(args: argparse.Namespace) -> int:
    """Plan, validate the plan document, then write plan.json, loop.script and plots."""
    from quickhealth.identify.errors import InputError
    from quickhealth.station.fsio import (
        claim_output_folder,
        foreign_results,
        make_dirs,
        refuse_overwriting_inputs,
        replacing_line,
    )
    from quickhealth.station.planning.cell import load_cell
    from quickhealth.station.planning.figures import write_figures
    from quickhealth.station.planning.planfile import dumps, plan_from_dict, plan_to_dict
    from quickhealth.station.planning.planner import plan_loop
    from quickhealth.station.planning.urscript import render_urscript

    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    files = ("plan.json", "loop.script", "fig6_joints.png", "fig6_targets.png")
    cell_file = Path(args.cell) if Path(args.cell).is_file() else None
    refuse_overwriting_inputs([("--out", out / n) for n in files], [cell_file])
    foreign = foreign_results(out, "plan")
    claim_output_folder(out, foreign, force=args.force)  # before the planning work
    cell = load_cell(args.cell)

    tty = sys.stderr.isatty()

    def progress(stage: str, done: int, total: int) -> None:
        # progress on a terminal only, overwritten in place: errors stay one line
        if tty and total:
            end = "\r\033[K" if done == total else "\r"
            sys.stderr.write(f"{stage}: {done}/{total}{end}")
            sys.stderr.flush()

    res = plan_loop(cell, args.n, args.seed, progress)
    doc = plan_to_dict(res)
    plan = plan_from_dict(doc, "plan.json")  # the program is made from the validated document
    script = render_urscript(plan)
    other = _other_plan(out / "plan.json", doc["hash"])
    forced = claim_output_folder(out, foreign + other, force=args.force)
    replaced = [n for n in files if (out / n).exists()]
    why = "the same plan" if "plan.json" in replaced else ""
    said = replacing_line(out, replaced, why, forced)
    make_dirs(out)
    _write(out / "plan.json", dumps(doc).encode("utf-8"))
    _write(out / "loop.script", script.encode("utf-8"))
    figs = write_figures(res, out)
    if said:
        print(said, file=sys.stderr)
    for line in res.summary():
        print(line)
    print(f"plan {doc['hash']}")
    print(f"wrote {out / 'plan.json'}, {out / 'loop.script'}, " + ", ".join(str(f) for f in figs))
    return 0


def _other_plan(path: Path, new_hash: str) -> list[str]:
    """Why ``path`` (an existing plan.json) is another plan than the one of ``new_hash``
    (runs and the trend compare plans by hash: replacing a different plan is not silent)."""
    import json

    if not path.exists():
        return []
    try:
        old = json.loads(path.read_text(encoding="utf-8")).get("hash")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        return [f"a plan.json that cannot be read ({path.name})"]
    if old == new_hash:
        return []
    return [f"another plan ({path.name} {str(old)[:19]}..., this one {new_hash[:19]}...)"]
