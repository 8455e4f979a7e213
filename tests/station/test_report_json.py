"""One report: the command line, the TUI and reprocessing write the same report.json."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.twin import make_twin, random_joints, schedules
from quickhealth.station.cli import main
from quickhealth.station.formats import write_measurements
from quickhealth.station.report_json import SCHEMA, check_report
from quickhealth.station.reprocess import ReprocessJob, reprocess_run
from quickhealth.station.tui.facade import Station

MAX_ORDER = 2
PRODUCER_KEYS = ("input", "run")  # who wrote it, not what was assessed


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
        assert math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12), f"{where}: {a!r} vs {b!r}"
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


def _core(doc: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in doc.items() if k not in PRODUCER_KEYS}


@pytest.mark.slow
def test_cli_tui_and_reprocess_write_one_report(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    # thermal: the workspace map and the report name their reference conditions
    twin = make_twin(seed=21, effects={"thermal": 3e-5})
    q = random_joints(twin.robot, 70, seed=22, T_instr_base=twin.truth.T_instr_base)
    time, temp = schedules(len(q))
    run = tmp_path / "run"
    run.mkdir()
    meas_csv = run / "measurements.csv"
    write_measurements(meas_csv, twin.measure(q, time, temp, seed=23, meta={"run_id": "r1"}))

    # 1. the command line
    cli_out = tmp_path / "cli"
    rc = main(
        ["identify", "fit", str(meas_csv), "--robot", "ur5", "--out", str(cli_out)]
        + ["--effects", "thermal", "--max-order", str(MAX_ORDER), "--quiet"]
    )
    assert rc == 0, capsys.readouterr().err
    cli = json.loads((cli_out / "report.json").read_text())

    # 2. the TUI's analysis (Results screen): writes report.json into its run folder
    station = Station.from_data(
        meas_csv, archive_root=tmp_path / "archive", run_id="r1", max_order=MAX_ORDER
    )
    station.analysis.effects = ("thermal",)
    station.results()
    tui = json.loads((station.run_dir / "report.json").read_text())

    # 3. fleet reprocessing of the CLI's run folder, orders selected anew
    src = tmp_path / "archived"
    shutil.copytree(cli_out, src)
    shutil.copy(meas_csv, src / "measurements.csv")
    res = reprocess_run(
        ReprocessJob("ur5", "r1", str(src), str(tmp_path / "re"), orders="select", max_order=2)
    )
    assert res.ok, res.error
    rep = json.loads((tmp_path / "re" / "report.json").read_text())

    for doc in (cli, tui, rep):
        check_report(doc)
        assert doc["schema"] == SCHEMA
        assert doc["effects"] == ["thermal"]
        assert doc["workspace"]["conditions"]["temp_c"] == 20.0
        assert "20.0 °C" in " ".join(doc["summary"])
    assert tui["run"]["run_id"] == "r1" and tui["run"]["verdict"] in ("healthy", "degraded")
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
