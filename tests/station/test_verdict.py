"""The one verdict (station/reporting/verdict.py): each of its rules, in the documented order,
the words every door prints, and the verdict a report.json carries back to the archive."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from quickhealth.station.reporting.verdict import (
    Figures,
    HealthVerdict,
    MissingEffect,
    Spec,
    ThresholdFigure,
    healthy_of,
    judge,
    spec_of_meta,
)

NOW = Figures(0.50, 0.20, 1.00)


def trend(now: Figures, base: Figures, changes: tuple[str, ...] = (), baseline_is_latest=False):  # type: ignore[no-untyped-def]
    """A two-run trend (baseline, this run) as identify.trend.TrendResult shows it."""
    f = {k: (getattr(base, f"{k}_mm"), getattr(now, f"{k}_mm")) for k in ("mean", "std", "max")}
    if baseline_is_latest:
        f = {k: (v[1],) for k, v in f.items()}
    return SimpleNamespace(
        baseline_index=0,
        latest=0 if baseline_is_latest else 1,
        run_ids=("r1",) if baseline_is_latest else ("r0", "r1"),
        figures_mm=f,
        change_flags=lambda index=None: [] if baseline_is_latest or index == 0 else list(changes),
    )


def test_without_a_trend_the_words_say_there_is_no_baseline_and_no_spec() -> None:
    j = judge(NOW)
    assert j.verdict is HealthVerdict.HEALTHY and j.healthy
    assert "no baseline" in j.reason and j.baseline is None
    lines = j.lines()
    assert lines[0] == j.headline() and lines[0].startswith("HEALTHY: no spec set")
    assert (
        "no accuracy spec set (spec_mm in the cell or robot file): judged against the " in lines[1]
    )
    assert lines[2] == "no baseline to compare with: the run is not archived"
    assert lines[-1].startswith("what to do: archive the run")


def test_above_the_spec_is_flagged_even_for_the_baseline_itself() -> None:
    spec = Spec(0.9, ThresholdFigure.MAX, "cell reference")
    j = judge(NOW, trend=trend(NOW, NOW, baseline_is_latest=True), spec=spec)
    assert j.verdict is HealthVerdict.FLAGGED and j.out_of_spec and j.this_is_baseline
    assert j.reason == (
        "the max TCP error is 1.000 mm, above the spec of 0.9 mm (max TCP error, cell reference)"
    )
    assert j.changes == () and j.fit_as_baseline  # out of spec, not changed: still a reference
    assert "this run is the baseline" in j.baseline_line()


def test_a_baseline_is_never_flagged_against_itself() -> None:
    t = trend(NOW, NOW, changes=("joint 2 tilt about x grew",), baseline_is_latest=True)
    j = judge(NOW, trend=t, spec=Spec(2.0))
    assert j.verdict is HealthVerdict.HEALTHY
    assert j.reason == "within the spec; this run is the robot's baseline"


def test_a_change_since_the_baseline_is_flagged_within_the_spec() -> None:
    t = trend(NOW, Figures(0.49, 0.2, 0.99), ("joint 2 tilt about x grew", "mean EWMA above"))
    j = judge(NOW, trend=t, missing=MissingEffect("backlash:j2", 0.01), spec=Spec(2.0))
    assert j.verdict is HealthVerdict.FLAGGED and not j.out_of_spec
    assert (
        j.reason == "the robot changed since its baseline: joint 2 tilt about x grew (and 1 more)"
    )
    assert j.as_dict()["baseline_run"] == "r0" and j.as_dict()["this_is_baseline"] is False
    assert not j.fit_as_baseline  # a changed run is no reference (unless it is the baseline)
    assert j.lines()[2].startswith("changed since the baseline run r0")
    assert "  - mean EWMA above" in j.lines()


def test_the_spec_figure_is_the_one_it_names() -> None:
    j = judge(NOW, spec=Spec(0.4, ThresholdFigure.MEAN))
    assert j.verdict is HealthVerdict.FLAGGED and "mean TCP error is 0.500 mm, above" in j.reason
    assert judge(NOW, spec=Spec(0.6, ThresholdFigure.MEAN)).healthy
    assert judge(NOW, spec=Spec(0.15, ThresholdFigure.STD)).verdict == "flagged"


def test_more_than_ten_percent_above_the_baseline_is_degraded() -> None:
    j = judge(NOW, trend=trend(NOW, Figures(0.44, 0.2, 1.0)))
    assert j.verdict is HealthVerdict.DEGRADED and not j.fit_as_baseline
    assert j.reason.startswith("the mean TCP error is 0.500 mm, 14% above the baseline's 0.440 mm")
    assert judge(NOW, trend=trend(NOW, Figures(0.46, 0.2, 0.95))).healthy  # 9 %, 5 %
    assert judge(NOW, trend=trend(NOW, Figures(0.46, 0.2, 0.95))).reason == (
        "no spec set and unchanged since the baseline run r0"
    )


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
    assert "--effects backlash:j2" in j.action
    assert j.fit_as_baseline  # a model missing an effect is still a reference for change
    assert MissingEffect.of_diagnosis({"verdict": "adequate", "candidates": []}) is None


def test_the_spec_a_run_recorded_from_its_cell() -> None:
    assert spec_of_meta({"spec_mm": "2", "cell": "reference"}) == Spec(
        2.0, ThresholdFigure.MAX, "cell reference"
    )
    assert spec_of_meta({"spec_mm": "-1"}) is None and spec_of_meta({}) is None
    assert Spec.of_dict(Spec(1.5, ThresholdFigure.MEAN, "x").as_dict()) == Spec(
        1.5, ThresholdFigure.MEAN, "x"
    )
    assert Spec.of_dict({"mm": float("nan")}) is None


@pytest.mark.parametrize(
    ("doc", "healthy"),
    [
        ({"verdict": {"verdict": "flagged"}, "run": {"healthy": True}}, False),
        ({"verdict": {"verdict": "degraded", "fit_as_baseline": True}}, True),
        ({"verdict": {"verdict": "flagged", "fit_as_baseline": True}}, True),  # out of spec
        ({"verdict": {"verdict": "healthy"}}, True),
        ({"run": {"healthy": False}}, False),  # the TUI's reports before the one verdict
        ({"healthy": True}, True),  # version 1 reports
        ({"verdict": {"missing": "no trend"}}, None),
        ({}, None),
    ],
)
def test_archive_add_reads_the_verdict_a_report_carries(doc: dict, healthy: bool | None) -> None:
    assert healthy_of(doc) is healthy
