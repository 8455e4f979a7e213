"""The quick check: has the robot changed since its baseline run?  One call for every door.

:func:`quick_check` runs the check on a station through the run's own machinery
(:func:`~quickhealth.station.run.loop.run_plan`: pre-flight, self-check, the crash-safe journal,
images, faults, cancel and ``resume``) with a :class:`CheckSequence` that chooses each next
pose while the data come in, and writes ``check.json`` beside the run's measurements.csv and
journal.  The statistics are :mod:`quickhealth.identify.quickcheck`.

Choosing the next pose (:class:`CheckSequence`): among the plan's poses not yet visited (and,
for a paired check, measured by the baseline), the one with the most information on change
per second of robot time from where the arm is: the D-optimal gain of every family of change
(:func:`~quickhealth.identify.quickcheck.information_gains`) over the time of a joint move
there at the plan's joint speed and acceleration (the trapezoid the controller runs) plus
the dwell at a pose (settling, pan, capture: the median measured so far).  Every move is a
joint (moveJ) leg checked for collisions by the planner's own check; a candidate without a
free leg is skipped.  The check stops when the test decides and, for "changed", once one
family of change holds 90 % of the evidence (the poses after the decision only name it), or
at the end of the plan.

Robot time at real speed (``robot_time_s``): every move's duration from the plan's joint
speed and acceleration (the motion law of the controller and of the simulator, which runs
it ``--sim-speed-factor`` times faster), plus each pose's measured settling, pan and capture
time, plus the move back home.  ``full_loop_robot_time_s`` is the plan's loop counted the
same way: its legs as planned (linear or joint) from home and back, and the median measured
dwell at each of its poses.

SYNOPSIS::

    base = load_baseline(Path("runs/base"))
    res = quick_check(station, plan, cell, base, Path("checks/c1"))
    res.verdict, res.robot_time_s, res.document["changes"]
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ...identify import quickcheck as qc
from ...identify.errors import HardwareError, InputError
from ...identify.faults import NamedChange
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.transforms import R_to_rpy
from ..formats import read_measurements, read_model
from ..formats.common import write_text_atomic
from ..hardware.legs import Leg
from ..provenance import software_version
from ..run.journal import JOURNAL, JournalState, read_journal
from ..run.loop import RunResult, run_plan
from ..run.outputs import journal_measurements
from ..run.progress import Progress, ProgressFn
from ..run.settings import RunSettings
from ..station import Station

if TYPE_CHECKING:  # the planner's collision library loads with the sequence, not the import
    from ..planning.cell import Cell
    from ..planning.planfile import Plan, PlanPose

F = NDArray[np.float64]

CHECK_FILE = "check.json"
CHECK_SCHEMA = "quickhealth.check/1"
#: Dwell at a pose (s) assumed before the first one is measured: the cell's settle time plus
#: a capture.
FIRST_DWELL_EXTRA_S = 0.5
DESIGN = (
    "Wald's sequential probability ratio test with composite hypotheses: Robbins' mixture "
    "likelihood ratio against 1/alpha for 'changed', the least favourable change of at least "
    "the detectable size against beta for 'unchanged' (anytime-valid by Ville's inequality)"
)


# --------------------------------------------------------------------------- the baseline


@dataclass(frozen=True, eq=False)
class Baseline:
    """A fitted baseline run: its model and (for a paired check) its measurements."""

    folder: Path
    fitted: FittedModel
    measurements: Measurements | None
    run_id: str
    plan_hash: str
    model_sha256: str


def load_baseline(folder: Path) -> Baseline:
    """The baseline run in ``folder``: model.json (fitted: ``quickhealth identify fit``) and
    its measurements.csv when present (the check is then paired with them).

    Raises
    ------
    InputError
        No folder, no model.json, or a file that cannot be read (one line).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"--baseline {folder}: not a run folder")
    mp = folder / "model.json"
    if not mp.is_file():
        raise InputError(
            f"--baseline {folder}: no model.json (fit the baseline run first: quickhealth "
            f"identify fit {folder / 'measurements.csv'} --robot ROBOT --out {folder})"
        )
    fitted = read_model(mp)
    meas = None
    csv = folder / "measurements.csv"
    if csv.is_file():
        meas = read_measurements(csv, fitted.robot.n_joints)
        if meas.pose_id is None or len(set(meas.pose_id)) != meas.n_poses:
            meas = None  # not a station run (no unique pose ids): compare with the model
    run_id, plan_hash = folder.name, ""
    rj = folder / "run.json"
    if rj.is_file():
        try:
            doc = json.loads(rj.read_text(encoding="utf-8"))
            run_id = str(doc.get("run_id") or run_id)
            plan_hash = str(doc.get("plan_hash") or "")
        except (OSError, ValueError, AttributeError):
            pass
    sha = hashlib.sha256(mp.read_bytes()).hexdigest()
    return Baseline(folder, fitted, meas, run_id, plan_hash, sha)


def archive_baseline(robot: str, archive: str | Path | None, db: str | None = None) -> Path:
    """The folder of ``robot``'s baseline run in the archive (one line when there is none)."""
    from ..archive import Archive  # SQLAlchemy: only when the archive is asked

    arch = Archive.open(archive, db, create=False)
    rec = arch.baseline(robot)
    if rec is None:
        raise InputError(
            f"robot {robot!r} has no baseline in the archive {arch.root}: quickhealth archive "
            "baseline ROBOT RUN_ID"
        )
    folder = arch.folder(rec)
    if not folder.is_dir():
        raise InputError(
            f"baseline run {rec.run_id} of robot {robot}: its folder {folder} is missing"
        )
    return folder


# --------------------------------------------------------------------------- robot time


def joint_move_s(plan: Plan, q_from: F, q_to: F) -> float:
    """Duration (s) of a moveJ from ``q_from`` to ``q_to`` at the plan's joint speed and
    acceleration: the synchronised trapezoid of the largest joint change."""
    from ..planning.planner import trap_time  # the planner loads python-fcl: not for a report

    mo = plan.motion
    d = float(np.max(np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))))
    return float(trap_time(np.array(d), mo.joint_speed, mo.joint_accel))


def dwell_s(timing: dict[str, float] | None) -> float | None:
    """Robot time at a pose after its move (s): settling, the pan motor, capture."""
    if not timing:
        return None
    return float(sum(timing.get(k, 0.0) for k in ("settle", "pan", "capture")))


def plan_loop_s(plan: Plan, dwell: float) -> float:
    """The plan's whole loop at real speed: its legs as planned (from home), back home, and
    ``dwell`` at each pose."""
    docs = plan.document.get("poses", [])
    legs = sum(float(p.get("leg_time_s", 0.0)) for p in docs)
    back = joint_move_s(plan, plan.poses[-1].q, plan.home) if plan.home is not None else 0.0
    return legs + back + dwell * len(plan.poses)


# --------------------------------------------------------------------------- the sequence


def rank_candidates(
    model: qc.ChangeModel,
    baseline: Baseline,
    plan: Plan,
    meas: Measurements | None,
    q_now: F,
    left: list[PlanPose],
    rows: Measurements,
    dwell: float,
) -> list[PlanPose]:
    """The poses ``left`` (their candidate ``rows``), best first: information on change
    (:func:`~quickhealth.identify.quickcheck.information_gains`) per second of robot time
    (the joint move from ``q_now`` at the plan's speed, plus ``dwell``)."""
    gains = qc.information_gains(model, baseline.fitted, meas, q_now, rows)
    cost = np.array([joint_move_s(plan, q_now, p.q) for p in left]) + dwell
    return [left[int(k)] for k in np.argsort(-(gains / cost))]


class CheckSequence:
    """Chooses the check's poses as the data come in (a :class:`~..run.PoseSequence`)."""

    order = "capture"
    wait_for_measurements = True

    def __init__(
        self,
        plan: Plan,
        cell: Cell,
        baseline: Baseline,
        model: qc.ChangeModel,
        q_start: F,
        say: Callable[[str], None] | None = None,
    ) -> None:
        from ..planning.collision import CollisionWorld  # python-fcl: only when a check runs

        self.plan = plan
        self.cell = cell
        self.base = baseline
        self.model = model
        self.q_start = np.asarray(q_start, float)
        self.say = say or (lambda s: None)
        self.world = CollisionWorld(cell)
        self.run = qc.CheckRun(model, baseline.fitted)
        self.stop_reason = ""
        self.candidates = self._candidates()
        self.skipped: list[str] = []

    def _candidates(self) -> list[PlanPose]:
        """The plan's poses a check may visit: inside the model's joint ranges (its series
        would extrapolate elsewhere) and, paired, measured by the baseline."""
        spec = self.base.fitted.spec
        out = []
        for p in self.plan.poses:
            if np.any(p.q < spec.q_lo - 1e-9) or np.any(p.q > spec.q_hi + 1e-9):
                continue
            if self.model.paired and p.name not in self.model.pairs:
                continue
            out.append(p)
        if not out:
            raise InputError(
                "no pose of the plan can be checked against this baseline (outside its joint "
                "ranges, or never measured by it): check with the baseline's own plan"
            )
        return out

    def measurements(self, state: JournalState) -> Measurements | None:
        """The check's measured poses in execution order."""
        return journal_measurements(state, self.plan, {}, order="capture")

    def _rows(self, poses: list[PlanPose]) -> Measurements:
        """Candidate rows: their joints and their expected noise (the baseline's measurement
        of the pose, else the model's instrument defaults)."""
        bm = self.base.measurements
        q = np.array([p.q for p in poses])
        ids = tuple(p.name for p in poses)
        if bm is not None and self.model.paired:
            sub = bm.subset(np.array([self.model.pairs[p.name] for p in poses]))
            return replace(
                sub, q=q, pose_id=ids, time=None, temp=None, excluded=None,
                joint_temp=None, joint_torque=None,
            )  # fmt: skip
        T = self.base.fitted.predict(q)
        return Measurements(q=q, pos=T[:, :3, 3], rpy=R_to_rpy(T[:, :3, :3]), pose_id=ids)

    def _here(self, state: JournalState) -> F:
        last = self._last(state)
        return self.q_start if last is None else np.asarray(state.captured[last].q, float)

    @staticmethod
    def _last(state: JournalState) -> int | None:
        return next(reversed(state.captured), None) if state.captured else None

    def _dwell(self, state: JournalState) -> float:
        d = [dwell_s(c.timing) for c in state.captured.values()]
        d = [x for x in d if x is not None]
        if d:
            return float(np.median(d))
        return float(self.plan.motion.settle_s) + FIRST_DWELL_EXTRA_S

    @property
    def status(self) -> qc.CheckStatus | None:
        """The test after every pose measured so far."""
        return self.run.status

    @property
    def decision(self) -> tuple[qc.Decision, int] | None:
        """The first boundary crossed and after how many poses."""
        return self.run.decision

    def update(self, state: JournalState) -> Measurements | None:
        """The test after every pose the journal holds (:class:`~..identify.quickcheck.CheckRun`)."""
        meas = self.measurements(state)
        self.run.update(meas)
        return meas

    def next_pose(self, state: JournalState) -> PlanPose | None:
        from ..planning.planner import joint_leg_ok  # python-fcl, loaded with the sequence

        meas = self.update(state)
        why = self.run.stop_reason()
        if why is not None:
            self.stop_reason = why
            return None
        done = state.done_indices
        left = [p for p in self.candidates if p.index not in done]
        if not left:
            self.stop_reason = "the plan's poses are all measured"
            return None
        q_now = self._here(state)
        ranked = rank_candidates(
            self.model, self.base, self.plan, meas, q_now, left, self._rows(left),
            self._dwell(state),
        )  # fmt: skip
        for p in ranked:
            if joint_leg_ok(self.cell, self.world, q_now, p.q):
                return replace(p, leg=Leg.JOINT)
            self.skipped.append(p.name)
        self.stop_reason = "no collision-free joint leg to any pose left"
        return None

    def resume_pose(self, state: JournalState) -> PlanPose | None:
        last = self._last(state)
        return None if last is None else self.plan.poses[last - 1]

    def finish(self, state: JournalState) -> tuple[F, Leg] | None:
        from ..planning.planner import joint_leg_ok  # python-fcl, loaded with the sequence

        home = self.plan.home
        if home is None:
            return None
        q = self._here(state)
        if not joint_leg_ok(self.cell, self.world, q, home):
            self.say("the arm stays at its last pose: no collision-free joint leg home from there")
            return None
        return home, Leg.JOINT


# --------------------------------------------------------------------------- the check


@dataclass(frozen=True, eq=False)
class CheckOutcome:
    """What a check decided and wrote (check.json's ``document``), live or replayed."""

    out: Path
    status: qc.CheckStatus | None
    document: dict[str, Any]

    @property
    def verdict(self) -> str:
        """``"unchanged"`` or ``"changed"``."""
        return str(self.document["verdict"])

    @property
    def changed(self) -> bool:
        """True when the check found a change."""
        return self.verdict == qc.Decision.CHANGED.value

    def summary(self) -> list[str]:
        """The lines every door shows."""
        return summary_lines(self.document)


@dataclass(frozen=True, eq=False)
class CheckResult(CheckOutcome):
    """What :func:`quick_check` did and wrote, with the run that measured the poses."""

    run: RunResult | None = None


def quick_check(
    station: Station,
    plan: Plan,
    cell: Cell,
    baseline: Baseline,
    out: Path,
    *,
    settings: qc.CheckSettings = qc.CheckSettings(),
    run_settings: RunSettings = RunSettings(),
    resume: bool = False,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    say: Callable[[str], None] | None = None,
) -> CheckResult:
    """Check ``station``'s robot against ``baseline`` with ``plan``'s poses into ``out``.

    Raises
    ------
    InputError
        The baseline and the plan do not fit (another robot, no pose to check), the folder
        holds another run, or a resumed folder holds another check.
    HardwareError
        Pre-flight failed (nothing moved); a fault during the check ends the run cleanly and
        is raised after check.json is written (the check can be resumed).
    """
    out = Path(out)
    fitted = baseline.fitted
    if fitted.robot.n_joints != plan.robot.n_joints:
        raise InputError(
            f"the baseline's robot has {fitted.robot.n_joints} joints, the plan's "
            f"{plan.robot.n_joints}"
        )
    model = qc.change_model(fitted, settings, baseline.measurements)
    q_start = plan.home if plan.home is not None else station.robot.joints()
    seq = CheckSequence(plan, cell, baseline, model, q_start, say)
    extra = {
        "kind": "check",
        "baseline_run": baseline.run_id,
        "baseline_model_sha256": baseline.model_sha256,
        "false_alarm": settings.false_alarm,
        "detect_mm": settings.detect * 1e3,
        "power": settings.power,
    }

    def same_check(state: JournalState) -> None:
        start = state.start or {}
        if start.get("kind") != "check":
            raise InputError(f"{out}: holds a run, not a quick check: check into another folder")
        if start.get("baseline_model_sha256") != baseline.model_sha256:
            raise InputError(
                f"{out}: the interrupted check compared with another baseline "
                f"({start.get('baseline_run', '?')}): resume with the same --baseline"
            )
        for key in ("false_alarm", "detect_mm", "power"):
            if not math.isclose(float(start.get(key, math.nan)), float(extra[key])):  # type: ignore[arg-type]
                raise InputError(
                    f"{out}: the interrupted check used {key.replace('_', '-')} "
                    f"{start.get(key)}: resume with the same error rates"
                )

    jpath = out / JOURNAL
    if resume and jpath.is_file():
        st0 = read_journal(jpath)
        if st0.ended and not (out / CHECK_FILE).is_file():  # killed after its end record
            same_check(st0)
            return _finish(out, plan, baseline, model, seq, st0, None)
    res = run_plan(
        station,
        plan,
        out,
        resume=resume,
        settings=run_settings,
        progress=progress,
        cancel=cancel,
        sequence=seq,
        start_extra=extra,
        check_resume=same_check,
    )
    result = _finish(out, plan, baseline, model, seq, read_journal(jpath), res)
    if res.stopped:
        raise HardwareError(
            f"check stopped after {res.n_measured} measured poses: {res.stopped} "
            f"(rerun with --resume to continue)"
        )
    return result


def _finish(
    out: Path,
    plan: Plan,
    baseline: Baseline,
    model: qc.ChangeModel,
    seq: CheckSequence,
    state: JournalState,
    run: RunResult | None,
) -> CheckResult:
    """check.json from the journal: the test on every measured pose, the robot time."""
    meas = seq.update(state)
    doc = check_document(plan, baseline, model, state, seq)
    if run is not None and run.stopped:
        doc["stopped"] = run.stopped
    write_text_atomic(out / CHECK_FILE, json.dumps(doc, indent=1) + "\n")
    if run is None:
        run = RunResult(out, len(plan.poses), 0 if meas is None else meas.n_poses, 0, None,
                        None, None, None, out / "measurements.csv")  # fmt: skip
    return CheckResult(out, seq.status, doc, run)


def check_document(
    plan: Plan,
    baseline: Baseline,
    model: qc.ChangeModel,
    state: JournalState,
    seq: CheckSequence,
) -> dict[str, Any]:
    """check.json's content (mm, mrad, s at the file boundary)."""
    status = seq.status
    order = list(state.captured)
    q_prev = seq.q_start
    move = 0.0
    dwell = []
    for i in order:
        c = state.captured[i]
        move += joint_move_s(plan, q_prev, c.q)
        q_prev = c.q
        dw = dwell_s(c.timing)
        if dw is not None:
            dwell.append(dw)
    back = 0.0
    if plan.home is not None and state.ended and order:
        back = joint_move_s(plan, q_prev, plan.home)
    med = float(np.median(dwell)) if dwell else float(plan.motion.settle_s)
    robot = move + back + float(np.sum(dwell)) + med * (len(order) - len(dwell))
    full = plan_loop_s(plan, med)
    measured_move = sum((state.captured[i].timing or {}).get("move", 0.0) for i in order)
    return {
        **decision_document(model, status, seq.decision, robot, full),
        "pose_names": [state.captured[i].name for i in order],
        "robot_time": {
            "moves_s": move,
            "return_home_s": back,
            "dwell_s": float(np.sum(dwell)),
            "dwell_median_s": med,
            "measured_moves_wall_s": measured_move,
            "note": "moves at the plan's joint speed and acceleration (real speed, also when "
            "the simulator runs faster); settling, pan and capture as measured",
        },
        "baseline": baseline_json(baseline, model),
        "plan_hash": plan.hash,
        "stop_reason": seq.stop_reason,
        "skipped_no_free_leg": sorted(set(seq.skipped)),
        "software": f"quickhealth {software_version()}",
        "started_utc": (state.start or {}).get("started_utc", ""),
        "run_id": (state.start or {}).get("run_id", ""),
    }


def decision_document(
    model: qc.ChangeModel,
    status: qc.CheckStatus | None,
    decided: tuple[qc.Decision, int] | None,
    robot_time_s: float,
    full_loop_s: float,
) -> dict[str, Any]:
    """The part of check.json every check shares, live or replayed: the verdict, the named
    changes, the error rates and the test (mm, mrad, s at the file boundary)."""
    s = model.settings
    decision = qc.Decision.CONTINUE if decided is None else decided[0]
    changes: list[dict[str, Any]] = []
    if status is not None and decision is qc.Decision.CHANGED:
        changes = [
            _change_json(c, n)
            for c, n in zip(status.changes(), status.named_changes(), strict=True)
        ]
        if status.omnibus_probability >= 0.05:
            changes.append(
                {
                    "joint": None,
                    "motion": "other",
                    "family": "omnibus",
                    "fault": None,
                    "words": "a change no single fault, joint motion or effect describes",
                    "size": None,
                    "sigma": None,
                    "size_unit": None,
                    "tcp_mm": None,
                    "probability": status.omnibus_probability,
                    "log_lr": status.log_lr_omnibus,
                    "action": "run a full assessment",
                }
            )
            changes.sort(key=lambda c: -c["probability"])
    return {
        "schema": CHECK_SCHEMA,
        "verdict": "changed" if decision is qc.Decision.CHANGED else "unchanged",
        "decided": decision is not qc.Decision.CONTINUE,
        "decided_after_poses": None if decided is None else decided[1],
        "poses": 0 if status is None else status.n_poses,
        "robot_time_s": robot_time_s,
        "full_loop_robot_time_s": full_loop_s,
        "fraction_of_full_loop": robot_time_s / full_loop_s if full_loop_s > 0 else math.nan,
        "changes": changes,
        "false_alarm": s.false_alarm,
        "power": s.power,
        "miss": 1.0 - s.power,
        "detect_mm": s.detect * 1e3,
        "design": DESIGN,
        "test": _test_json(status, model),
    }


def baseline_json(baseline: Baseline, model: qc.ChangeModel) -> dict[str, Any]:
    """check.json's ``baseline``."""
    return {
        "folder": str(baseline.folder),
        "run_id": baseline.run_id,
        "plan_hash": baseline.plan_hash,
        "model_sha256": baseline.model_sha256,
        "paired": model.paired,
    }


def summary_lines(d: dict[str, Any]) -> list[str]:
    """The lines every door shows of a check.json document."""
    lines = [
        f"{d['verdict'].upper()} after {d['poses']} poses: {d['robot_time_s']:.1f} s of "
        f"robot time, {100 * d['fraction_of_full_loop']:.0f} % of the full loop's "
        f"{d['full_loop_robot_time_s']:.1f} s"
        + ("" if d["decided"] else " (undecided at the end of the plan)")
    ]
    for c in d["changes"]:
        if c["size"] is None:
            lines.append(f"  {c['words']} ({100 * c['probability']:.0f} % of the evidence)")
            continue
        lines.append(
            f"  {c['words']}: changed by {c['size']:+.4g} ± {c['sigma']:.2g} {c['size_unit']} "
            f"(z = {c['z']:+.1f}; TCP up to {c['tcp_mm']:.3f} mm; "
            f"{100 * c['probability']:.0f} % of the evidence)"
        )
    if not d["decided"]:
        lines.append(
            f"  not decided: a change of {d['detect_mm']} mm is not excluded "
            f"({d['test']['weakest']} least measured); run a full assessment"
        )
    return lines


def _change_json(c: qc.Change, named: NamedChange) -> dict[str, Any]:
    """One change of check.json: the named fault (:meth:`~.faults.NamedChange.to_json`:
    ``fault``, words, size and σ in mm/mrad, z, p, the alternatives, the action) with the
    family's test figures."""
    return {
        **named.to_json(),
        "motion": c.motion,
        "family": c.family,
        "tcp_mm": c.tcp * 1e3,
        "log_lr": c.log_lr,
    }


def _test_json(status: qc.CheckStatus | None, model: qc.ChangeModel) -> dict[str, Any]:
    s = model.settings
    out: dict[str, Any] = {
        "log_lr_changed_boundary": s.log_a,
        "log_lr_unchanged_boundary": s.log_b,
        "families": len(model.families),
        "paired": model.paired,
        "noise_scale": model.noise_scale,
    }
    if status is None:
        return {**out, "log_lr": None, "log_sup_h1": None, "weakest": None}
    return {
        **out,
        "log_lr": status.log_lr,
        "log_lr_omnibus": status.log_lr_omnibus,
        "log_sup_h1": status.log_sup_h1,
        "weakest": status.weakest,
        "chi2": status.chi2,
        "dof": status.dof,
    }


__all__ = [
    "Baseline",
    "CheckOutcome",
    "CheckResult",
    "CheckSequence",
    "Progress",
    "archive_baseline",
    "baseline_json",
    "check_document",
    "decision_document",
    "load_baseline",
    "quick_check",
    "summary_lines",
]
