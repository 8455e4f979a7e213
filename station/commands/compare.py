"""``quickhealth compare`` (also ``identify compare``): add an effect, watch the held-out error fall.

    quickhealth compare DIR/model.json MEAS.csv --effects LIST
        [--heldout HELD.csv] [--folds K] [--json OUT.json] [--plots DIR]

Fits the model of DIR/model.json (fitted to MEAS.csv, e.g. by ``identify fit``) again without
and with the effects of LIST, with the same Chebyshev orders, and reports the position and
rotation RMS per axis and overall on HELD.csv, or by K-fold cross-validation of MEAS.csv when
there is no held-out file.  --plots writes the residuals before and after against each
effect's regressor (compare.png).  Exit status 0, 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ...identify.compare import compare_effect, plot_comparison
from ...identify.errors import InputError
from .. import options
from ..formats import check_fit_rows, read_measurements, read_model, write_text_atomic
from ..fsio import refuse_overwriting_inputs, write_figure
from ..progress import Progress


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``compare`` sub-command to ``subparsers`` (the top level and ``identify``'s:
    one definition, two doors)."""
    c = subparsers.add_parser(
        "compare",
        help="fit with and without an effect, held-out error before and after",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(c)
    c.set_defaults(func=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's arguments (used by ``identify compare`` and the top-level ``compare``)."""
    p.add_argument("model", type=Path, help="model.json of the fit without the effect")
    p.add_argument("meas", type=Path, help="the measurement CSV the model was fitted to")
    p.add_argument(
        "--effects",
        required=True,
        help="comma-separated effects to add, e.g. backlash:j2 or compliance:j2,thermal",
    )
    p.add_argument("--heldout", type=Path, help="held-out measurement CSV (else cross-validate)")
    p.add_argument(
        "--folds", type=options.FOLDS, default=5, help="cross-validation folds (default 5)"
    )
    p.add_argument("--json", type=Path, help="write the comparison as JSON here")
    p.add_argument("--plots", type=Path, help="folder for compare.png")
    p.add_argument(
        "--quiet", action="store_true", help="no progress on stderr (bar or stage lines)"
    )


def run(args: argparse.Namespace) -> int:
    """Run the comparison; prints the table, writes --json and --plots."""
    png = None if args.plots is None else args.plots / "compare.png"
    if args.plots is not None and args.plots.exists() and not args.plots.is_dir():
        raise InputError(f"{args.plots}: --plots must be a folder")
    refuse_overwriting_inputs(
        [("--json", args.json), ("--plots", png)], [args.model, args.meas, args.heldout]
    )
    fitted = read_model(args.model)
    nj = fitted.robot.n_joints
    train = read_measurements(args.meas, nj)
    check_fit_rows(train, args.meas)  # compare fits the training data again
    held = read_measurements(args.heldout, nj) if args.heldout else None
    with Progress(quiet=args.quiet) as say:  # a bar on a terminal, stage lines in a log
        cmp = compare_effect(
            fitted, train, args.effects, heldout=held, folds=args.folds, progress=say
        )
    print("\n".join(cmp.summary()))
    if args.json:
        write_text_atomic(args.json, json.dumps(cmp.to_dict(), indent=1) + "\n")
    if png is not None:
        write_figure(plot_comparison(cmp), png, dpi=110)
        print(f"plot: {png}")
    return 0
