"""The TUI's quick check (Run screen ``k``) through its facade on the in-process simulated
cell: a baseline run, its results archived, then the check against it, recorded as a check."""

from __future__ import annotations

from pathlib import Path

import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.planning import load_cell
from quickhealth.station.tui.facade import make_plan
from quickhealth.station.tui.simulated import in_process


@pytest.mark.slow
def test_quick_check_against_the_archived_baseline(tmp_path: Path) -> None:
    plan = make_plan(load_cell("reference"), 14, 3)
    station = in_process(tmp_path / "archive", plan=plan, max_order=1, threshold_mm=5.0)
    try:
        with pytest.raises(InputError, match="no baseline run"):
            station.quick_check()
        final = station.run(lambda p: None)
        assert final.done == len(plan.poses)
        station.results()  # fitted and archived: the robot's first run is its baseline
        lines: list[str] = []
        summary = station.quick_check(lines.append)
        assert summary[0].startswith("UNCHANGED after"), summary
        assert any(line.startswith("pose:") for line in lines)
        checks = station.archive.checks(station.robot_name)
        assert len(checks) == 1 and checks[0].verdict == "unchanged"
        assert checks[0].baseline_run_id == station.run_id
        assert [r.run_id for r in station.archive.runs(station.robot_name)] == [station.run_id]
        h = station.history()
        assert h.checks and "not assessments" in h.checks[0]
    finally:
        station.shutdown()
