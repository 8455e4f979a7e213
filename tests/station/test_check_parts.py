"""The quick check's parts that need no robot: the journal's timing, robot time at real speed,
and the archive's refusals of what is not a check."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.formats.journal import Captured, decode, encode


def test_captures_journal_where_the_robot_time_went():
    rec = Captured(3, "P003", np.zeros(6), 0.1, 12.5, ("a.png", "b.png"),
                   timing={"move": 2.5, "settle": 0.2, "pan": 0.0, "capture": 0.4})  # fmt: skip
    back = decode(json.loads(json.dumps(encode(rec))))
    assert back.timing == rec.timing
    old = encode(rec)
    del old["timing_s"]  # an older journal
    assert decode(old).timing is None
    bad = {**encode(rec), "timing_s": {"move": -1}}
    with pytest.raises(ValueError, match="non-negative"):
        decode(bad)


def test_robot_time_at_real_speed():
    from types import SimpleNamespace

    from quickhealth.station.services.checking import dwell_s, joint_move_s, plan_loop_s

    mo = SimpleNamespace(joint_speed=np.radians(60.0), joint_accel=np.radians(120.0))
    plan = SimpleNamespace(
        motion=mo,
        home=np.zeros(6),
        poses=[SimpleNamespace(q=np.full(6, np.radians(90.0)))],
        document={"poses": [{"leg_time_s": 2.5}]},
    )
    # 90° at 60°/s, 120°/s²: 0.5 s up, 1 s cruise, 0.5 s down
    assert joint_move_s(plan, np.zeros(6), plan.poses[0].q) == pytest.approx(2.0)
    assert dwell_s({"move": 9.0, "settle": 0.2, "pan": 0.1, "capture": 0.4}) == pytest.approx(0.7)
    assert dwell_s(None) is None
    assert plan_loop_s(plan, 0.7) == pytest.approx(2.5 + 2.0 + 0.7)


def test_archive_refuses_what_is_not_a_check(tmp_path):
    import qh_runs

    from quickhealth.station.archive import Archive

    arch = Archive.open(tmp_path / "arch")
    arch.add_run("r", qh_runs.make_run(tmp_path / "run1", 1, n_poses=30, light=True))
    folder = tmp_path / "c"
    folder.mkdir()
    with pytest.raises(InputError, match="no check.json"):
        arch.add_check("r", folder)
    (folder / "check.json").write_text(json.dumps({"schema": "quickhealth.report/2"}))
    with pytest.raises(InputError, match="not a quick check"):
        arch.add_check("r", folder)
    doc = {"schema": "quickhealth.check/1", "verdict": "changed", "decided": True, "poses": 4,
           "robot_time_s": 15.0, "full_loop_robot_time_s": 250.0, "run_id": "c1",
           "started_utc": "2026-01-02T08:00:00Z", "baseline": {"run_id": "run1"},
           "changes": [{"words": "joint 2 tilt about x", "size": 0.11, "size_unit": "mrad"}]}  # fmt: skip
    (folder / "check.json").write_text(json.dumps(doc))
    rec = arch.add_check("r", folder)
    assert (rec.check_id, rec.verdict, rec.poses, rec.baseline_run_id) == (
        "c1",
        "changed",
        4,
        "run1",
    )
    assert "joint 2 tilt about x 0.11 mrad" in rec.changes
    assert [c.check_id for c in arch.checks("r")] == ["c1"]
    assert [r.run_id for r in arch.runs("r")] == ["run1"]  # a check is never a run
    from quickhealth.station.archive import check_lines

    lines = check_lines(arch.checks("r"))
    assert lines[0].startswith("quick checks (1") and "CHANGED after 4 poses" in lines[1]
    with pytest.raises(InputError, match="already archived"):
        arch.add_check("r", folder)
