"""``quickhealth trend``: a robot's runs over time against its baseline; exit 1 when flagged.

quickhealth trend ROBOT [--threshold-mm X] [--figure max] [--tolerance-mm X] [--json OUT] [--plot PNG]
    First the latest run's verdict in words (:func:`quickhealth.station.reporting.verdict.judge`,
    the same lines its report and the TUI show), then the runs with their workspace error
    figures and verdicts, warnings, prognosis and quick checks.  The spec is the latest run's
    (its cell or robot file's ``spec_mm``); --threshold-mm overrides it.  Exit 1 when the
    latest run is flagged: above the spec, or changed since the baseline (an error curve
    beyond the combined uncertainty, a control-chart alarm); --fail-on threshold: only the
    spec counts.  A baseline is never flagged against itself.
"""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from ...identify.errors import InputError
from .. import options
from ..formats.common import json_plain, write_text_atomic
from ..formats.report import trend_to_json
from ..fsio import refuse_outputs_inside, refuse_overwriting_inputs, write_figure
from ..reporting.verdict import (
    Figures,
    HealthVerdict,
    Judgement,
    MissingEffect,
    Spec,
    ThresholdFigure,
    judge,
    missing_effect_in,
    spec_of_run,
)
from .archive import add_archive_options, open_archive

if TYPE_CHECKING:  # types only: the archive loads SQLAlchemy, the trend scipy.stats
    from ...identify.trend import TrendResult
    from ..archive import Archive, RunRecord


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``trend``."""
    t = subparsers.add_parser(
        "trend",
        help="a robot's runs over time against its baseline; exit 1 when flagged",
        description=(
            "Workspace error figures, error-curve changes judged against the combined "
            "uncertainty, EWMA control limits, prognosis and root-cause hints. Exit status 1 "
            "when the latest run is flagged."
        ),
    )
    t.add_argument("robot")
    add_archive_options(t)
    t.add_argument(
        "--threshold-mm",
        type=options.LENGTH_MM,
        default=None,
        help="the accuracy spec (mm) instead of the latest run's (its cell or robot file's)",
    )
    t.add_argument(
        "--figure",
        choices=[f.value for f in ThresholdFigure],
        default=ThresholdFigure.MAX.value,
        help="figure the spec applies to (max)",
    )
    t.add_argument(
        "--tolerance-mm",
        type=options.LENGTH_MM,
        default=None,
        help="level the prognosis extrapolates to (default: the spec)",
    )
    t.add_argument(
        "--alpha",
        type=options.PROBABILITY,
        default=1e-4,
        help="false-alarm probability of the curve test per run (1e-4)",
    )
    t.add_argument(
        "--min-change-mm",
        type=options.CHANGE_MM,
        default=0.01,
        help="smallest translation change that counts (0.01)",
    )
    t.add_argument(
        "--min-change-mrad",
        type=options.CHANGE_MRAD,
        default=0.02,
        help="smallest rotation change that counts (0.02)",
    )
    t.add_argument(
        "--fail-on",
        choices=("any", "threshold"),
        default="any",
        help="what makes the exit status 1 (any: a flagged verdict; threshold: above the spec)",
    )
    t.add_argument("--json", default=None, help="write the trend as JSON here")
    t.add_argument("--plot", default=None, help="write the trend figure (PNG) here")
    t.set_defaults(func=_trend)


def _trend(args: argparse.Namespace) -> int:
    for name in ("threshold_mm", "tolerance_mm"):
        v = getattr(args, name)
        if v is not None and not v > 0:
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
    if not 0 < args.alpha < 1:
        raise InputError(f"--alpha must be in (0, 1), got {args.alpha}")
    from ..archive import (  # the archive and the trend: SQLAlchemy, scipy.stats
        check_lines,
        missing_words,
        trend_for,
        trend_runs,
    )

    refuse_overwriting_inputs([("--json", args.json), ("--plot", args.plot)], [])
    arch = open_archive(args)
    # the archive (its index, its run folders) is this command's input
    refuse_outputs_inside([("--json", args.json), ("--plot", args.plot)], arch.root, "the archive")
    recs, missing = trend_runs(arch, args.robot)  # the runs the trend judges
    latest = recs[-1]
    override = (
        None
        if args.threshold_mm is None
        else Spec(args.threshold_mm, ThresholdFigure(args.figure), "--threshold-mm")
    )
    spec = spec_of_run(arch.folder(latest), override)  # the latest run's, as its report's
    res = trend_for(
        arch,
        args.robot,
        threshold_mm=None if spec is None else spec.mm,
        threshold_figure=ThresholdFigure.MAX.value if spec is None else spec.figure.value,
        tolerance_mm=args.tolerance_mm,
        alpha=args.alpha,
        min_change_m=args.min_change_mm * 1e-3,
        min_change_rad=args.min_change_mrad * 1e-3,
    )
    b = res.baseline_index
    from ..services.report import run_diagnosis  # the diagnosis, as the run's report makes it

    j = judge(
        Figures.of_trend(res, res.latest),
        trend=res,
        missing=MissingEffect.of_diagnosis(run_diagnosis(arch.folder(latest))),
        spec=spec,
        baseline_time=recs[b].time_utc,
    )
    # the words first: the latest run's verdict, as its report and the TUI say it
    print(f"{args.robot}: latest run {latest.run_id} ({latest.time_utc})")
    for line in j.lines():
        print(line)
    print(f"\nruns ({len(recs)}; baseline {res.run_ids[b]}; TCP error over the workspace, mm):")
    print(f"  {'run':<24} {'time (UTC)':<21} {'mean':>7} {'std':>7} {'max':>7}  verdict")
    for i, r in enumerate(recs):
        if i < b:
            v = "- (before the baseline)"
        else:
            ji = j if i == res.latest else _judge_earlier(arch, r, res, i, override)
            v = ji.verdict.value + (" (baseline)" if i == b else "")
        f = res.figures_mm
        print(
            f"  {r.run_id:<24} {r.time_utc:<21} {f['mean'][i]:7.3f} {f['std'][i]:7.3f} "
            f"{f['max'][i]:7.3f}  {v}"
        )
    for w in [*missing_words(arch, missing), *res.warnings]:
        print(f"warning: {w}")
    for p in res.prognoses.values():
        print(f"prognosis: {p.words()}")
    # quick checks are listed apart: a verdict against the baseline, not an assessment
    checks = [c for c in arch.checks(args.robot) if c.time_utc >= recs[b].time_utc]
    for line in check_lines(checks):
        print(line)
    if checks and checks[-1].verdict == "changed" and checks[-1].time_utc > latest.time_utc:
        print(
            f"latest quick check {checks[-1].check_id} (after the latest run) says CHANGED: "
            "run a full assessment"
        )
    if args.json:
        doc = json_plain(trend_to_json(res))
        doc["verdict"] = j.as_dict()
        doc["checks"] = [
            {k: v for k, v in c.__dict__.items() if k not in ("root", "path")} for c in checks
        ]
        write_text_atomic(args.json, json.dumps(json_plain(doc), indent=1) + "\n")
    if args.plot:
        from ..reporting.figures import trend_figure  # matplotlib: only for --plot

        write_figure(trend_figure(res, None if spec is None else spec.mm), args.plot, dpi=100)
    if args.fail_on == "threshold":
        return 1 if j.out_of_spec else 0
    return 1 if j.verdict is HealthVerdict.FLAGGED else 0


def _judge_earlier(
    arch: Archive, rec: RunRecord, res: TrendResult, i: int, override: Spec | None
) -> Judgement:
    """Run ``i``'s verdict as the trend gave it when it was the latest (its own spec and
    diagnosis; the trend's verdicts use only the runs up to each run)."""
    folder = arch.folder(rec)
    return judge(
        Figures.of_trend(res, i),
        trend=res,
        missing=missing_effect_in(folder),
        spec=spec_of_run(folder, override),
        index=i,
    )
