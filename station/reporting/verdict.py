"""The one health verdict: healthy, degraded or flagged, why, and what to do
(docs/monitoring.md, "The verdict").

Every door judges a run with :func:`judge` and shows :meth:`Judgement.lines`, the same words
everywhere: the HTML report and its report.json, the technician's Results and History
screens, ``reprocess``, ``trend`` (the latest run), the nightly job (which runs ``report`` and
``trend``) and ``archive add`` (which reads the verdict a report.json carries,
:func:`healthy_of`).  A run is judged on its fit (the workspace TCP error figures), its
diagnosis, the archive's baseline (the trend up to it) and the robot's accuracy spec
(:class:`Spec`, ``spec_mm`` of the cell or robot file: :func:`spec_of_run`), in this order:

- **flagged**: the figure the spec names (the workspace maximum unless it says otherwise) is
  above the spec; or the robot changed since its baseline (an error curve changed beyond the
  two fits' uncertainty, a control-chart alarm).  A run is never flagged against itself: the
  baseline run can only be flagged by the spec;
- **degraded**: within the spec and unchanged, but the mean or max TCP error is more than
  10 % above the baseline run's, or the diagnosis finds a physical effect the model misses;
- **healthy**: none of these.

Without a spec the run is judged against its baseline only, and the words say that no spec is
set.  The figures are the workspace TCP error figures in mm, as report.json, the archive's
index and the trend carry them; with a trend, the run's figures are the index's (like with
like).

SYNOPSIS::

    j = judge(Figures.of_report(doc), trend=res, missing=MissingEffect.of_diagnosis(diag),
              spec=spec_of_run(run_dir))
    j.verdict, j.reason, j.action, j.lines()
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..formats.common import load_json_limited

if TYPE_CHECKING:  # the type only: the trend loads scipy.stats, archive add would wait for it
    from ...identify.trend import TrendResult

#: A run whose mean or max TCP error is this much above the baseline's is degraded.
RISE = 0.10

#: Where to say the spec goes when none is set.
NO_SPEC_WORDS = (
    "no accuracy spec set (spec_mm in the cell or robot file): judged against the baseline only"
)


class HealthVerdict(StrEnum):
    """What a run says about the robot (the value is what report.json and the screens show)."""

    HEALTHY = "healthy"
    DEGRADED = "degraded"
    FLAGGED = "flagged"


class ThresholdFigure(StrEnum):
    """Which workspace TCP error figure a spec applies to."""

    MEAN = "mean"
    STD = "std"
    MAX = "max"


FIGURE_WORDS = {"mean": "mean TCP error", "std": "TCP error spread (std)", "max": "max TCP error"}


@dataclass(frozen=True)
class Spec:
    """The accuracy spec: the TCP error (mm) the application accepts, on one workspace figure
    (the maximum unless it says otherwise), and where it was stated (``source``: "cell
    reference", "robot file arm.toml", "--threshold-mm")."""

    mm: float
    figure: ThresholdFigure = ThresholdFigure.MAX
    source: str = ""

    def words(self) -> str:
        """ "the spec of 2 mm (max TCP error, cell reference)"."""
        where = f", {self.source}" if self.source else ""
        return f"the spec of {self.mm:g} mm ({FIGURE_WORDS[self.figure]}{where})"

    def as_dict(self) -> dict[str, Any]:
        """report.json's ``spec``."""
        return {"mm": self.mm, "figure": self.figure.value, "source": self.source}

    @classmethod
    def of_dict(cls, doc: object) -> Spec | None:
        """A ``spec`` object of report.json (None when absent or not a positive number)."""
        if not isinstance(doc, Mapping):
            return None
        mm, fig = doc.get("mm"), doc.get("figure", "max")
        if not isinstance(mm, int | float) or not (math.isfinite(mm) and mm > 0):
            return None
        if fig not in tuple(ThresholdFigure):
            return None
        return cls(float(mm), ThresholdFigure(fig), str(doc.get("source", ""))[:200])


@dataclass(frozen=True)
class Figures:
    """The workspace TCP error figures of one run, mm (report.json's ``workspace``)."""

    mean_mm: float
    std_mm: float
    max_mm: float

    def of(self, figure: ThresholdFigure) -> float:
        """The figure a spec names."""
        return {"mean": self.mean_mm, "std": self.std_mm, "max": self.max_mm}[figure]

    @classmethod
    def of_report(cls, doc: Mapping[str, Any]) -> Figures:
        """The figures of a report.json document (version 1 or 2)."""
        ws = doc.get("workspace")
        get = ws.get if isinstance(ws, dict) else (lambda k: doc.get(f"workspace_{k}"))
        return cls(*(float(get(k)) for k in ("mean_mm", "std_mm", "max_mm")))

    @classmethod
    def of_trend(cls, trend: TrendResult, index: int) -> Figures:
        """The figures the trend (the archive's index) holds for run ``index``."""
        f = trend.figures_mm
        return cls(f["mean"][index], f["std"][index], f["max"][index])


@dataclass(frozen=True)
class MissingEffect:
    """The diagnosis's top missing effect: its name and the predicted residual drop (mm)."""

    effect: str
    predicted_rms_drop_mm: float | None

    @classmethod
    def of_diagnosis(cls, doc: Mapping[str, Any] | None) -> MissingEffect | None:
        """The first suggested effect of a ``diagnose --json`` document, None when the
        verdict is "adequate" (or there is no diagnosis)."""
        if not doc or doc.get("verdict") != "missing-effect":
            return None
        cands = {c.get("effect"): c for c in doc.get("candidates", [])}
        name = next(iter(doc.get("suggested") or []), None) or next(iter(cands), None)
        if name is None:
            return None
        return cls(str(name), cands.get(name, {}).get("predicted_rms_drop_mm"))


@dataclass(frozen=True)
class Judgement:
    """The verdict on one run, why, what to do, and what it was judged on.

    ``figures`` are the run's (from the archive's index when there is a trend), ``baseline``
    the baseline run's (None without a trend); ``conditions`` names the reference conditions
    of condition-dependent effects ("" when none).  ``changes`` are the trend's words for how
    the run changed since the baseline (empty for the baseline itself).
    """

    verdict: HealthVerdict
    reason: str
    action: str
    figures: Figures
    spec: Spec | None = None
    baseline: Figures | None = None
    baseline_run: str | None = None
    baseline_time: str = ""  # ISO 8601, "" when unknown
    this_is_baseline: bool | None = None
    changes: tuple[str, ...] = ()
    rising: bool = False  # the mean or max TCP error more than RISE above the baseline's
    top_missing_effect: MissingEffect | None = None
    conditions: str = ""
    uncertainty: str = ""  # "" or how the bands were made (an estimated scatter), for the line
    no_baseline: str = "the run is not archived"  # why there is no trend, when there is none

    @property
    def healthy(self) -> bool:
        """True for "healthy"."""
        return self.verdict is HealthVerdict.HEALTHY

    @property
    def out_of_spec(self) -> bool:
        """True when the figure the spec names is above it."""
        s = self.spec
        return s is not None and self.figures.of(s.figure) > s.mm

    @property
    def fit_as_baseline(self) -> bool:
        """Whether later runs may be compared with this one (the archive's ``healthy`` flag,
        which chooses the first baseline): it has not changed or risen since its baseline.  A
        run out of spec, or whose model misses an effect, is still a fair reference for
        change, and a baseline always stays one (its verdict never removes it)."""
        return not self.changes and not self.rising

    def headline(self) -> str:
        """The first line every door prints: ``HEALTHY: …``."""
        return f"{self.verdict.value.upper()}: {self.reason}"

    def spec_line(self) -> str:
        """The run's TCP error against the spec, or that no spec is set."""
        f = self.figures
        err = f"TCP error over the workspace: max {f.max_mm:.3f} mm, mean {f.mean_mm:.3f} mm"
        s = self.spec
        if s is None:
            return f"{err}; {NO_SPEC_WORDS}"
        v = f.of(s.figure)
        where = "above" if v > s.mm else "within"
        return f"{err}; {where} {s.words()}"

    def baseline_line(self) -> str:
        """The run against its baseline, in words."""
        if self.baseline is None or self.baseline_run is None:
            return f"no baseline to compare with: {self.no_baseline}"
        when = _day(self.baseline_time)
        if self.this_is_baseline:
            return f"this run is the baseline{when}: later runs are compared with it"
        b, f = self.baseline, self.figures
        change = "changed" if self.changes else "unchanged"
        return (
            f"{change} since the baseline run {self.baseline_run}{when} (max {b.max_mm:.3f} mm "
            f"then, {f.max_mm - b.max_mm:+.3f} mm now; mean {b.mean_mm:.3f} mm, "
            f"{f.mean_mm - b.mean_mm:+.3f} mm)"
        )

    def lines(self) -> tuple[str, ...]:
        """The verdict in the technician's words, the same at every door: the headline, the
        spec, the baseline, what to do."""
        out = [self.headline(), self.spec_line(), self.baseline_line()]
        out += [f"  - {c}" for c in self.changes[1:6]]
        out.append(f"what to do: {self.action}")
        return tuple(out)

    def as_dict(self) -> dict[str, Any]:
        """The report's ``verdict`` section (report.json and the page's embedded JSON)."""
        data: dict[str, Any] = {
            "mean_mm": self.figures.mean_mm,
            "max_mm": self.figures.max_mm,
            "conditions": self.conditions,
            "uncertainty": self.uncertainty,
            "spec": None if self.spec is None else self.spec.as_dict(),
            "out_of_spec": self.out_of_spec,
        }
        if self.baseline is not None:
            data.update(
                baseline_run=self.baseline_run,
                baseline_time_utc=self.baseline_time,
                baseline_mean_mm=self.baseline.mean_mm,
                baseline_max_mm=self.baseline.max_mm,
                this_is_baseline=self.this_is_baseline,
            )
        top = self.top_missing_effect
        data["top_missing_effect"] = (
            None
            if top is None
            else {"effect": top.effect, "predicted_rms_drop_mm": top.predicted_rms_drop_mm}
        )
        data.update(
            changes=list(self.changes),
            verdict=self.verdict.value,
            reason=self.reason,
            action=self.action,
            fit_as_baseline=self.fit_as_baseline,
            lines=list(self.lines()),
        )
        return data


def judge(
    figures: Figures,
    *,
    trend: TrendResult | None = None,
    missing: MissingEffect | None = None,
    spec: Spec | None = None,
    conditions: str = "",
    uncertainty: str = "",
    baseline_time: str = "",
    no_baseline: str = "",
    index: int | None = None,
) -> Judgement:
    """Healthy, degraded or flagged (see the module docstring), with the reason and the action.

    Parameters
    ----------
    figures : Figures
        The run's workspace TCP error (report.json); replaced by the trend's own figures of
        the latest run when ``trend`` is given and they are finite.
    trend : TrendResult, optional
        The robot's trend up to this run (its latest run), judged against its baseline.
    missing : MissingEffect, optional
        The diagnosis's top missing effect.
    spec : Spec, optional
        The accuracy spec (None: judged against the baseline only).
    baseline_time : str
        When the baseline run was measured (ISO 8601), for the words.
    no_baseline : str
        Without a trend: why there is none (default: the run is not archived).
    index : int, optional
        Judge this run of the trend instead of its latest (the trend's verdicts use only the
        runs up to each run, so this is what the trend said when that run was the latest).
    """
    no_baseline = no_baseline or "the run is not archived"
    base = None
    baseline_run = this_is_baseline = None
    changes: tuple[str, ...] = ()
    fault_action = ""  # what the named fault's dictionary entry recommends
    if trend is not None:  # both figures from the archive's index: like with like
        b = trend.baseline_index
        i = trend.latest if index is None else index
        now = Figures.of_trend(trend, i)
        figures = Figures(*(_finite(v, d) for v, d in zip(_fig(now), _fig(figures), strict=True)))
        base = Figures.of_trend(trend, b)
        baseline_run, this_is_baseline = trend.run_ids[b], b == i
        changes = () if this_is_baseline else tuple(trend.change_flags(i))
        named = [] if this_is_baseline else getattr(trend, "named_changes", lambda i: [])(i)
        fault_action = named[0].action if named and getattr(named[0], "action", "") else ""
        if named and changes:  # the named fault first, in words and units; its statistics last
            c = named[0]
            rest = [x for x in changes if x != c.line()]
            changes = (f"{c.words} changed by {c.size_words()}", *rest, f"in full: {c.line()}")
    rose = [
        (what, now, was)
        for what, now, was in (
            ("mean", figures.mean_mm, None if base is None else base.mean_mm),
            ("max", figures.max_mm, None if base is None else base.max_mm),
        )
        if was is not None and was > 0 and now > (1 + RISE) * was
    ]
    over = spec is not None and figures.of(spec.figure) > spec.mm
    if over:
        assert spec is not None
        v = figures.of(spec.figure)
        verdict = HealthVerdict.FLAGGED
        reason = f"the {FIGURE_WORDS[spec.figure]} is {v:.3f} mm, above {spec.words()}"
        if changes:
            reason += f"; and {_first(changes)}"
        action = (
            "recalibrate the robot (quickhealth export MODEL --ur-calibration FILE) or "
            "compensate its programs (quickhealth compensate); the report's workspace map "
            "shows where the error is largest"
        )
    elif changes:
        verdict = HealthVerdict.FLAGGED
        reason = f"the robot changed since its baseline: {_first(changes)}"
        action = (
            f"{fault_action.rstrip('.')}; then run a new full assessment"
            if fault_action
            else "find what changed at the named joint (a collision, a motor, encoder or "
            "gearbox replaced, a loose mounting), re-zero or recalibrate it, then run a new "
            "full assessment"
        )
    elif rose:
        what, now, was = rose[0]
        verdict = HealthVerdict.DEGRADED
        reason = (
            f"the {what} TCP error is {now:.3f} mm, {now / was - 1:.0%} above the baseline's "
            f"{was:.3f} mm"
        )
        action = "measure again soon and watch the trend: the error is rising"
    elif missing is not None:
        drop = missing.predicted_rms_drop_mm
        verdict = HealthVerdict.DEGRADED
        reason = f"the error model misses a physical effect: {missing.effect}" + (
            f" (adding it would lower the residual RMS by {drop:.3f} mm)"
            if drop is not None
            else ""
        )
        action = (
            f"add it to the model and compare (quickhealth identify compare MODEL MEAS "
            f"--effects {missing.effect})"
        )
    else:
        verdict = HealthVerdict.HEALTHY
        where = "within the spec" if spec is not None else "no spec set"
        if trend is None:
            reason = f"{where}; no baseline yet: {no_baseline}"
            action = (
                "archive the run to compare later runs with it (quickhealth archive add)"
                if no_baseline.startswith("the run is not archived")
                else "give the robot a baseline (quickhealth archive baseline ROBOT RUN_ID, or "
                "b on the TUI's History screen)"
            )
        elif this_is_baseline:
            reason = f"{where}; this run is the robot's baseline"
            action = "nothing: later runs are compared with this one"
        else:
            reason = f"{where} and unchanged since the baseline run {baseline_run}"
            action = "nothing"
    return Judgement(
        verdict=verdict,
        reason=reason,
        action=action,
        figures=figures,
        spec=spec,
        baseline=base,
        baseline_run=baseline_run,
        baseline_time=baseline_time,
        this_is_baseline=this_is_baseline,
        changes=changes,
        rising=bool(rose),
        top_missing_effect=missing,
        conditions=conditions,
        uncertainty=uncertainty,
        no_baseline=no_baseline,
    )


def spec_of_run(run_dir: Path, override: Spec | None = None) -> Spec | None:
    """The accuracy spec a run is judged against: ``override`` (a command's ``--threshold-mm``)
    if given, else report.json's ``spec`` (the fit records the robot file's or the run's),
    else the ``spec_mm`` the run recorded from its cell (run.json, measurements.csv's
    comments); None when nothing states one."""
    if override is not None:
        return override
    rp = run_dir / "report.json"
    doc = load_json_limited(rp, "report") if rp.is_file() else {}
    got = Spec.of_dict(doc.get("spec")) if isinstance(doc, dict) else None
    if got is not None:
        return got
    from ..archive.folders import run_metadata  # the folder's files, read as archive add does

    meta = run_metadata(run_dir)
    return spec_of_meta(meta)


def spec_of_meta(meta: Mapping[str, str]) -> Spec | None:
    """The spec a run's metadata states (``spec_mm``, from its cell), or None."""
    text = meta.get("spec_mm")
    try:
        mm = float(text) if text is not None else math.nan
    except ValueError:
        return None
    if not (math.isfinite(mm) and mm > 0):
        return None
    cell = meta.get("cell")
    return Spec(mm, ThresholdFigure.MAX, f"cell {cell}" if cell else "the run's metadata")


def missing_effect_in(run_dir: Path) -> MissingEffect | None:
    """The top missing effect of a run folder's diagnosis: report.json's ``diagnosis`` section
    (``quickhealth report`` writes it), else ``diagnosis.json``; None when there is none."""
    rp, dp = run_dir / "report.json", run_dir / "diagnosis.json"
    doc = load_json_limited(rp, "report") if rp.is_file() else {}
    diag = doc.get("diagnosis") if isinstance(doc, dict) else None
    if not (isinstance(diag, dict) and "verdict" in diag) and dp.is_file():
        diag = load_json_limited(dp, "diagnosis")
    return MissingEffect.of_diagnosis(diag if isinstance(diag, dict) else None)


def healthy_of(report: Mapping[str, Any]) -> bool | None:
    """Whether a report.json's run may be a baseline (the archive's ``healthy`` flag): its
    ``verdict`` section (``fit_as_baseline``, else healthy), else the TUI's ``run.healthy``
    (reports before the one verdict), else an older top-level ``healthy``; None when it
    carries no verdict."""
    section = report.get("verdict")
    if isinstance(section, dict) and section.get("verdict") in tuple(HealthVerdict):
        fit = section.get("fit_as_baseline")
        return fit if isinstance(fit, bool) else section["verdict"] == HealthVerdict.HEALTHY
    run = report.get("run")
    for v in (run.get("healthy") if isinstance(run, dict) else None, report.get("healthy")):
        if isinstance(v, bool):
            return v
    return None


def recorded_verdict(report: Mapping[str, Any]) -> tuple[HealthVerdict, str] | None:
    """The verdict and reason a report.json carries (its ``verdict`` section), or None."""
    section = report.get("verdict")
    if isinstance(section, dict) and section.get("verdict") in tuple(HealthVerdict):
        return HealthVerdict(section["verdict"]), str(section.get("reason", ""))
    return None


def _first(changes: tuple[str, ...]) -> str:
    more = sum(not c.startswith("in full: ") for c in changes[1:])
    return changes[0] + (f" (and {more} more)" if more > 0 else "")


def _day(iso: str) -> str:
    """ " of 2026-11-12" for an ISO time, "" when unknown."""
    try:
        t = datetime.fromisoformat(iso.replace("Z", "+00:00"))
    except ValueError:
        return ""
    t = t if t.tzinfo else t.replace(tzinfo=UTC)
    return f" of {t.astimezone(UTC):%Y-%m-%d}"


def _fig(f: Figures) -> tuple[float, float, float]:
    return f.mean_mm, f.std_mm, f.max_mm


def _finite(v: float, default: float) -> float:
    return float(v) if math.isfinite(v) else default
