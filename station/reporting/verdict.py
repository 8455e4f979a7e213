"""The one health verdict: healthy, degraded or flagged, and why (docs/monitoring.md, "The report").

Every door judges a run with :func:`judge`: the HTML report and its report.json, the
technician's Results screen, ``reprocess``, ``trend`` (the latest run) and ``archive add``
(which reads the verdict a report.json carries, :func:`healthy_of`).

- **flagged**: the trend against the baseline raised a flag (a control-chart alarm, the
  threshold crossed, an error curve changed); the reason is the first flag;
- **degraded**: no flag, but the figure the threshold names is above it, or the mean or max
  TCP error is more than 10 % above the baseline run's, or the diagnosis finds a physical
  effect the model misses;
- **healthy**: none of these.

The figures are the workspace TCP error figures in mm, as report.json, the archive's index and
the trend carry them; with a trend, the run's figures are the index's (like with like).

SYNOPSIS::

    j = judge(Figures.of_report(doc), trend=res, missing=MissingEffect.of_diagnosis(diag),
              threshold=Threshold(0.5))
    j.verdict, j.reason, j.healthy
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..formats.common import load_json_limited

if TYPE_CHECKING:  # the type only: the trend loads scipy.stats, archive add would wait for it
    from ...identify.trend import TrendResult

#: A run whose mean or max TCP error is this much above the baseline's is degraded.
RISE = 0.10


class HealthVerdict(StrEnum):
    """What a run says about the robot (the value is what report.json and the screens show)."""

    HEALTHY = "healthy"
    DEGRADED = "degraded"
    FLAGGED = "flagged"


class ThresholdFigure(StrEnum):
    """Which workspace TCP error figure a threshold applies to."""

    MEAN = "mean"
    STD = "std"
    MAX = "max"


@dataclass(frozen=True)
class Threshold:
    """A limit on one workspace TCP error figure (``--threshold-mm``, ``--figure``)."""

    mm: float
    figure: ThresholdFigure = ThresholdFigure.MAX


@dataclass(frozen=True)
class Figures:
    """The workspace TCP error figures of one run, mm (report.json's ``workspace``)."""

    mean_mm: float
    std_mm: float
    max_mm: float

    def of(self, figure: ThresholdFigure) -> float:
        """The figure a threshold names."""
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
    """The verdict on one run, why, and what it was judged on.

    ``figures`` are the run's (from the archive's index when there is a trend), ``baseline``
    the baseline run's (None without a trend); ``conditions`` names the reference conditions
    of condition-dependent effects ("" when none).
    """

    verdict: HealthVerdict
    reason: str
    figures: Figures
    baseline: Figures | None = None
    baseline_run: str | None = None
    this_is_baseline: bool | None = None
    top_missing_effect: MissingEffect | None = None
    conditions: str = ""
    threshold: Threshold | None = None
    uncertainty: str = ""  # "" or how the bands were made (an estimated scatter), for the line

    @property
    def healthy(self) -> bool:
        """True for "healthy" (the archive's healthy flag)."""
        return self.verdict is HealthVerdict.HEALTHY

    def as_dict(self) -> dict[str, Any]:
        """The report's ``verdict`` section (report.json and the page's embedded JSON)."""
        data: dict[str, Any] = {
            "mean_mm": self.figures.mean_mm,
            "max_mm": self.figures.max_mm,
            "conditions": self.conditions,
            "uncertainty": self.uncertainty,
        }
        if self.baseline is not None:
            data.update(
                baseline_run=self.baseline_run,
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
        data.update(verdict=self.verdict.value, reason=self.reason)
        return data


def judge(
    figures: Figures,
    *,
    trend: TrendResult | None = None,
    missing: MissingEffect | None = None,
    threshold: Threshold | None = None,
    conditions: str = "",
    uncertainty: str = "",
) -> Judgement:
    """Healthy, degraded or flagged (see the module docstring), with the one-line reason.

    Parameters
    ----------
    figures : Figures
        The run's workspace TCP error (report.json); replaced by the trend's own figures of
        the latest run when ``trend`` is given and they are finite.
    trend : TrendResult, optional
        The robot's trend up to this run (its latest run), judged against its baseline.
    missing : MissingEffect, optional
        The diagnosis's top missing effect.
    threshold : Threshold, optional
        Without a trend, a figure above it makes the run degraded (the trend flags it).
    """
    base = None
    baseline_run = this_is_baseline = None
    if trend is not None:  # both figures from the archive's index: like with like
        b, i = trend.baseline_index, trend.latest
        now = Figures.of_trend(trend, i)
        figures = Figures(*(_finite(v, d) for v, d in zip(_fig(now), _fig(figures), strict=True)))
        base = Figures.of_trend(trend, b)
        baseline_run, this_is_baseline = trend.run_ids[b], b == i
    flags = trend.flags() if trend is not None else []
    rose = [
        f"{what} TCP error {now:.3f} mm is {now / was - 1:.0%} above the baseline's {was:.3f} mm"
        for what, now, was in (
            ("mean", figures.mean_mm, None if base is None else base.mean_mm),
            ("max", figures.max_mm, None if base is None else base.max_mm),
        )
        if was is not None and was > 0 and now > (1 + RISE) * was
    ]
    if trend is not None:
        figure = ThresholdFigure(trend.threshold_figure)
    else:
        figure = threshold.figure if threshold is not None else ThresholdFigure.MAX
    over = threshold is not None and figures.of(figure) > threshold.mm
    if flags:
        verdict = HealthVerdict.FLAGGED
        reason = flags[0] + (f" (and {len(flags) - 1} more)" if len(flags) > 1 else "")
    elif over:
        assert threshold is not None
        verdict = HealthVerdict.DEGRADED
        reason = f"TCP error {figures.of(figure):.3f} mm is above the threshold {threshold.mm:g} mm"
    elif rose:
        verdict, reason = HealthVerdict.DEGRADED, rose[0]
    elif missing is not None:
        drop = missing.predicted_rms_drop_mm
        verdict = HealthVerdict.DEGRADED
        reason = f"the error model misses a physical effect: {missing.effect}" + (
            f" (adding it would lower the residual RMS by {drop:.3f} mm)"
            if drop is not None
            else ""
        )
    else:
        verdict = HealthVerdict.HEALTHY
        reason = (
            "no flag against the baseline and no missing effect"
            if trend is not None
            else "no missing effect (no baseline to compare with: the run is not archived)"
        )
    return Judgement(
        verdict,
        reason,
        figures,
        base,
        baseline_run,
        this_is_baseline,
        missing,
        conditions,
        threshold,
        uncertainty,
    )


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
    """Whether a report.json judged its run healthy: its ``verdict`` section, else the TUI's
    ``run.healthy`` (reports before the one verdict), else an older top-level ``healthy``;
    None when it carries no verdict."""
    section = report.get("verdict")
    if isinstance(section, dict) and section.get("verdict") in tuple(HealthVerdict):
        return section["verdict"] == HealthVerdict.HEALTHY
    run = report.get("run")
    for v in (run.get("healthy") if isinstance(run, dict) else None, report.get("healthy")):
        if isinstance(v, bool):
            return v
    return None


def _fig(f: Figures) -> tuple[float, float, float]:
    return f.mean_mm, f.std_mm, f.max_mm


def _finite(v: float, default: float) -> float:
    return float(v) if math.isfinite(v) else default
