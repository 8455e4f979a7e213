"""``quickhealth check --replay``: a recorded run serves as the robot (backtesting)."""

from __future__ import annotations

import json

import pytest
import qh_runs as _runs

from quickhealth.station.cli import main
from quickhealth.station.run.lock import ENV_VAR, RunLock


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A fitted baseline run of the twin, a healthy repeat and one whose joint 3 reading
    lost 0.3 mrad of its zero (the fault raised into the truth)."""
    base = tmp_path_factory.mktemp("replay")
    return (
        _runs.make_run(base / "base", 0, n_poses=40),
        _runs.make_run(base / "same", 1, n_poses=40),
        _runs.make_run(base / "zero", 2, n_poses=40, degrade={"j3.ez.c0": 3e-4}),
    )


def _replay(rec, base, out, capsys):
    code = main(["check", "--replay", str(rec), "--baseline", str(base), "--out", str(out)])
    return code, capsys.readouterr().out, json.loads((out / "check.json").read_text())


def test_replay_of_a_changed_run_names_the_fault(runs, tmp_path, capsys):
    base, _, zero = runs
    code, out, doc = _replay(zero, base, tmp_path / "c", capsys)
    assert code == 1 and out.startswith("CHANGED after")
    top = doc["changes"][0]
    assert top["fault"] == "j3.zero" and top["size_unit"] == "mrad"
    assert abs(top["size"] - 0.3) < 2 * top["sigma"], top
    assert doc["replay"]["paired"] and doc["baseline"]["paired"]  # same plan: pose by pose
    assert doc["poses"] == len(doc["replay"]["rows_used"]) < 40
    assert 0 < doc["robot_time_s"] < doc["full_loop_robot_time_s"]


def test_replay_of_a_healthy_run_is_unchanged_with_the_same_document(
    runs, tmp_path, capsys, monkeypatch
):
    """... while a station's run holds the cell: a replay drives no hardware."""
    base, same, _ = runs
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "lock"))
    (tmp_path / "lock").mkdir(mode=0o700)
    cell = RunLock.acquire(tmp_path / "a-station-run")
    try:
        code, out, doc = _replay(same, base, tmp_path / "h", capsys)
    finally:
        cell.release()
    assert code == 0 and out.startswith("UNCHANGED after") and doc["changes"] == []
    keys = {"schema", "verdict", "decided", "poses", "robot_time_s", "full_loop_robot_time_s",
            "changes", "false_alarm", "power", "detect_mm", "test", "baseline", "pose_names"}  # fmt: skip
    assert keys <= set(doc)


def test_replay_refuses_what_is_no_run(runs, tmp_path, capsys):
    base = runs[0]
    (tmp_path / "empty").mkdir()
    code = main(["check", "--replay", str(tmp_path / "empty"), "--baseline", str(base),
                 "--out", str(tmp_path / "o")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "not a recorded run" in err and len(err.strip().splitlines()) == 1
    code = main(["check", "--baseline", str(base), "--out", str(tmp_path / "o2")])
    err = capsys.readouterr().err
    assert code == 2 and "--replay" in err
