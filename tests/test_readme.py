"""The README's command table as a tutorial: every command, in order, exactly as written, from
an empty folder, with the exit status the table documents.

The commands and their exit statuses are read from README.md (so the README cannot drift
from what works) and run through the command line's ``main`` in an empty folder; each step
reads what an earlier one wrote, and ``quickhealth examples`` makes what no step writes (the
calibration images and the tracker export).  Only the interactive TUI is not typed here
(tests/station/test_tui_cli.py and the simulated-cell TUI tests drive it).  The hardware step
``run --sim`` runs on the simulated cell (the real ur-rtde client against the controller
simulator) and must measure the plan; the simulated arm runs faster than life and renders
smaller images (``QUICKHEALTH_SIM_SPEED_FACTOR``, ``QUICKHEALTH_SIM_IMAGE_SCALE``), which
changes the simulated hardware, not the commands.
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from quickhealth.station import formats
from quickhealth.station.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"

# the one step a test cannot perform: the reason is the assertion's message
INTERACTIVE = {"tui": "interactive (tests/station/test_tui_cli.py drives it)"}


def readme_steps() -> list[tuple[str, int | None]]:
    """The ``quickhealth ...`` commands of the README's command table, in order, each with the
    exit status its row documents (None: not a status, e.g. the interactive TUI's "–")."""
    text = README.read_text(encoding="utf-8")
    table = text[text.index("| step | command | exit | docs |") :]
    table = table[: table.index("\n\n")]
    steps = []
    for row in table.splitlines()[2:]:
        cells = row.split(" | ")
        cmds = re.findall(r"`(quickhealth [^`]+)`", cells[1])
        codes = [int(c) if c.strip().isdigit() else None for c in cells[2].split(",")]
        assert len(codes) == len(cmds), (row, "one exit status per command")
        steps += list(zip(cmds, codes, strict=True))
    return steps


def test_readme_table_lists_the_tutorial_in_order():
    steps = readme_steps()
    words = [" ".join(shlex.split(c)[1:3]) for c, _ in steps]
    assert words[:4] == ["examples", "plan --cell", "vision calibrate", "run --cell"]
    assert len(steps) == 21, steps
    assert [c for c, code in steps if code is None] == ["quickhealth tui --sim"]


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_readme_tutorial_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("QUICKHEALTH_ARCHIVE", str(tmp_path / "archive"))
    # its own run lock: a run on this machine's cell (a demo, another test run) is not ours
    monkeypatch.setenv("QUICKHEALTH_LOCK_DIR", str(tmp_path / "lock"))
    # the simulated hardware, not the commands: an arm 20x faster than life and quarter-size
    # images (a 1x arm makes this one test take 4 of make test's minutes)
    monkeypatch.setenv("QUICKHEALTH_SIM_SPEED_FACTOR", "20")
    monkeypatch.setenv("QUICKHEALTH_SIM_IMAGE_SCALE", "0.25")
    done, outputs = [], {}
    for cmd, code in readme_steps():
        argv = shlex.split(cmd)[1:]
        skip = INTERACTIVE.get(argv[0])
        if skip:
            done.append(f"{cmd}: not run ({skip})")
            continue
        rc = main(argv)
        out, err = capsys.readouterr()
        assert "Traceback" not in out + err, (cmd, err)
        assert rc == code, (cmd, rc, code, err[-2000:])
        outputs[" ".join(argv[:2])] = out
        done.append(f"{cmd}: exit {rc}")
    print("\n".join(done))
    # each step's output fed the next
    for p in ("l/view01.png", "r/view01.png", "export.csv", "cal.json", "remeasured.csv", "meas.csv",
              "plan/plan.json", "plan/loop.script", "run1/measurements.csv", "run1/model.json",
              "run1/report.json", "pred.csv", "diag.json", "t/meas.csv", "t/meas.heldout.csv",
              "t/model.json", "run1/report.html", "run1/report.pdf", "corrected.urdf",
              "loop_comp.script"):  # fmt: skip
        assert Path(p).is_file(), p
    assert json.loads(Path("cal.json").read_text())["verdict"] == "ok"
    arch = tmp_path / "archive" / "robots" / "cell3"
    assert arch.is_dir() and any(arch.iterdir())
    # one verdict: trend and report say the same first lines about run1, judged against the
    # reference cell's spec (2 mm) and as the robot's baseline, never flagged against itself
    trend_lines = outputs["trend cell3"].splitlines()
    report_lines = outputs["report run1/"].splitlines()
    rep = json.loads(Path("run1/report.json").read_text())
    lines = rep["verdict"]["lines"]
    assert trend_lines[1 : 1 + len(lines)] == lines == report_lines[: len(lines)]
    assert lines[0] == "HEALTHY: within the spec; this run is the robot's baseline"
    assert "within the spec of 2 mm (max TCP error, cell reference)" in lines[1]
    # compensate says which target it kept as written, and why
    comp = outputs["compensate run1/model.json"]
    assert re.search(r"target 4: joint 6 correction .* kept as written, not compensated", comp)
    # the report has every section: the trend too (run1/ was archived as cell3 before the
    # report step, and the report finds it there); ISO 9283 does not apply to the reference
    # plan, which visits each pose once, and the report says so rather than "Not available"
    page = Path("run1/report.html").read_text()
    assert page.count("Not available") == 0, re.findall(r"Not available: [^<]*", page)
    n_poses = formats.read_measurements("run1/measurements.csv", 6).n_poses  # all measured
    applicable = re.findall(r"Not applicable: [^<]*", page)
    assert len(applicable) == 1 and applicable[0].startswith(
        f"Not applicable: the plan visits each of its {n_poses} poses once"
    ), applicable
    assert rep["schema"] == "quickhealth.report/2" and rep["trend"]["baseline"] == "run1"
    assert set(rep["iso9283"]) == {"not_applicable"}
