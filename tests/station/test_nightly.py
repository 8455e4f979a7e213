"""The nightly, unattended run: the shipped systemd units verify, the script's exit status."""

import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

UNITS = Path(__file__).resolve().parents[2] / "station" / "data" / "systemd"


def _units(tmp_path, exec_start=None):
    """The shipped units, pointed at the shipped script and example settings in tmp_path."""
    for f in UNITS.iterdir():
        shutil.copy2(f, tmp_path / f.name)
    svc = tmp_path / "quickhealth-nightly.service"
    text = svc.read_text()
    text = text.replace(
        "/usr/local/lib/quickhealth/quickhealth-nightly.sh",
        exec_start or str(tmp_path / "quickhealth-nightly.sh"),
    ).replace("/etc/quickhealth/nightly.env", str(tmp_path / "nightly.env.example"))
    svc.write_text(text)
    return svc, tmp_path / "quickhealth-nightly.timer"


@pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here"
)
def test_systemd_units_verify(tmp_path):
    svc, timer = _units(tmp_path)
    r = subprocess.run(
        ["systemd-analyze", "verify", str(svc), str(timer)], capture_output=True, text=True
    )
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr
    # and verify does catch a broken unit: a script that is not there
    bad = tmp_path / "bad"
    bad.mkdir()
    svc, timer = _units(bad, exec_start=str(bad / "missing.sh"))
    r = subprocess.run(["systemd-analyze", "verify", str(svc)], capture_output=True, text=True)
    assert r.returncode != 0 and "missing.sh" in r.stderr
    r = subprocess.run(
        ["systemd-analyze", "calendar", "*-*-* 02:00:00"], capture_output=True, text=True
    )
    assert r.returncode == 0 and "02:00:00" in r.stdout


STUB = """#!/bin/sh
echo "$*" >> "$STUB_LOG"
case "$1" in run) exit ${STUB_RUN:-0};; trend) exit ${STUB_TREND:-0};; check) exit ${STUB_CHECK:-0};; esac
exit 0
"""


def _nightly(tmp_path, **env):
    stub = tmp_path / "quickhealth"
    stub.write_text(STUB)
    stub.chmod(stub.stat().st_mode | stat.S_IXUSR)
    log = tmp_path / "calls.log"
    log.unlink(missing_ok=True)
    settings = {
        "QH_ROBOT": "ur5-cell3", "QH_CELL": "cell.toml", "QH_PLAN": "plan.json",
        "QH_ROBOT_IP": "192.168.1.10", "QH_CALIBRATION": "CAL.json",
        "QH_RUNS": str(tmp_path / "runs"), "QH_ARCHIVE": str(tmp_path / "arch"),
        "QH_BIN": str(stub), "STUB_LOG": str(log),
    }  # fmt: skip
    full = {"PATH": os.environ["PATH"], **settings, **env}
    full = {k: v for k, v in full.items() if v is not None}
    r = subprocess.run(
        [str(UNITS / "quickhealth-nightly.sh")], env=full, capture_output=True, text=True
    )
    calls = log.read_text().splitlines() if log.is_file() else []
    return r, calls


def test_nightly_script_steps_and_exit_status(tmp_path):
    r, calls = _nightly(tmp_path, QH_DB="postgresql+psycopg://qh@db/qh", QH_THRESHOLD_MM="0.5")
    assert r.returncode == 0, r.stderr
    assert [c.split()[0] for c in calls] == ["run", "identify", "archive", "report", "trend"]
    assert "--unattended" in calls[0] and "--robot-ip 192.168.1.10" in calls[0]
    run_dir = calls[0].split("--out ")[1].split()[0]
    assert run_dir.startswith(str(tmp_path / "runs")) and f"--out {run_dir}" in calls[1]
    assert calls[2].endswith("--db postgresql+psycopg://qh@db/qh")
    # the report judges the run (its verdict is the one every door shows), then the trend
    assert (
        calls[3].startswith(f"report {run_dir} --robot ur5-cell3")
        and "--threshold-mm 0.5" in calls[3]
    )
    assert "--threshold-mm 0.5" in calls[4] and f"--json {run_dir}/trend.json" in calls[4]
    # the trend flags the robot: exit 1, for the timer's unit to fail and alert
    r, calls = _nightly(tmp_path, STUB_TREND="1")
    assert r.returncode == 1 and len(calls) == 5 and "--db" not in calls[2]
    # the cell fails: exit 3, nothing fitted or archived
    r, calls = _nightly(tmp_path, STUB_RUN="3")
    assert r.returncode == 3 and len(calls) == 1
    # a setting missing: exit 2 with one line, nothing run
    r, calls = _nightly(tmp_path, QH_ROBOT_IP=None)
    assert r.returncode == 2 and calls == []
    assert r.stderr.strip().splitlines() == [
        "quickhealth-nightly: error: not set: QH_ROBOT_IP (see nightly.env.example)"
    ]


def test_nightly_quick_check_runs_the_full_loop_only_when_changed(tmp_path):
    r, calls = _nightly(tmp_path, QH_MODE="check")  # unchanged: the check alone
    assert r.returncode == 0, r.stderr
    assert [c.split()[0] for c in calls] == ["check"]
    assert "--robot ur5-cell3" in calls[0] and "--unattended" in calls[0]
    assert f"--archive {tmp_path / 'arch'}" in calls[0]
    r, calls = _nightly(tmp_path, QH_MODE="check", STUB_CHECK="1")  # changed: the full loop
    assert r.returncode == 0 and [c.split()[0] for c in calls] == [
        "check", "run", "identify", "archive", "report", "trend"
    ]  # fmt: skip
    r, calls = _nightly(tmp_path, QH_MODE="check", STUB_CHECK="3")  # the cell failed
    assert r.returncode == 3 and len(calls) == 1
    r, calls = _nightly(tmp_path, QH_MODE="nightly")
    assert r.returncode == 2 and calls == [] and "QH_MODE" in r.stderr


def test_the_documented_cron_line_passes_the_settings_to_the_script(tmp_path):
    """docs/monitoring.md's cron line, run by /bin/sh as cron would, with the shipped settings."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "monitoring.md").read_text()
    line = next(ln for ln in doc.splitlines() if ln.strip().startswith("0 2 * * *"))
    command = line.strip().split(None, 5)[5]  # after the five time fields
    stub = tmp_path / "quickhealth"
    stub.write_text(STUB)
    stub.chmod(stub.stat().st_mode | stat.S_IXUSR)
    env_file = tmp_path / "nightly.env"
    text = (UNITS / "nightly.env.example").read_text()
    text = text.replace("/opt/quickhealth/.venv/bin/quickhealth", str(stub))
    text = text.replace("/var/lib/quickhealth/runs", str(tmp_path / "runs"))
    env_file.write_text(text + f"STUB_LOG={tmp_path / 'calls.log'}\n")
    command = (
        command.replace("/etc/quickhealth/nightly.env", str(env_file))
        .replace(
            "/usr/local/lib/quickhealth/quickhealth-nightly.sh",
            str(UNITS / "quickhealth-nightly.sh"),
        )
        .replace("/var/log/quickhealth-nightly.log", str(tmp_path / "cron.log"))
    )
    r = subprocess.run(["/bin/sh", "-c", command], env={"PATH": os.environ["PATH"]})
    log = (tmp_path / "cron.log").read_text()
    assert r.returncode == 0, log
    calls = (tmp_path / "calls.log").read_text().splitlines()
    assert [c.split()[0] for c in calls] == ["run", "identify", "archive", "report", "trend"], log
    assert "--robot-ip 192.168.1.10" in calls[0] and "--robot ur5-cell3" in calls[2]
