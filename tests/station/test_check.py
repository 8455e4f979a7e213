"""``quickhealth check`` on the simulated cell with the real ur-rtde client: a baseline run of
a short plan, then a healthy robot ("unchanged", after a kill -9 and --resume) and a robot
whose link 2 twisted 0.1 mrad (``j2.ex.c0``: joint 3's axis tilts, "changed", that fault
named), each in a fraction of the loop's
robot time; the archive records the check as a check.

Images are 1/4 of the reference sensor and the arm moves 20× faster than life (robot time is
reported at real speed all the same).  The acceptance figures on the full reference plan are
docs/monitoring.md's.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import qh_station_plan as _station_plan

from quickhealth.station.cli import main
from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal

pytestmark = [pytest.mark.slow]

SIM = ["--sim", "--sim-image-scale", "0.25", "--sim-speed-factor", "20"]


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """A fitted baseline run of a 12-pose plan of the reference cell."""
    d = tmp_path_factory.mktemp("check")
    os.environ["QUICKHEALTH_LOCK_DIR"] = str(d / "lock")
    plan = _station_plan.plan_file(tmp_path_factory.getbasetemp(), 12)
    base = d / "base"
    assert main(["run", "--cell", "reference", "--plan", str(plan), "--out", str(base), *SIM]) == 0
    assert main(["identify", "fit", str(base / "measurements.csv"), "--robot", "ur5",
                 "--out", str(base), "--max-order", "1"]) == 0  # fmt: skip
    return plan, base


def _check(plan, base, out, *extra):
    return ["check", "--cell", "reference", "--plan", str(plan), "--baseline", str(base),
            "--out", str(out), *SIM, *extra]  # fmt: skip


@pytest.mark.timeout(120)
def test_tilted_joint_2_is_changed_and_named(baseline, tmp_path, capsys):
    """From the archive's baseline (check --robot), recorded there as a check."""
    plan, base = baseline
    arch = tmp_path / "arch"
    assert main(["archive", "add", str(base), "--robot", "ur5-sim", "--archive", str(arch)]) == 0
    out = tmp_path / "worn"
    code = main(["check", "--cell", "reference", "--plan", str(plan), "--robot", "ur5-sim",
                 "--archive", str(arch), "--out", str(out), *SIM,
                 "--sim-degrade", "j2.ex.c0=0.0001"])  # fmt: skip
    text = capsys.readouterr()
    assert code == 1, text.err
    assert "CHANGED after" in text.out and "joint 3 tilt about x" in text.out
    assert "recorded as check worn of robot ur5-sim" in text.out
    doc = json.loads((out / "check.json").read_text())
    assert doc["verdict"] == "changed" and doc["decided"]
    top = doc["changes"][0]
    assert (top["fault"], top["joint"], top["size_unit"]) == ("j3.tilt_x", 3, "mrad")
    assert 0.05 < top["size"] < 0.2 and top["sigma"] > 0
    assert doc["false_alarm"] == 0.01 and doc["detect_mm"] == 0.05 and doc["power"] == 0.95
    assert 0 < doc["robot_time_s"] < doc["full_loop_robot_time_s"]
    assert doc["poses"] == len(doc["pose_names"]) < 12
    # measurements.csv and the journal as a run's, in the order the check visited the poses
    rows = [ln.split(",")[0] for ln in (out / "measurements.csv").read_text().splitlines()
            if ln.startswith("P")]  # fmt: skip
    assert rows == doc["pose_names"]
    st = read_journal(out / JOURNAL)
    assert st.ended and st.start["kind"] == "check" and st.start["false_alarm"] == 0.01
    assert all(c.timing is not None and c.timing["move"] > 0 for c in st.captured.values())
    # the archive lists it as a check, never as a run
    assert (
        main(["trend", "ur5-sim", "--archive", str(arch), "--json", str(tmp_path / "t.json")]) == 0
    )
    text = capsys.readouterr().out
    assert "quick checks (1; not assessments)" in text and "runs (1; baseline base;" in text
    assert "says CHANGED: run a full assessment" in text
    checks = json.loads((tmp_path / "t.json").read_text())["checks"]
    assert [c["check_id"] for c in checks] == ["worn"] and checks[0]["verdict"] == "changed"
    assert (arch / "checks" / "ur5-sim" / "worn" / "check.json").is_file()
    assert (
        main(["archive", "add-check", str(out), "--robot", "ur5-sim", "--archive", str(arch)]) == 2
    )
    assert "already archived" in capsys.readouterr().err


@pytest.mark.timeout(150)
def test_healthy_check_killed_then_resumed_is_unchanged(baseline, tmp_path, capsys):
    plan, base = baseline
    out = tmp_path / "healthy"
    args = _check(plan, base, out)
    env = {**os.environ, "QUICKHEALTH_LOCK_DIR": os.environ["QUICKHEALTH_LOCK_DIR"]}
    err = tmp_path / "stderr.txt"
    with open(err, "w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "quickhealth.station.cli", *args],
                                env=env, stdout=subprocess.DEVNULL, stderr=f)  # fmt: skip
    try:
        t0 = time.monotonic()
        while _captured(out) < 2:
            assert proc.poll() is None, err.read_text()
            assert time.monotonic() - t0 < 90, "no capture within 90 s"
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    time.sleep(0.5)  # the killed check's simulator sees its parent gone
    assert not read_journal(out / JOURNAL).ended
    # a resume with other error rates would be another check: refused, nothing moves
    assert main([*args, "--resume", "--false-alarm", "0.05"]) == 2
    assert "resume with the same error rates" in capsys.readouterr().err
    code = main([*args, "--resume"])
    text = capsys.readouterr()
    assert code == 0, text.err
    assert "UNCHANGED after" in text.out
    doc = json.loads((out / "check.json").read_text())
    # decided within the 12 poses or, on a plan this short, not (the full reference plan's
    # figures are in docs/monitoring.md): never "changed"
    assert doc["verdict"] == "unchanged" and doc["changes"] == []
    recs = [r for _, r, _ in iter_records(out / JOURNAL)]
    measured = [r["name"] for r in recs if r.get("type") == "measured"]
    assert len(measured) == len(set(measured)) == doc["poses"]  # nothing lost or repeated
    assert sum(r.get("type") == "resume" for r in recs) == 1
    # a finished check resumed again: nothing moves, check.json as it was
    again = main([*args, "--resume"])
    assert again == 2 and "already complete" in capsys.readouterr().err


def _captured(out: Path) -> int:
    if not (out / JOURNAL).exists():
        return 0
    try:
        return sum(1 for _, r, _ in iter_records(out / JOURNAL) if r.get("type") == "captured")
    except Exception:  # noqa: BLE001 - being written
        return 0
