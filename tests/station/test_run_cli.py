"""`quickhealth run` on the command line: hostile inputs refused with one line and nothing
written or executed; two unattended runs at once."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import qh_station_plan as _station_plan

from quickhealth.station.cli import main


@pytest.fixture(scope="module")
def plan_path(tmp_path_factory):
    return _station_plan.plan_file(tmp_path_factory.getbasetemp(), 6)


def _one_line_error(capsys, code, want):
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("quickhealth: error: "), err
    assert want in err, err


def test_pose_name_carrying_urscript_is_refused(plan_path, tmp_path, capsys):
    from quickhealth.station.planning.planfile import content_hash

    doc = json.loads(plan_path.read_text())
    doc["poses"][0]["name"] = 'P1"\nsocket_open("10.0.0.9", 6000)\nsocket_send_string("x'
    doc["hash"] = content_hash(doc)  # a well-formed file, hash and all
    evil = tmp_path / "evil_plan.json"
    evil.write_text(json.dumps(doc))
    out = tmp_path / "run"
    code = main(["run", "--cell", "reference", "--plan", str(evil), "--out", str(out), "--sim"])
    _one_line_error(capsys, code, "is not a plain identifier")
    assert not out.exists()


def test_cell_file_with_a_yaml_object_tag_is_refused(plan_path, tmp_path, capsys):
    marker = tmp_path / "pwned"
    cell = tmp_path / "cell.toml"
    cell.write_text(f'!!python/object/apply:os.system ["touch {marker}"]\nname = "x"\n')
    out = tmp_path / "run"
    code = main(["run", "--cell", str(cell), "--plan", str(plan_path), "--out", str(out), "--sim"])
    _one_line_error(capsys, code, str(cell))
    assert not marker.exists() and not out.exists()


@pytest.mark.parametrize(
    ("env", "value", "want"),
    [
        (
            "QUICKHEALTH_SIM_SPEED_FACTOR",
            "fast",
            "QUICKHEALTH_SIM_SPEED_FACTOR='fast': not a number",
        ),
        ("QUICKHEALTH_SIM_SPEED_FACTOR", "nan", "must be in 0.1..100"),
        ("QUICKHEALTH_SIM_SPEED_FACTOR", "1e9", "must be in 0.1..100"),
        ("QUICKHEALTH_SIM_IMAGE_SCALE", "0", "must be in 0.05..1"),
        ("QUICKHEALTH_SIM_IMAGE_SCALE", "inf", "must be in 0.05..1"),
    ],
)
def test_absurd_simulated_cell_settings_are_refused(
    plan_path, tmp_path, capsys, monkeypatch, env, value, want
):
    monkeypatch.setenv(env, value)
    out = tmp_path / "run"
    code = main(
        ["run", "--cell", "reference", "--plan", str(plan_path), "--out", str(out), "--sim"]
    )
    _one_line_error(capsys, code, want)
    assert not out.exists()


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_model_file_that_is_a_pickle_is_refused(tmp_path, capsys):
    marker = tmp_path / "pwned"
    model = tmp_path / "model.json"
    model.write_bytes(pickle.dumps(_Payload(marker)))
    inp = tmp_path / "q.csv"
    inp.write_text("q1,q2,q3,q4,q5,q6\n0,-90,90,-90,-90,0\n")
    out = tmp_path / "pred.csv"
    code = main(["identify", "predict", str(model), str(inp), "--out", str(out)])
    _one_line_error(capsys, code, "model.json")
    assert not marker.exists() and not out.exists()


@pytest.mark.parametrize("name", ["../evil", "a/../../b", "..", "ur5/../../etc"])
def test_robot_name_that_escapes_is_refused(plan_path, tmp_path, capsys, name):
    out = tmp_path / "run"
    code = main(
        ["run", "--cell", "reference", "--plan", str(plan_path), "--out", str(out), "--sim",
         "--robot-name", name]
    )  # fmt: skip
    _one_line_error(capsys, code, "robot name")
    assert not out.exists()


def test_run_folder_with_dotdot_is_refused(plan_path, tmp_path, capsys):
    out = tmp_path / "a" / ".." / ".." / "escaped"
    code = main(
        ["run", "--cell", "reference", "--plan", str(plan_path), "--out", str(out), "--sim"]
    )
    _one_line_error(capsys, code, "'..' is not allowed")
    assert not (tmp_path.parent / "escaped").exists()


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_second_unattended_run_exits_at_once(plan_path, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("QUICKHEALTH_LOCK_DIR", str(tmp_path / "lock"))
    first = subprocess.Popen(
        [sys.executable, "-m", "quickhealth.station.cli", "run", "--cell", "reference",
         "--plan", str(plan_path), "--out", str(tmp_path / "r1"), "--sim", "--unattended",
         "--sim-image-scale", "0.25", "--sim-speed-factor", "8"],
        env={**os.environ, "QUICKHEALTH_LOCK_DIR": str(tmp_path / "lock")},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        lock = tmp_path / "lock" / "run.lock"
        t0 = time.monotonic()
        while not (lock.exists() and str(first.pid) in lock.read_text()):
            assert first.poll() is None, first.communicate()
            assert time.monotonic() - t0 < 60
            time.sleep(0.05)
        t1 = time.monotonic()
        code = main(
            ["run", "--cell", "reference", "--plan", str(plan_path), "--out", str(tmp_path / "r2"),
             "--sim", "--unattended"]
        )  # fmt: skip
        dt = time.monotonic() - t1
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=10)
    err = capsys.readouterr().err
    assert code == 3 and dt < 2.0, (code, dt, err)
    assert err.count("\n") == 1 and "another quickhealth run holds the cell" in err
    assert f"pid {first.pid}" in err
    assert not (tmp_path / "r2").exists()


def test_run_lock_is_exclusive_and_names_its_holder(tmp_path):
    from quickhealth.station.run.lock import RunBusy, RunLock

    with RunLock.acquire(tmp_path / "night1", directory=tmp_path / "lk"):
        with pytest.raises(RunBusy) as err:
            RunLock.acquire(tmp_path / "night2", directory=tmp_path / "lk")
        assert f"pid {os.getpid()}" in str(err.value) and "night1" in str(err.value)
    RunLock.acquire(tmp_path / "night3", directory=tmp_path / "lk").release()  # free again


def test_sim_controller_refuses_bad_options(capsys):
    assert main(["sim-controller", "--speed-factor", "1e9"]) == 2
    assert "--speed-factor" in capsys.readouterr().err
    assert main(["sim-controller", "--q0-deg", "1,2,x"]) == 2
    assert "--q0-deg" in capsys.readouterr().err


def test_run_into_a_plan_folder_is_refused_without_force(plan_path, tmp_path, capsys):
    out = tmp_path / "plan"
    out.mkdir()
    (out / "plan.json").write_text(plan_path.read_text())
    before = sorted(p.name for p in out.iterdir())
    argv = ["run", "--cell", "reference", "--plan", str(plan_path), "--out", str(out), "--sim"]
    code = main(argv)
    _one_line_error(
        capsys, code, "holds a plan (plan.json): choose another folder, or give --force"
    )
    assert sorted(p.name for p in out.iterdir()) == before  # nothing written, nothing moved
