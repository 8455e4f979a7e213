"""The station's file writing (station/fsio.py) through the commands that use it.

- Figures are written atomically like every other file (``write_figure``), with the same
  one-line errors; no module writes a figure any other way, and identify/ and vision/ write
  no file at all.
- Output folders (``plan``, ``identify fit``): a folder holding results of another kind or
  of another run is refused without ``--force``; the README's flow (fit into the run folder
  that holds the measurements) keeps working and says what it replaces, in one line.
- CSV outputs quote a pose_id that holds a comma or a quote.
"""

from __future__ import annotations

import ast
import csv
import errno
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.errors import InputError, QuickhealthError
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats, fsio
from quickhealth.station.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _figure() -> Figure:
    fig = Figure(figsize=(2, 1.5))
    fig.subplots().plot([0, 1], [1, 0])
    return fig


# ------------------------------------------------------------------------------ figures


def test_write_figure_is_atomic_and_respects_the_umask(tmp_path):
    out = tmp_path / "sub" / "f.png"
    old = os.umask(0o027)
    try:
        assert fsio.write_figure(_figure(), out, dpi=50) == str(out)
    finally:
        os.umask(old)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert stat.S_IMODE(out.stat().st_mode) == 0o640
    assert [p.name for p in out.parent.iterdir()] == ["f.png"]  # no temporary file left


@pytest.mark.parametrize(
    ("err", "exc", "status", "text"),
    [
        (errno.EROFS, InputError, 2, "cannot write: Read-only file system"),
        (errno.EIO, QuickhealthError, 3, "writing failed: Input/output error"),
    ],
)
def test_a_failed_figure_write_keeps_the_old_file(tmp_path, monkeypatch, err, exc, status, text):
    out = tmp_path / "f.png"
    out.write_bytes(b"old figure")

    def fail(*a, **k):
        raise OSError(err, os.strerror(err))

    monkeypatch.setattr(fsio.os, "replace", fail)
    with pytest.raises(exc, match=text) as info:
        fsio.write_figure(_figure(), out)
    assert info.value.exit_status == status
    assert out.read_bytes() == b"old figure"
    assert [p.name for p in tmp_path.iterdir()] == ["f.png"]


def _calls(path: Path, names: set[str]) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in names:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {name}")
    return found


def test_every_figure_goes_through_write_figure():
    """savefig only renders into memory (fsio.write_figure, the HTML report's data URIs)."""
    allowed = {"station/fsio.py", "station/reporting/page.py"}
    calls = [
        c
        for p in sorted((ROOT / "station").rglob("*.py"))
        if str(p.relative_to(ROOT)) not in allowed
        for c in _calls(p, {"savefig"})
    ]
    assert calls == []
    # and there it writes into a BytesIO, never to a path
    src = (ROOT / "station" / "reporting" / "page.py").read_text()
    assert src.count(".savefig(") == 1 and "fig.savefig(buf, format=" in src


def test_identify_and_vision_write_no_files():
    """The pure libraries (docs: no files, clocks, hardware): no savefig, no writes."""
    writes = {"savefig", "write_text", "write_bytes", "imwrite", "dump", "mkdir", "tofile"}
    writes |= {"save", "savez", "savetxt", "touch", "unlink", "rename", "rmtree", "copyfile"}
    calls = []
    for pkg in ("identify", "vision"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            calls += _calls(p, writes)
            tree = ast.parse(p.read_text(encoding="utf-8"))
            for node in ast.walk(tree):  # open(..., "w"/"a"/"x")
                if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "open":
                    modes = [a.value for a in node.args[1:2] if isinstance(a, ast.Constant)]
                    modes += [
                        k.value.value
                        for k in node.keywords
                        if k.arg == "mode" and isinstance(k.value, ast.Constant)
                    ]
                    if any(set(str(m)) & set("wax+") for m in modes):
                        calls.append(f"{p.relative_to(ROOT)}:{node.lineno}: open {modes}")
    assert calls == []


# ------------------------------------------------------------------------ output folders


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("fsio")
    twin = make_twin(seed=5)
    q = random_joints(twin.robot, 60, seed=6, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=7)
    ids = ("a,b", 'say "hi"', "x, y") + tuple(f"P{i}" for i in range(3, 60))
    from dataclasses import replace

    meas = replace(meas, pose_id=ids)
    formats.write_measurements(d / "meas.csv", meas)
    return {"dir": d, "meas": meas, "twin": twin}


def _fit(meas: Path, out: Path, *extra: str) -> list[str]:
    argv = ["identify", "fit", str(meas), "--robot", "ur5", "--out", str(out)]
    return [*argv, "--max-order", "0", "--quiet", *extra]


def _listing(d: Path) -> dict[str, str]:
    return {p.name: p.read_bytes().hex()[:64] for p in sorted(d.iterdir()) if p.is_file()}


def test_fit_into_its_run_folder_twice_says_what_it_replaces(data, tmp_path, capsys):
    """The README's flow: run1/ holds the run; fit into it, then fit again (no --force)."""
    run = tmp_path / "run1"
    run.mkdir()
    (run / "measurements.csv").write_bytes((data["dir"] / "meas.csv").read_bytes())
    (run / "run.json").write_text("{}")
    (run / "journal.jsonl").write_text("")
    assert main(_fit(run / "measurements.csv", run)) == 0
    err = capsys.readouterr().err
    assert "replacing" not in err  # nothing was there to replace
    model = (run / "model.json").read_bytes()
    assert main(_fit(run / "measurements.csv", run)) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"replacing {run}/model.json, {run}/report.json, {run}/residuals.csv "
        "(the earlier fit of this data)"
    ]
    assert json.loads((run / "model.json").read_bytes())["coeffs"] == json.loads(model)["coeffs"]
    # the run's own files are kept
    assert {"measurements.csv", "run.json", "journal.jsonl"} <= set(_listing(run))


def test_fit_into_another_runs_folder_needs_force(data, tmp_path, capsys):
    other = tmp_path / "run2"
    other.mkdir()
    (other / "measurements.csv").write_text("q1,q2,q3,q4,q5,q6,x,y,z\n")
    (other / "model.json").write_text("{}")
    before = _listing(other)
    assert main(_fit(data["dir"] / "meas.csv", other)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out holds a run (measurements.csv)" in err[0]
    assert "a fit of unknown data (model.json)" in err[0] and "--force" in err[0]
    assert _listing(other) == before  # nothing written
    assert main(_fit(data["dir"] / "meas.csv", other, "--force")) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"replacing {other}/model.json (--force: {other} held a run (measurements.csv); "
        "a fit of unknown data (model.json))"
    ]
    assert (other / "measurements.csv").read_text() == "q1,q2,q3,q4,q5,q6,x,y,z\n"  # untouched
    assert json.loads((other / "report.json").read_text())["input"] == str(data["dir"] / "meas.csv")


def test_fit_into_a_results_folder_of_the_same_data_replaces_it(data, tmp_path, capsys):
    res = tmp_path / "results"
    assert main(_fit(data["dir"] / "meas.csv", res)) == 0
    (res / "notes.txt").write_text("mine")  # not a result: never a reason to refuse
    capsys.readouterr()
    assert main(_fit(data["dir"] / "meas.csv", res)) == 0
    assert capsys.readouterr().err.startswith(f"replacing {res}/model.json")
    # another measurement file into the same folder: the fit of other data is refused
    other = tmp_path / "other.csv"
    other.write_bytes((data["dir"] / "meas.csv").read_bytes())
    assert main(_fit(other, res)) == 2
    err = capsys.readouterr().err
    assert f"holds the fit of another measurement file, {data['dir'] / 'meas.csv'}" in err
    assert (res / "notes.txt").read_text() == "mine"


def test_plan_again_into_its_folder(tmp_path, capsys):
    out = tmp_path / "plan"
    argv = ["plan", "--cell", "reference", "--n", "20", "--out", str(out)]
    assert main(argv) == 0
    doc = (out / "plan.json").read_bytes()
    capsys.readouterr()
    assert main(argv) == 0  # the same command: the same plan, replaced, said in one line
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"replacing {out}/fig6_joints.png, {out}/fig6_targets.png, {out}/loop.script, "
        f"{out}/plan.json (the same plan)"
    ]
    assert (out / "plan.json").read_bytes() == doc
    # another plan is refused: runs and the trend compare plans by their hash
    assert main([*argv[:-2], "--seed", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out holds another plan (plan.json sha256:" in err[0]
    assert (out / "plan.json").read_bytes() == doc
    assert main([*argv[:-2], "--seed", "1", "--out", str(out), "--force"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"replacing {out}/fig6_joints.png")
    assert "(--force: " in err[0] and "held another plan" in err[0]
    assert json.loads((out / "plan.json").read_text())["seed"] == 1


def test_claim_output_folder_refuses_a_file(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="--out exists and is not a folder"):
        fsio.claim_output_folder(tmp_path / "f")


# ---------------------------------------------------------------------------------- CSV


def test_residuals_and_predictions_quote_a_nasty_pose_id(data, tmp_path):
    from quickhealth.station.formats import residual_table

    meas = data["meas"]
    twin = data["twin"]
    spec = ErrorModelSpec.uniform(6, 0, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, meas, spec, noise=InstrumentNoise(3e-5, 1e-4))
    rows = list(csv.reader(residual_table(fm, meas).splitlines()))
    head = rows[0]
    assert all(len(r) == len(head) for r in rows)
    assert [r[1] for r in rows[1:]] == list(meas.pose_id)
    assert [r[1] for r in rows[1:4]] == ["a,b", 'say "hi"', "x, y"]
    r_mm = np.array([float(r[head.index("r_mm")]) for r in rows[1:]])
    assert r_mm == pytest.approx(np.linalg.norm(fm.residual_pos, axis=1) * 1e3, abs=2e-6)
    # the measurement file itself reads back to the same ids
    assert formats.read_measurements(data["dir"] / "meas.csv", 6).pose_id == meas.pose_id


def test_stale_temp_files_of_a_killed_writer_are_removed(tmp_path):
    """What kill -9 between write and rename leaves (write_atomic's own naming) is swept on
    --resume; a live writer's temporary file and a user's files are left alone."""
    import subprocess
    import sys

    from quickhealth.station.fsio import remove_stale_temp_files, write_atomic

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    stale = tmp_path / f".0003_P003_L.png.{dead}.cf306f5d.tmp"
    live = tmp_path / f".journal.jsonl.{os.getpid()}.0badf00d.tmp"
    for p in (stale, live, tmp_path / ".notes.tmp", tmp_path / "0001_P001_L.png"):
        p.write_bytes(b"x")
    write_atomic(tmp_path / "done.json", "{}")
    assert remove_stale_temp_files(tmp_path) == [stale.name]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [live.name, ".notes.tmp", "0001_P001_L.png", "done.json"]
    )
