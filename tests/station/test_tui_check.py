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
        steps: list[tuple[int, int, str]] = []
        summary = station.quick_check(lambda done, total, line: steps.append((done, total, line)))
        assert summary[0].startswith("UNCHANGED after"), summary
        assert any(line.startswith("pose:") for _, _, line in steps)
        # the progress counts the check's own poses: up by one per measured pose, to the
        # number of poses the check took
        done = [d for d, _, _ in steps]
        assert (
            done == sorted(done) and done[0] == 0 and {t for _, t, _ in steps} == {len(plan.poses)}
        )
        n_check = int(summary[0].split("after ")[1].split(" poses")[0])
        assert done[-1] == n_check and set(done) == set(range(n_check + 1))
        checks = station.archive.checks(station.robot_name)
        assert len(checks) == 1 and checks[0].verdict == "unchanged"
        assert checks[0].baseline_run_id == station.run_id
        assert [r.run_id for r in station.archive.runs(station.robot_name)] == [station.run_id]
        h = station.history()
        assert h.checks and "not assessments" in h.checks[0]
        # History lists the check beside the run, each with its own verdict
        assert [(r.kind, r.verdict) for r in h.rows] == [("run", "healthy"), ("check", "unchanged")]
    finally:
        station.shutdown()
