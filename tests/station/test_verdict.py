"""The one verdict (station/reporting/verdict.py): each of its rules, in the documented order, and the
verdict a report.json carries back to the archive."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from quickhealth.station.reporting.verdict import (
    Figures,
    HealthVerdict,
    MissingEffect,
    Threshold,
    ThresholdFigure,
    healthy_of,
    judge,
)

NOW = Figures(0.50, 0.20, 1.00)


def trend(now: Figures, base: Figures, flags: tuple[str, ...] = (), figure: str = "max"):  # type: ignore[no-untyped-def]
    """A two-run trend (baseline, this run) as identify.trend.TrendResult shows it."""
    f = {k: (getattr(base, f"{k}_mm"), getattr(now, f"{k}_mm")) for k in ("mean", "std", "max")}
    return SimpleNamespace(
        baseline_index=0,
        latest=1,
        run_ids=("r0", "r1"),
        figures_mm=f,
        threshold_figure=figure,
        flags=lambda index=None: list(flags),
    )


def test_healthy_without_a_trend_says_there_is_no_baseline() -> None:
    j = judge(NOW)
    assert j.verdict is HealthVerdict.HEALTHY and j.healthy
    assert "no baseline" in j.reason and j.baseline is None


def test_a_flag_wins_over_everything_else() -> None:
    t = trend(NOW, Figures(0.1, 0.1, 0.1), ("joint 2 tilt about x grew", "mean EWMA above"))
    j = judge(NOW, trend=t, missing=MissingEffect("backlash:j2", 0.01), threshold=Threshold(0.5))
    assert j.verdict is HealthVerdict.FLAGGED
    assert j.reason == "joint 2 tilt about x grew (and 1 more)"
    assert j.as_dict()["baseline_run"] == "r0" and j.as_dict()["this_is_baseline"] is False


def test_the_threshold_figure_above_its_limit_is_degraded() -> None:
    j = judge(NOW, threshold=Threshold(0.4, ThresholdFigure.MEAN))
    assert j.verdict is HealthVerdict.DEGRADED and "0.500 mm is above the threshold 0.4" in j.reason
    assert judge(NOW, threshold=Threshold(0.6, ThresholdFigure.MEAN)).healthy
    assert judge(NOW, threshold=Threshold(0.15, ThresholdFigure.STD)).verdict == "degraded"


def test_more_than_ten_percent_above_the_baseline_is_degraded() -> None:
    j = judge(NOW, trend=trend(NOW, Figures(0.44, 0.2, 1.0)))
    assert j.verdict is HealthVerdict.DEGRADED
    assert j.reason.startswith("mean TCP error 0.500 mm is 14% above the baseline's 0.440 mm")
    assert judge(NOW, trend=trend(NOW, Figures(0.46, 0.2, 0.95))).healthy  # 9 %, 5 %


def test_a_missing_effect_is_degraded_and_named() -> None:
    doc = {
        "verdict": "missing-effect",
        "suggested": ["backlash:j2"],
        "candidates": [{"effect": "backlash:j2", "predicted_rms_drop_mm": 0.052}],
    }
    j = judge(NOW, missing=MissingEffect.of_diagnosis(doc))
    assert j.verdict is HealthVerdict.DEGRADED
    assert j.reason == (
        "the error model misses a physical effect: backlash:j2 (adding it would lower the "
        "residual RMS by 0.052 mm)"
    )
    assert MissingEffect.of_diagnosis({"verdict": "adequate", "candidates": []}) is None


@pytest.mark.parametrize(
    ("doc", "healthy"),
    [
        ({"verdict": {"verdict": "flagged"}, "run": {"healthy": True}}, False),
        ({"verdict": {"verdict": "healthy"}}, True),
        ({"run": {"healthy": False}}, False),  # the TUI's reports before the one verdict
        ({"healthy": True}, True),  # version 1 reports
        ({"verdict": {"missing": "no trend"}}, None),
        ({}, None),
    ],
)
def test_archive_add_reads_the_verdict_a_report_carries(doc: dict, healthy: bool | None) -> None:
    assert healthy_of(doc) is healthy
