"""One answer from every door: the command line (fit, archive add, report, trend), the TUI's
Results and History screens and reprocessing judge a run alike, in the same words, and write
the same report.json."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from qh_tui import settle, text

from quickhealth.identify.errors import InputError
from quickhealth.identify.twin import make_twin, random_joints, schedules
from quickhealth.station.archive import Archive
from quickhealth.station.cli import main
from quickhealth.station.formats import REPORT_SCHEMA as SCHEMA
from quickhealth.station.formats import check_report, write_measurements
from quickhealth.station.reporting.verdict import HealthVerdict, Spec
from quickhealth.station.reprocess import jobs_for_archive, reprocess
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.facade import Facade

MAX_ORDER = 2
ROBOT, RUN = "ur5-a", "r1"
# where the file came from, and which program wrote it: each door reads its own copy of the
# same measurements (compared below by content), and provenance names the versions.  Numbers
# agree to 1e-9 (the fits to 1e-12; the diagnosis scores, -log10 of tiny p-values, amplify)
PROVENANCE = ("input", "provenance")


def _compare(a: Any, b: Any, where: str = "") -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{where}: keys {set(a) ^ set(b)}"
        for k in a:
            _compare(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{where}: lengths"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _compare(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and not isinstance(a, bool):
        assert isinstance(b, int | float), where
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), f"{where}: {a!r} vs {b!r}"
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


def _core(doc: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in doc.items() if k not in PROVENANCE}


def _same_data(a: dict[str, Any], b: dict[str, Any]) -> None:
    pa, pb = Path(a["input"]), Path(b["input"])
    assert pa.read_bytes() == pb.read_bytes(), (pa, pb)


@pytest.mark.slow
async def test_every_door_gives_one_verdict_and_one_report(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    # thermal: the workspace map and the report name their reference conditions; a hidden
    # backlash makes the diagnosis (and so the verdict) say something
    twin = make_twin(seed=21, effects={"thermal": 3e-5, "backlash:j2": 4e-4})
    q = random_joints(twin.robot, 40, seed=22, T_instr_base=twin.truth.T_instr_base)
    time, temp = schedules(len(q))
    run = tmp_path / "run"
    run.mkdir()
    meas_csv = run / "measurements.csv"
    meta = {"run_id": RUN, "started_utc": "2026-11-01T02:00:00Z"}
    write_measurements(meas_csv, twin.measure(q, time, temp, seed=23, meta=meta))

    # 1. the command line: fit the run folder, archive it (as the robot's baseline: a degraded
    # run is never the first healthy one), report it against the archive
    a1 = tmp_path / "archive-cli"
    for argv in (
        ["identify", "fit", str(meas_csv), "--robot", "ur5", "--out", str(run)]
        + ["--effects", "thermal", "--max-order", str(MAX_ORDER), "--quiet"],
        ["archive", "add", str(run), "--robot", ROBOT, "--run-id", RUN, "--archive", str(a1)]
        + ["--baseline"],
    ):
        assert main(argv) == 0, capsys.readouterr().err
    archived = Archive.open(a1).run_path(ROBOT, RUN)
    capsys.readouterr()
    rc = main(
        ["report", str(archived), "--archive", str(a1), "--robot", ROBOT, "--threshold-mm", "2"]
    )
    assert rc == 0, capsys.readouterr().err
    printed = capsys.readouterr().out.splitlines()[0]
    cli = json.loads((archived / "report.json").read_text())

    # 2. the TUI's analysis (Results screen) on the same file, in its own archive
    station = Facade.from_data(
        meas_csv, archive_root=tmp_path / "archive-tui", robot_name=ROBOT, max_order=MAX_ORDER,
        threshold_mm=2.0,
    )  # fmt: skip
    station.analysis.effects = ("thermal",)
    app = QuickhealthApp(station)
    async with app.run_test(size=(120, 40)) as pilot:
        await pilot.press("4")
        await settle(app, pilot)
        h = app.screen.health
        assert h is not None
        shown = text(app, "#summary")
        await pilot.press("6")  # History: the run's verdict as its report gave it
        await settle(app, pilot)
        hist = app.screen.history
        history_head = text(app, "#trend")
    tui = json.loads((station.run_dir / "report.json").read_text())
    # the trend command on either archive: its first lines are the latest run's verdict
    trend_lines = []
    for arch_dir in (a1, station.archive.root):
        capsys.readouterr()
        assert main(["trend", ROBOT, "--archive", str(arch_dir), "--threshold-mm", "2"]) == 0
        trend_lines.append(capsys.readouterr().out.splitlines()[1:])

    # 3. fleet reprocessing of the archived run, orders selected anew, judged as reported
    jobs = jobs_for_archive(
        Archive.open(a1), ROBOT, tag="again", orders="select", max_order=MAX_ORDER,
        report=True, spec=Spec(2.0, source="--threshold-mm"),
    )  # fmt: skip
    (res,) = reprocess(jobs, workers=1)
    assert res.ok, res.error
    rep = json.loads((Path(res.out_dir) / "report.json").read_text())

    # one verdict: the report's, everywhere (a missing effect: degraded, not healthy)
    verdict = cli["verdict"]["verdict"]
    assert verdict == HealthVerdict.DEGRADED and "backlash:j2" in cli["verdict"]["reason"]
    assert printed == f"DEGRADED: {cli['verdict']['reason']}"
    assert h.verdict == res.verdict == tui["verdict"]["verdict"] == rep["verdict"]["verdict"]
    assert h.verdict == verdict and h.reason == cli["verdict"]["reason"] == res.reason
    assert "DEGRADED" in shown and "backlash:j2" in shown  # the TUI shows the report's verdict
    # the same words at every door: report (printed and report.json), TUI Results, TUI
    # History, the trend command on the CLI's archive and on the TUI's
    lines = cli["verdict"]["lines"]
    assert h.verdict_lines == tuple(lines) == tuple(tui["verdict"]["lines"])
    assert hist is not None and hist.latest == tuple(lines)
    assert f"latest run: DEGRADED: {cli['verdict']['reason']}" in " ".join(history_head.split())
    assert [r.verdict for r in hist.rows] == ["degraded"]
    for tl in trend_lines:
        assert tl[: len(lines)] == lines, (tl, lines)
    assert cli["run"] == {
        "run_id": RUN, "robot_name": ROBOT, "verdict": verdict, "healthy": False,
        "threshold_mm": 2.0, "threshold_figure": "max",
    }  # fmt: skip
    for arch in (Archive.open(a1), station.archive):  # the index: still the baseline (a model
        # missing an effect is a fair reference for change; a verdict never unseats a baseline)
        assert arch.get(ROBOT, RUN).healthy is True and arch.baseline(ROBOT).run_id == RUN

    # one report.json: every key and figure alike, provenance aside
    for doc in (cli, tui, rep):
        check_report(doc)
        assert doc["schema"] == SCHEMA and doc["effects"] == ["thermal"]
        assert doc["workspace"]["conditions"]["temp_c"] == 20.0
        assert set(doc) >= {"coverage", "diagnosis", "trend", "iso9283", "verdict", "run"}
    assert h.max_mm == pytest.approx(cli["workspace"]["max_mm"], rel=1e-9)
    _same_data(cli, tui)
    _same_data(cli, rep)
    _compare(_core(cli), _core(tui), "cli~tui")
    _compare(_core(cli), _core(rep), "cli~reprocess")


def test_check_report_names_what_is_wrong() -> None:
    with pytest.raises(InputError, match="schema"):
        check_report({"schema": "quickhealth.report/1"})
    with pytest.raises(InputError, match="missing key 'n_poses'"):
        check_report({"schema": SCHEMA})


def test_one_checker_serves_the_archive_and_the_schema() -> None:
    # report_json re-exports the formats package's checker and schema: one of each
    from quickhealth.station import formats

    assert check_report is formats.check_report and SCHEMA == formats.REPORT_SCHEMA
    v1 = {
        "schema": "quickhealth.report/1",
        "n_poses": 150,
        "rms_pos_mm": 0.05,
        "chi2": 420.0,
        "bic": 1234.5,
        "workspace": {"mean_mm": 0.3, "std_mm": 0.1, "max_mm": 0.8},
    }
    check_report(v1, "old.json", complete=False)  # the archive still takes version 1
    with pytest.raises(InputError, match="old.json: schema is 'quickhealth.report/1'"):
        check_report(v1, "old.json")
    with pytest.raises(InputError, match=r"old.json: bic is nan: not a complete fit report"):
        check_report({**v1, "bic": float("nan")}, "old.json", complete=False)
