"""Backtesting the quick check: a recorded run serves as the robot (``check --replay``).

"Would the quick check have caught this?"  A recorded full run (a folder with its
``measurements.csv``, and where it has them its ``plan.json`` and journal) stands in for the
robot: the check chooses, one after another, among the run's rows by the same rule as on a
station (:func:`~.checking.rank_candidates`: information on a change per second of robot
time), "measures" a pose by taking its recorded row, and decides with the same sequential
test (:class:`~quickhealth.identify.quickcheck.CheckRun`).  It writes the same check.json
(plus a ``replay`` object) and exits as the check does: 0 unchanged, 1 changed.

Robot time: each move in the check's own order at the recorded plan's joint speed and
acceleration (or the reference cell's, for a run without a plan: a tracker series), each
pose's dwell (settling, pan, capture) as the run's journal measured it at that pose, or the
median the journal measured, or the motion's settle time plus a capture when there is no
journal.  Moves between rows are taken as free joint moves: the run reached every row, but
no collision check is made on the check's own legs (there is no cell).

Pairing: when the baseline's measurements carry the recorded rows' pose ids, each row is
compared with the baseline's own measurement of that pose (the paired check); otherwise
with the baseline's model, its covariance integrated out (another pose set, a tracker
series split by goal pose).

SYNOPSIS::

    res = replay_check(Path("runs/night-12"), load_baseline(Path("runs/base")), Path("bt/12"))
    res.verdict, res.document["changes"][0]["fault"]
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify import quickcheck as qc
from ...identify.errors import InputError
from ...identify.measurements import Measurements
from ..formats import read_measurements
from ..formats.common import write_text_atomic
from ..provenance import software_version
from ..run.journal import JOURNAL, read_journal
from .checking import (
    CHECK_FILE,
    FIRST_DWELL_EXTRA_S,
    Baseline,
    CheckOutcome,
    baseline_json,
    decision_document,
    dwell_s,
)

F = NDArray[np.float64]


#: What :func:`replay_check` decided and wrote (the live check's outcome, without a run).
ReplayResult = CheckOutcome


@dataclass(frozen=True, eq=False)
class Recorded:
    """A recorded run as the replay's robot: its rows, motion law, home and dwell per row."""

    folder: Path
    meas: Measurements
    joint_speed: float  # rad/s
    joint_accel: float  # rad/s²
    motion_source: str
    home: F | None
    dwell: F  # (n,) s per row
    dwell_source: str
    plan_loop_s: float | None  # the recorded plan's loop, as the live check counts it


def load_recorded(folder: Path, n_joints: int) -> Recorded:
    """The recorded run in ``folder`` (one line when it is no run folder)."""
    from ..planning import load_cell, load_plan  # the planner: only its motion law is used

    folder = Path(folder)
    csv = folder / "measurements.csv"
    if not folder.is_dir() or not csv.is_file():
        raise InputError(f"--replay {folder}: not a recorded run (no measurements.csv)")
    meas = read_measurements(csv, n_joints)
    plan, why = None, "the recorded run has no plan.json"
    if (folder / "plan.json").is_file():
        try:
            plan = load_plan(folder / "plan.json")
        except InputError as exc:  # robot time only: say so, never guess the plan
            why = f"its plan.json cannot be read: {exc}"
    if plan is not None:
        motion, source, home = plan.motion, "the recorded run's plan.json", plan.home
    else:
        motion = load_cell("reference").motion
        source, home = f"the reference cell's ({why})", None
    dwell = np.full(meas.n_poses, float(motion.settle_s) + FIRST_DWELL_EXTRA_S)
    dwell_source = "the motion's settle time plus a capture (no journal)"
    loop = None
    if (folder / JOURNAL).is_file():
        st = read_journal(folder / JOURNAL)
        by_name = {c.name: dwell_s(c.timing) for c in st.captured.values()}
        known = [v for v in by_name.values() if v is not None]
        if known:
            med = float(np.median(known))
            ids = meas.pose_id or ()
            dwell = np.array([by_name.get(p) or med for p in ids] or dwell)
            dwell_source = "the recorded run's journal (per pose; its median where absent)"
            if plan is not None:
                from .checking import plan_loop_s

                loop = plan_loop_s(plan, med)
    return Recorded(folder, meas, float(motion.joint_speed), float(motion.joint_accel), source,
                    home, dwell, dwell_source, loop)  # fmt: skip


def _move_s(rec: Recorded, q_from: F, q_to: F) -> F:
    """Rest-to-rest trapezoid of the largest joint change (the controller's moveJ)."""
    d = np.max(np.abs(np.atleast_2d(q_to) - np.asarray(q_from)), axis=-1)
    v, a = rec.joint_speed, rec.joint_accel
    return np.where(d > v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


def replay_check(
    recorded: Path,
    baseline: Baseline,
    out: Path,
    *,
    settings: qc.CheckSettings = qc.CheckSettings(),
    say: Callable[[str], None] | None = None,
) -> ReplayResult:
    """The quick check with the recorded run in ``recorded`` as the robot; writes
    ``out/check.json``.

    Raises
    ------
    InputError
        No recorded run, another robot, or no row the baseline can be compared at.
    """
    say = say or (lambda s: None)
    fitted = baseline.fitted
    rec = load_recorded(Path(recorded), fitted.robot.n_joints)
    ids = rec.meas.pose_id
    paired = (
        baseline.measurements is not None
        and ids is not None
        and set(ids) <= set(baseline.measurements.pose_id or ())
    )
    model = qc.change_model(fitted, settings, baseline.measurements if paired else None)
    spec = fitted.spec
    inside = np.all((rec.meas.q >= spec.q_lo - 1e-9) & (rec.meas.q <= spec.q_hi + 1e-9), axis=1)
    left = [int(i) for i in np.flatnonzero(inside)]
    if not left:
        raise InputError(
            f"--replay {rec.folder}: no row inside the baseline's joint ranges: nothing to check"
        )
    cand = replace(rec.meas, time=None, temp=None, excluded=None)
    run = qc.CheckRun(model, fitted)
    order: list[int] = []
    q_now = rec.home if rec.home is not None else rec.meas.q[left[0]]
    q_start = np.asarray(q_now, float)
    meas = None
    stop = "the recorded run's rows are all measured"
    while left:
        why = run.stop_reason()
        if why is not None:
            stop = why
            break
        gains = qc.information_gains(model, fitted, meas, q_now, cand.subset(np.array(left)))
        cost = _move_s(rec, q_now, rec.meas.q[left]) + rec.dwell[left]
        k = left.pop(int(np.argmax(gains / cost)))
        order.append(k)
        q_now = rec.meas.q[k]
        meas = rec.meas.subset(np.array(order))
        run.update(meas)
        say(f"pose {len(order):3d}: {_name(rec, k)}")
    else:
        why = run.stop_reason()
        stop = why or stop
    doc = _document(rec, baseline, model, run, order, q_start, stop)
    Path(out).mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(out) / CHECK_FILE, json.dumps(doc, indent=1) + "\n")
    return CheckOutcome(Path(out), run.status, doc)


def _name(rec: Recorded, k: int) -> str:
    return rec.meas.pose_id[k] if rec.meas.pose_id else f"row {k}"


def _document(rec, baseline, model, run, order, q_start, stop) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    """check.json of a replay: the live check's keys, robot time as :mod:`this module <.replay>`
    counts it, and a ``replay`` object."""
    q = rec.meas.q
    path = [q_start, *[q[k] for k in order]]
    moves = float(sum(_move_s(rec, a, b)[0] for a, b in zip(path[:-1], path[1:], strict=True)))
    back = float(_move_s(rec, path[-1], rec.home)[0]) if rec.home is not None and order else 0.0
    dwell = float(np.sum(rec.dwell[order])) if order else 0.0
    robot = moves + back + dwell
    if rec.plan_loop_s is not None:
        full = rec.plan_loop_s
    else:  # the recorded rows in their own order, counted the same way
        full = float(np.sum(_move_s(rec, q[:-1], q[1:]))) + float(np.sum(rec.dwell))
        if rec.home is not None:
            full += float(_move_s(rec, rec.home, q[0])[0] + _move_s(rec, q[-1], rec.home)[0])
    return {
        **decision_document(model, run.status, run.decision, robot, full),
        "pose_names": [_name(rec, k) for k in order],
        "robot_time": {
            "moves_s": moves,
            "return_home_s": back,
            "dwell_s": dwell,
            "dwell_median_s": float(np.median(rec.dwell[order])) if order else None,
            "note": f"moves at {rec.motion_source} joint speed and acceleration in the check's "
            f"own order; dwell from {rec.dwell_source}",
        },
        "baseline": baseline_json(baseline, model),
        "plan_hash": None,
        "stop_reason": stop,
        "skipped_no_free_leg": [],
        "software": f"quickhealth {software_version()}",
        "started_utc": "",
        "run_id": rec.folder.name,
        "replay": {
            "recorded_run": str(rec.folder),
            "rows": rec.meas.n_poses,
            "rows_used": [int(k) for k in order],  # data rows, 0-based, in the check's order
            "paired": model.paired,
            "motion": rec.motion_source,
            "dwell": rec.dwell_source,
            "collision_checked": False,
        },
    }


__all__ = ["Recorded", "ReplayResult", "load_recorded", "replay_check"]
