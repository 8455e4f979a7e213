"""Every effect through every door, through the command line (not the library).

For each registered effect type with an example (``register(..., example=...)``: every effect a
twin can hide by one size), one case, and one case with two effects at once and one with three:
``quickhealth twin`` hides the effects, ``identify fit`` fits the paper's model,
``diagnose`` names what is missing, ``identify fit --effects <its suggested list>`` fits again
and ``identify predict`` on held-out poses must come within 1.3x the noise floor.  On the same
data the other doors: ``compare`` (the held-out error falls) and reprocessing of the fitted run
folder (the same report.json) for every case, the TUI's "add effect" (the held-out error
falls) for the two- and three-effect cases.  Then the TUI's "add effect" and results
(report.json) for the condition-dependent effects, thermal and drift.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import pytest

from quickhealth.identify.effects import effect_types
from quickhealth.station.cli import main
from quickhealth.station.formats import check_report

FLOOR_MM = math.sqrt(3) * 0.03  # 3D RMS of the twin's 0.03 mm per-axis instrument noise

# every registered effect type's own example (sizes at the command line's units, twin --help),
# then two and three effects at once
CASES = {
    t.example.partition("=")[0].replace(":", "_"): (t.example, {t.example.partition("=")[0]})
    for t in effect_types()
    if t.example
} | {
    "two": ("backlash:j3=0.0229,thermal=5e-5", {"backlash:j3", "thermal"}),
    "three": (
        "compliance:j2=0.00143,cyclic:j1:h9=0.01146,depthscale=4e-4",
        {"compliance:j2", "cyclic:j1:h9", "depthscale"},
    ),
}

TUI_CASES = ("two", "three")  # with the thermal-and-drift TUI test below: all six families


def _qh(*argv: str) -> None:
    assert main([str(a) for a in argv]) == 0, argv


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_twin_diagnose_fit_predict_through_the_cli(case: str, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    hidden, truth = CASES[case]
    meas = tmp_path / "meas.csv"
    _qh("twin", "--effects", hidden, "--n", 150, "--heldout", 200, "--seed", 4, "--out", meas)
    _qh("identify", "fit", meas, "--robot", "ur5", "--out", tmp_path / "fit0", "--quiet")
    _qh("diagnose", tmp_path / "fit0/model.json", meas, "--json", tmp_path / "diag.json")
    diag = json.loads((tmp_path / "diag.json").read_text())
    assert diag["verdict"] == "missing-effect", diag["candidates"][:3]
    assert set(diag["suggested"]) == truth
    fit1 = tmp_path / "fit1"
    effects = ",".join(diag["suggested"])
    _qh("identify", "fit", meas, "--robot", "ur5", "--out", fit1, "--effects", effects, "--quiet")
    rep = json.loads((fit1 / "report.json").read_text())
    check_report(rep)
    assert set(rep["effects"]) == truth
    if "thermal" in truth:  # the workspace map states its reference conditions
        assert rep["workspace"]["conditions"]["temp_c"] == 20.0
    if "drift" in truth:
        assert rep["workspace"]["conditions"]["time_s"] > 0
    capsys.readouterr()
    pred = tmp_path / "pred.csv"
    _qh("identify", "predict", fit1 / "model.json", tmp_path / "meas.heldout.csv", "--out", pred)
    out = capsys.readouterr().out
    assert "assumed" not in out and "reference conditions" not in out  # the file has time/temp
    rows = list(csv.DictReader(pred.open()))
    assert len(rows) == 200
    rms = math.sqrt(sum(float(r["meas_minus_model_mm"]) ** 2 for r in rows) / len(rows))
    print(f"{case}: held-out RMS {rms:.4f} mm = {rms / FLOOR_MM:.3f} x floor")
    assert rms <= 1.3 * FLOOR_MM, (case, rms)
    _other_doors(case, effects, truth, meas, tmp_path)


def _other_doors(case: str, effects: str, truth: set[str], meas: Path, tmp_path: Path) -> None:
    """compare, reprocess and the TUI's "add effect" with the same effects on the same data."""
    from quickhealth.station.reprocess import ReprocessJob, reprocess_run
    from quickhealth.station.tui.facade import Facade

    heldout = tmp_path / "meas.heldout.csv"
    # compare: the model without and with the effects, judged on the held-out poses
    cmp = tmp_path / "cmp.json"
    _qh(
        "compare", tmp_path / "fit0/model.json", meas, "--effects", effects,
        "--heldout", heldout, "--json", cmp,
    )  # fmt: skip
    doc = json.loads(cmp.read_text())
    assert doc["after"]["pos_mm"] < 0.8 * doc["before"]["pos_mm"], (case, doc["after"])
    # reprocess the fitted run folder (orders selected anew, as identify fit did): same report
    run = tmp_path / "fit1"
    shutil.copy(meas, run / "measurements.csv")
    res = reprocess_run(ReprocessJob("ur5", case, str(run), str(tmp_path / "re"), orders="select"))
    assert res.ok, res.error
    cli, rep = (json.loads((d / "report.json").read_text()) for d in (run, tmp_path / "re"))
    check_report(rep)
    assert rep["effects"] == cli["effects"] and rep["orders"] == cli["orders"]
    for key in ("rms_pos_mm", "bic", "chi2"):
        assert math.isclose(rep[key], cli[key], rel_tol=1e-9), (case, key)
    assert math.isclose(rep["workspace"]["max_mm"], cli["workspace"]["max_mm"], rel_tol=1e-9)
    # the TUI: add each effect to the model it fitted itself (the two- and three-effect cases
    # and test_tui_adds_thermal_and_drift_and_writes_the_report: every family, ~1 s per effect)
    if case not in TUI_CASES:
        return
    station = Facade.from_data(meas, heldout, archive_root=tmp_path / "arch", run_id=case)
    for effect in sorted(truth):
        refit = station.add_effect(effect)
        assert effect in refit.effects_after and refit.after_mm < refit.before_mm, (case, refit)
    assert set(station.analysis.effects) == truth


def test_predict_names_the_conditions_it_assumed(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    meas = tmp_path / "meas.csv"
    _qh("twin", "--effects", "thermal=5e-5,drift=2e-4", "--n", 90, "--seed", 5, "--out", meas)
    _qh("identify", "fit", meas, "--robot", "ur5", "--out", tmp_path / "fit")
    _qh("identify", "fit", meas, "--robot", "ur5", "--out", tmp_path / "fit", "--quiet")
    _qh(
        "identify", "fit", meas, "--robot", "ur5", "--out", tmp_path / "fit",
        "--effects", "thermal,drift", "--max-order", 2, "--quiet",
    )  # fmt: skip
    summary = capsys.readouterr().out
    assert "workspace TCP error (model, at 20.0 °C, time" in summary
    rows = [r for r in meas.read_text().splitlines() if not r.startswith("#")]
    head = rows[0].split(",")
    keep = [i for i, c in enumerate(head) if c.startswith("q") or c == "pose_id"]
    joints = tmp_path / "joints.csv"
    joints.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in rows) + "\n")
    _qh("identify", "predict", tmp_path / "fit/model.json", joints, "--out", tmp_path / "p.csv")
    out = capsys.readouterr().out
    assert "no column for temp, time" in out and "20.0 °C" in out and "last pose" in out


@pytest.mark.slow
def test_tui_adds_thermal_and_drift_and_writes_the_report(tmp_path: Path) -> None:
    from quickhealth.station.tui.facade import Facade

    meas = tmp_path / "run" / "measurements.csv"
    _qh("twin", "--effects", "thermal=5e-5,drift=2e-4", "--n", 80, "--seed", 6, "--out", meas)
    station = Facade.from_data(meas, archive_root=tmp_path / "archive", run_id="t1")
    for effect in ("thermal", "drift"):
        refit = station.add_effect(effect)
        assert effect in refit.effects_after
    h = station.results()
    assert set(h.effects) == {"thermal", "drift"}
    doc = json.loads((station.run_dir / "report.json").read_text())
    check_report(doc)
    assert doc["workspace"]["conditions"]["temp_c"] == 20.0
    assert doc["workspace"]["conditions"]["time_s"] > 0
