"""The History screen's content: a robot's archived runs and quick checks with their verdicts
(a run's: the one its report gave, :func:`~..reporting.verdict.recorded_verdict`; a check's:
its own), the latest run's verdict lines, and the trend in words and as a PNG."""

from __future__ import annotations

from pathlib import Path

from ...identify.errors import InputError
from ...identify.trend import assess_trend
from ..archive import Archive, check_lines, run_state
from ..formats import read_report
from ..reporting.verdict import Spec, ThresholdFigure, recorded_verdict
from . import jobs
from .offload import offload
from .views import History, HistoryRow


def robot_history(archive: Archive, robot_name: str, spec: Spec | None, png: Path) -> History:
    """This robot's archived runs and quick checks, oldest first, each with the verdict its
    report (a check: its own) gave; the latest run's verdict lines; the trend's words."""
    root = shown_path(archive.root)
    try:
        recs = archive.runs(robot_name)
    except InputError:
        return History(robot_name, (), "no runs archived yet", archive=root)
    rows = []
    latest: tuple[str, ...] = ()
    for r in recs:
        doc = _report_json(archive.folder(r))
        got = recorded_verdict(doc)
        verdict, reason = (got[0].value, got[1]) if got else ("not judged", "no report yet")
        section = doc.get("verdict") if isinstance(doc.get("verdict"), dict) else {}
        latest = tuple(str(x) for x in section.get("lines", ())) or (
            f"{verdict.upper()}: {reason}",
        )
        rows.append(
            HistoryRow(
                run_id=r.run_id,
                when=r.time_utc[:16].replace("T", " "),
                mean_mm=r.mean_mm,
                std_mm=r.std_mm,
                max_mm=r.max_mm,
                verdict=verdict,
                baseline=r.baseline,
                reason=reason,
            )
        )
    checks = archive.checks(robot_name)
    for c in checks:
        rows.append(
            HistoryRow(
                run_id=c.check_id,
                when=c.time_utc[:16].replace("T", " "),
                mean_mm=float("nan"),
                std_mm=float("nan"),
                max_mm=float("nan"),
                verdict=c.verdict,
                kind="check",
                reason=f"{c.poses} poses vs baseline {c.baseline_run_id}"
                + (f": {c.changes}" if c.changes else ""),
            )
        )
    rows.sort(key=lambda x: x.when)
    base = next((i for i, r in enumerate(recs) if r.baseline), 0)
    result = assess_trend(
        [run_state(archive, r) for r in recs],
        base,
        threshold_mm=None if spec is None else spec.mm,
        threshold_figure=ThresholdFigure.MAX.value if spec is None else spec.figure.value,
    )
    prog = result.prognoses.get(ThresholdFigure.MAX.value if spec is None else spec.figure)
    words = "; ".join(result.change_flags()[:2]) or "no change since the baseline"
    if prog is not None and len(recs) > 2:
        words += "; " + prog.words()
    runs = tuple(x for x in rows if x.kind == "run")
    png = offload(
        jobs.trend_png_job,
        runs,
        None if spec is None else spec.mm,
        str(png),
    )
    return History(
        robot_name,
        tuple(rows),
        words,
        flagged=bool(latest) and latest[0].startswith("FLAGGED"),
        pngs=(png,),
        checks=tuple(check_lines(checks)),
        latest=latest,
        archive=root,
    )


def shown_path(p: Path) -> str:
    """A folder as the screens show it: relative to the working folder when inside it, from
    ``~`` when inside the home folder, else absolute."""
    for base, prefix in ((Path.cwd(), "./"), (Path.home(), "~/")):
        try:
            return prefix + str(p.relative_to(base))
        except ValueError:
            continue
    return str(p)


def _report_json(folder: Path) -> dict[str, object]:
    """A run folder's report.json as a dict ({} when absent or unreadable)."""
    try:
        doc = read_report(folder / "report.json")
    except (InputError, OSError):
        return {}
    return doc if isinstance(doc, dict) else {}
