"""``quickhealth plan select`` and ``plan --optimal``: the rows an optimal design chooses, carried
over as they were; one-line refusals (exit 2)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from quickhealth.identify.fit import fit_model
from quickhealth.identify.robot import ur5
from quickhealth.identify.select import data_spec
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station.cli import main
from quickhealth.station.formats import write_model
from quickhealth.station.planning.planfile import load_plan


def _candidates(path, n=60, seed=3, note="x"):
    q = np.degrees(random_joints(ur5(), n, seed=seed))
    lines = ["# cell: test", "q1,q2,q3,q4,q5,q6,note,x,y,z"]
    for i, r in enumerate(q):
        cells = [f"{v:.6f}" for v in r] + [f"{note}{i}", f"{i}.5", "-1", "2"]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return lines


def test_plan_select_carries_the_chosen_rows_over(tmp_path, capsys):
    lines = _candidates(tmp_path / "cand.csv")
    out = tmp_path / "chosen.csv"
    rc = main(["plan", "select", str(tmp_path / "cand.csv"), "--robot", "ur5", "--n", "12",
               "--out", str(out)])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "chose 12 of 60 rows (I-optimal" in text and "predicted workspace TCP band" in text
    got = out.read_text().splitlines()
    assert got[0] == "# cell: test" and got[1].startswith("# selected: 12 of 60 rows")
    assert got[2] == lines[1]  # the header, every column kept
    rows = got[3:]
    assert len(rows) == 12 and set(rows) <= set(lines[2:])
    assert rows == [ln for ln in lines[2:] if ln in rows]  # the file's order
    # only the joint angles are read: other columns do not change the choice
    _candidates(tmp_path / "other.csv", note="y")
    rc = main(["plan", "select", str(tmp_path / "other.csv"), "--robot", "ur5", "--n", "12",
               "--out", str(tmp_path / "c2.csv")])  # fmt: skip
    assert rc == 0
    idx = [ln.split(",")[6][1:] for ln in rows]
    idx2 = [ln.split(",")[6][1:] for ln in (tmp_path / "c2.csv").read_text().splitlines()[3:]]
    assert idx == idx2
    capsys.readouterr()
    rc = main(["plan", "select", str(tmp_path / "cand.csv"), "--robot", "ur5", "--n", "12",
               "--out", str(tmp_path / "c3.csv"), "--criterion", "D", "--position-only"])  # fmt: skip
    assert rc == 0 and "D-optimal" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "pattern"),
    [
        (["--n", "61"], r"--n 61: choose between 1 and 60"),
        (["--n", "5", "--tool-mm", "1,2"], r"--tool-mm"),
        (["--n", "5", "--robot", "ur99"], r"ur99"),
    ],
)
def test_plan_select_refuses_in_one_line(tmp_path, capsys, args, pattern):
    _candidates(tmp_path / "cand.csv")
    base = ["plan", "select", str(tmp_path / "cand.csv"), "--robot", "ur5", "--out",
            str(tmp_path / "o.csv")]  # fmt: skip
    rc = main(base + args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and pattern.split(":")[0].strip("\\-") in err[0], err
    assert not (tmp_path / "o.csv").exists()


def test_plan_select_refuses_a_file_without_joints(tmp_path, capsys):
    (tmp_path / "bad.csv").write_text("q1,q2,q3\n1,2,3\n")
    rc = main(["plan", "select", str(tmp_path / "bad.csv"), "--robot", "ur5", "--n", "1",
               "--out", str(tmp_path / "o.csv")])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "bad.csv:1:" in err and "q4" in err
    rc = main(["plan", "select", str(tmp_path / "bad.csv"), "--robot", "ur5", "--n", "1",
               "--out", str(tmp_path / "bad.csv")])  # fmt: skip
    assert rc == 2  # the output would replace the input


def test_plan_without_cell_is_a_usage_error(capsys):
    rc = main(["plan", "--n", "10"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--cell, --out" in err[0]


@pytest.mark.slow
def test_optimal_plan_keeps_the_chosen_poses_with_their_legs(tmp_path, capsys):
    out = tmp_path / "p"
    rc = main(["plan", "--cell", "reference", "--n", "60", "--seed", "2", "--optimal", "12",
               "--out", str(out)])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "optimal design: 12 of" in text and "not-selected" in text
    plan = load_plan(out / "plan.json")  # valid: schema, limits, FK, hash
    doc = json.loads((out / "plan.json").read_text())
    design = doc["summary"]["design"]
    assert design["chosen"] == 12 and design["kept"] == len(plan.poses)
    assert 10 <= len(plan.poses) <= 12
    assert design["predicted_band_mm"] < design["random_band_mm"]
    # 12 poses do not saturate the model (1.3 x its identifiable coefficients / 6): all 12
    # are chosen by information, none to represent the rest
    assert (design["information_poses"], design["spread_poses"], design["prior"]) == (
        12,
        0,
        "stated",
    )
    reasons = {d["reason"] for d in doc["dropped"]}
    assert "not-selected" in reasons
    # the design spreads the poses: on 12 poses from 60 targets every joint's usable range is
    # mostly covered (the reference cell's --optimal 30 covers 100 %: docs/plan.md)
    assert min(doc["summary"]["joints"]["coverage"]) >= 0.5


def _baseline(folder, excess_mm=0.0):
    """A fitted run folder (model.json) of a twin UR5, its residual scatter beyond the
    instrument's ``excess_mm`` per axis."""
    twin = make_twin(seed=4)
    q = random_joints(twin.robot, 80, seed=6, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=7)
    fm = fit_model(twin.robot, meas, data_spec(twin.robot, meas, order=1),
                   setup=(twin.truth.T_instr_base, twin.truth.T_flange_target))  # fmt: skip
    fm = replace(fm, noise=replace(fm.noise, excess_pos=excess_mm * 1e-3))
    folder.mkdir()
    write_model(folder / "model.json", fm)
    return folder


def test_plan_select_takes_its_prior_from_a_baseline(tmp_path, capsys):
    """--baseline RUN_DIR: the fitted run's orders and scatter are the prior; a run whose model
    leaves much unexplained gets fewer poses by information, more to represent the rest."""
    _candidates(tmp_path / "cand.csv", n=120)
    base = ["plan", "select", str(tmp_path / "cand.csv"), "--robot", "ur5", "--n", "50"]
    rc = main([*base, "--out", str(tmp_path / "a.csv"), "--baseline",
               str(_baseline(tmp_path / "quiet"))])  # fmt: skip
    out = capsys.readouterr().out
    assert (
        rc == 0 and "50 by information, 0 to represent the candidates; prior: baseline quiet" in out
    )
    assert "prior: baseline quiet (model sha256:" in (tmp_path / "a.csv").read_text()
    rc = main([*base, "--out", str(tmp_path / "b.csv"), "--baseline",
               str(_baseline(tmp_path / "scatter", excess_mm=0.2))])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 0 and "31 by information, 19 to represent the candidates" in out


@pytest.mark.parametrize(
    ("args", "pattern"),
    [
        (["select", "CAND", "--robot", "ur10", "--n", "5", "--baseline", "BASE"], "a fit of ur5"),
        (["select", "CAND", "--robot", "ur5", "--n", "5", "--baseline", "EMPTY"], "no model.json"),
        (["--cell", "reference", "--n", "10", "--baseline", "BASE"], "only with --optimal"),
    ],
)
def test_plan_baseline_refusals(tmp_path, capsys, args, pattern):
    _candidates(tmp_path / "cand.csv")
    _baseline(tmp_path / "base")
    (tmp_path / "empty").mkdir()
    sub = {"CAND": tmp_path / "cand.csv", "BASE": tmp_path / "base", "EMPTY": tmp_path / "empty"}
    rc = main(["plan", *(str(sub.get(a, a)) for a in args), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and pattern in err[0], err
    assert not (tmp_path / "o").exists()
