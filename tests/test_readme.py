"""The README's command table as a tutorial: every command, in order, exactly as written.

The commands are read from README.md (so the README cannot drift from what works) and run
through the command line's ``main`` in an empty folder; each step reads what an earlier one
wrote.  Two rows need what a test cannot type: the camera images of ``vision calibrate``
(and so ``vision measure ... --calibration cal.json``) and the interactive TUI.  The
hardware step ``run --sim`` runs on the simulated cell (the real ur-rtde client against the
controller simulator) and must measure the plan; the simulated arm runs faster than life and
renders smaller images (``QUICKHEALTH_SIM_SPEED_FACTOR``, ``QUICKHEALTH_SIM_IMAGE_SCALE``),
which changes the simulated hardware, not the commands.
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

# steps a test cannot perform: the reason is the assertion's message
NEEDS_A_PERSON = {
    "vision calibrate": "needs the user's camera images l/*.png, r/*.png",
    "vision measure": "needs cal.json from the calibration step",
    "import tracker": "needs the user's tracker export (tests/station/test_import_tracker.py)",
    "tui": "interactive (tests/station/test_tui_cli.py drives it)",
}
# commands whose exit status 1 means "flagged" (a verdict, not a failure)
MAY_FLAG = ("identify predict", "trend")


def readme_commands() -> list[str]:
    """The ``quickhealth ...`` commands of the README's command table, in order."""
    text = README.read_text(encoding="utf-8")
    table = text[text.index("| step | command | docs |") :]
    table = table[: table.index("\n\n")]
    cmds = []
    for row in table.splitlines()[2:]:
        cell = row.split(" | ")[1]
        cmds += re.findall(r"`(quickhealth [^`]+)`", cell)
    return cmds


def test_readme_table_lists_the_tutorial_in_order():
    cmds = readme_commands()
    words = [" ".join(shlex.split(c)[1:3]) for c in cmds]
    assert words[:3] == ["plan --cell", "vision calibrate", "run --cell"]
    assert len(cmds) == 20, cmds


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
    done = []
    for cmd in readme_commands():
        argv = shlex.split(cmd)[1:]
        name = " ".join(a for a in argv[:2] if not a.startswith("-"))
        skip = next((why for k, why in NEEDS_A_PERSON.items() if name.startswith(k)), None)
        if skip:
            done.append(f"{cmd}: not run ({skip})")
            continue
        rc = main(argv)
        out, err = capsys.readouterr()
        assert "Traceback" not in out + err, (cmd, err)
        if argv[0] == "compensate" and rc == 2:
            # refused: one line per target it would make worse, nothing written
            lines = err.strip().splitlines()
            assert lines and all("nothing written" in x and "target" in x for x in lines), err
            assert not Path("loop_comp.script").exists()
        else:
            ok = (0, 1) if any(" ".join(argv).startswith(m) for m in MAY_FLAG) else (0,)
            assert rc in ok, (cmd, rc, err)
        done.append(f"{cmd}: exit {rc}")
    print("\n".join(done))
    # each step's output fed the next
    for p in ("plan/plan.json", "plan/loop.script", "run1/measurements.csv", "run1/model.json",
              "run1/report.json", "pred.csv", "diag.json", "t/meas.csv", "t/meas.heldout.csv",
              "t/model.json", "run1/report.html", "corrected.urdf"):  # fmt: skip
        assert Path(p).is_file(), p
    arch = tmp_path / "archive" / "robots" / "cell3"
    assert arch.is_dir() and any(arch.iterdir())
    # the report has every section: the trend too (run1/ was archived as cell3 before the
    # report step, and the report finds it there); ISO 9283 does not apply to the reference
    # plan, which visits each pose once, and the report says so rather than "Not available"
    page = Path("run1/report.html").read_text()
    assert page.count("Not available") == 0, re.findall(r"Not available: [^<]*", page)
    n_poses = formats.read_measurements("run1/measurements.csv", 6).n_poses  # all measured
    assert re.findall(r"Not applicable: [^<]*", page) == [
        f"Not applicable: the plan visits each of its {n_poses} poses once: ISO 9283 accuracy "
        "(AP) and repeatability (RP) need poses visited more than once (one pose_id on "
        "several rows)"
    ]
    rep = json.loads(Path("run1/report.json").read_text())
    assert rep["schema"] == "quickhealth.report/2" and rep["trend"]["baseline"] == "run1"
    assert set(rep["iso9283"]) == {"not_applicable"}
