"""`quickhealth plan` on the command line: outputs, and one-line refusals (exit status 2)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from quickhealth.station.cli import main
from quickhealth.station.planning.planfile import load_plan

REF = Path(__file__).parents[2] / "station" / "data" / "reference_cell.toml"


def _one_line_error(capsys, rc, pattern):
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1, err
    assert err[0].startswith("quickhealth: error:") or "error:" in err[0]
    assert re.search(pattern, err[0]), err[0]


@pytest.mark.slow
def test_small_plan_writes_everything(tmp_path, capsys):
    out = tmp_path / "p"
    rc = main(["plan", "--cell", "reference", "--n", "16", "--seed", "2", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "generated 16, kept" in text and "plan sha256:" in text
    for name in ("plan.json", "loop.script", "fig6_joints.png", "fig6_targets.png"):
        assert (out / name).stat().st_size > 0
    plan = load_plan(out / "plan.json")
    doc = json.loads((out / "plan.json").read_text())
    assert doc["summary"]["generated"] == 16
    assert {p["leg"] for p in doc["poses"]} <= {"linear", "joint"}
    assert all(len(p["q_deg"]) == 6 for p in doc["poses"])
    assert all("reason" in d for d in doc["dropped"])
    assert plan.hash in (out / "loop.script").read_text().replace("# plan ", "")
    # same inputs, same frozen plan
    rc = main(
        ["plan", "--cell", str(REF), "--n", "16", "--seed", "2", "--out", str(tmp_path / "q")]
    )
    assert rc == 0
    assert load_plan(tmp_path / "q" / "plan.json").poses[0].q.tolist() == plan.poses[0].q.tolist()


def test_n_zero_is_refused(tmp_path, capsys):
    rc = main(["plan", "--cell", "reference", "--n", "0", "--out", str(tmp_path / "o")])
    _one_line_error(capsys, rc, r"--n: 0 is not a number of poses \(an integer in 1\.\.1000\)")
    assert not (tmp_path / "o").exists()


def test_camera_behind_a_wall_is_refused(tmp_path, capsys):
    wall = '\n[[obstacle]]\nname = "wall"\nshape = "box"\ncenter_mm = [1400, 0, 500]\nsize_mm = [50, 4000, 3000]\n'
    text = REF.read_text().replace("[motion]", wall + "\n[motion]")
    cell = tmp_path / "walled.toml"
    cell.write_text(text)
    rc = main(["plan", "--cell", str(cell), "--n", "20", "--out", str(tmp_path / "o")])
    _one_line_error(
        capsys, rc, r"walled\.toml: camera\.left: view of the work volume blocked by 'wall'"
    )
    assert not (tmp_path / "o").exists()


def test_camera_inside_an_obstacle_and_unreachable_workspace(tmp_path, capsys):
    text = REF.read_text().replace("center_mm = [2060, 0, 450]", "center_mm = [2000, 0, 450]")
    (tmp_path / "a.toml").write_text(text)
    rc = main(
        ["plan", "--cell", str(tmp_path / "a.toml"), "--n", "5", "--out", str(tmp_path / "o")]
    )
    _one_line_error(capsys, rc, r"camera\.left\.position_mm: inside obstacle 'stereo bar'")
    far = (
        REF.read_text()
        .replace("min_mm = [-350, -700, 60]", "min_mm = [0, 0, 2000]")
        .replace("max_mm = [750, 700, 850]", "max_mm = [100, 100, 2100]")
    )
    (tmp_path / "b.toml").write_text(far)
    rc = main(
        ["plan", "--cell", str(tmp_path / "b.toml"), "--n", "10", "--out", str(tmp_path / "o")]
    )
    _one_line_error(capsys, rc, r"no target pose is feasible .*unreachable")


@pytest.mark.parametrize(
    ("payload", "pattern"),
    [
        (b"!!python/object/apply:os.system ['touch /tmp/x']\n", r"YAML object tag"),
        (
            b"\x80\x04\x95\x10\x00\x00\x00\x00\x00\x00\x00}\x94\x8c\x01a\x94K\x01s.",
            r"not a TOML cell file",
        ),
        (b"<robot name='ur5'></robot>", r"not a TOML cell file"),
        (b'schema = "quickhealth.cell/1"\nname = "x"\n', r"robot: missing"),
    ],
)
def test_hostile_or_broken_cell_files(tmp_path, capsys, payload, pattern):
    f = tmp_path / "cell.toml"
    f.write_bytes(payload)
    rc = main(["plan", "--cell", str(f), "--n", "10", "--out", str(tmp_path / "o")])
    _one_line_error(capsys, rc, pattern)
    assert not (tmp_path / "o").exists()
