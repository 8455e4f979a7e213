"""Run a plan on the cell: the per-pose loop, pre-flight, self-check, crash-safe journal.

Stages of :func:`run_plan`, in order:

1. **Pre-flight** (:func:`preflight`), no motion before all pass: robot connected, powered,
   safety normal; plan made for this cell and robot; cameras capture images of the
   calibrated size; pan motor answers; disk space for the remaining poses.
2. **Self-check**: the fixed reference marker board is measured (start, and end of the run);
   the drift between the two is the instrument's, not the robot's, and is reported apart.
3. **Poses**, in plan order.  Per pose: move (joint or linear leg); wait until the joint
   stream shows the arm at rest (:func:`wait_settled`, not a fixed sleep); turn the target to
   face the cameras; capture; quick detection check in the predicted image region (retry,
   else record the pose as failed with the reason); write both images atomically; journal
   the capture (fsync).  The full 7D measurement runs in a worker thread while the robot
   moves on, and is journalled when done.
4. **Finish**: measurements.csv (CSV v1, execution order) and run.json from the journal.

A protective stop, a lost connection, a frozen stream or a motor failure stops the run
cleanly: the arm is stopped, every captured pose is kept (and measured), the journal says
why, and the error says what to do.  ``resume=True`` continues: captured but unmeasured poses
are measured from their images, the arm re-approaches the last completed pose (so every
joint approaches the next pose from the same side as in an uninterrupted run), and the loop
goes on from the first pose with no record.  No pose is lost or repeated.

The package by job: :mod:`.preflight`, :mod:`.settle`, :mod:`.capture` (quick check and 7D
measurement of a pair), :mod:`.runner` (one pose, the measurement worker, the self-check),
:mod:`.sequence` (which pose next), :mod:`.journal` (crash-safe records), :mod:`.outputs`
(measurements.csv, run.json), :mod:`.lock` (one run drives the cell; one writer per output).

SYNOPSIS
    >>> station = real_station(HardwareConfig.from_options(cell, robot_ip=ip, ...))  # doctest: +SKIP
    >>> result = run_plan(station, plan, Path("runs/n1"), progress=print)  # doctest: +SKIP
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...identify.errors import HardwareError, InputError
from ..formats.journal import RecordKind
from ..fsio import remove_stale_temp_files
from ..hardware.robot import Leg
from ..provenance import software_version
from ..station import Station
from .exposure import recorded_exposure, wants_search
from .journal import JOURNAL, SCHEMA, JournalState, read_journal
from .outputs import selfcheck_drift, write_calibration, write_outputs
from .preflight import preflight
from .progress import ProgressFn, ProgressKind
from .runner import PoseRunner, plan_speed
from .sequence import PlanOrder, PoseSequence
from .settings import RunSettings

if TYPE_CHECKING:  # types only: the planner loads the collision library, a run needs none of it
    from ..planning.planfile import Plan


@dataclass(frozen=True)
class RunResult:
    """Outcome of :func:`run_plan`."""

    run_dir: Path
    n_poses: int
    n_measured: int
    n_failed: int
    stopped: str | None  # the reason when the run stopped early
    selfcheck_drift_mm: float | None
    selfcheck_drift_deg: float | None
    selfcheck_ok: bool | None
    measurements: Path | None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Every pose has a record."""
        return self.stopped is None


def run_plan(
    station: Station,
    plan: Plan,
    run_dir: Path | str,
    *,
    resume: bool = False,
    settings: RunSettings = RunSettings(),
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    sequence: PoseSequence | None = None,
    start_extra: dict[str, object] | None = None,
    check_resume: Callable[[JournalState], None] | None = None,
) -> RunResult:
    """Execute ``plan`` on ``station`` into ``run_dir`` (see the module docstring).

    Parameters
    ----------
    station : Station
    plan : Plan
        From ``quickhealth.station.planning.load_plan``.
    run_dir : path
        The run folder (created; must not hold a journal unless ``resume``).
    resume : bool
        Continue the interrupted run in ``run_dir``.
    progress : callable, optional
        Called with a :class:`Progress` for every step (from the run's threads).
    cancel : threading.Event, optional
        Set it to stop after the current pose (the run can be resumed).
    sequence : PoseSequence, optional
        Which pose comes next (default :class:`PlanOrder`: the plan's loop).
    start_extra : dict, optional
        More keys for the journal's start record (e.g. what kind of run it is).
    check_resume : callable, optional
        Called with the interrupted run's journal before resuming; raises InputError when
        the folder holds another kind of run.

    Returns
    -------
    RunResult
        Also when the run stopped on a hardware fault (``stopped`` says why); the same
        message is then raised as HardwareError by the command line.

    Raises
    ------
    InputError
        The run folder does not fit (existing run without ``resume``, another plan …).
    HardwareError
        Pre-flight failed (nothing moved).
    """
    run_dir = Path(run_dir)
    jpath = run_dir / JOURNAL
    state = _open_run_folder(run_dir, plan, resume, check_resume)
    (run_dir / "images").mkdir(exist_ok=True)
    write_calibration(station, run_dir)
    if resume:  # half-written files of the killed run (its images are captured again)
        for folder in (run_dir, run_dir / "images"):
            remove_stale_temp_files(folder)
    r = PoseRunner(station, plan, run_dir, settings, progress, cancel)
    if resume and wants_search(station):  # the exposure stays the one the run found
        r.exposure_search = recorded_exposure(station, state.captured)
        r.exposure_logged = r.exposure_search is not None
    # A capture counts once its images are on disk (they are written after the record).
    imaged = {
        i for i, rec in state.captured.items() if all((run_dir / p).is_file() for p in rec.images)
    }
    done = imaged | set(state.failed)
    unmeasured = sorted(i for i in imaged if i not in state.measured)
    todo = [p for p in plan.poses if p.index not in done]
    seq: PoseSequence = sequence if sequence is not None else PlanOrder(plan, done)
    lines = preflight(station, plan, run_dir, len(todo), settings, resume=resume)
    for ln in lines:
        r.emit(ProgressKind.PREFLIGHT, status="ok", message=ln)
    r.journal.open(truncate_to=state.valid_bytes if state.truncated_tail else None)
    station.robot.clear_stop()  # starting (or resuming) is the operator's go: moves allowed
    stopped: str | None = None
    try:
        if resume:
            r.t_epoch = float(state.start["epoch"])
            r.append({"type": RecordKind.RESUME, "at_utc": _utc(), "done": len(done),
                      "truncated_tail": state.truncated_tail,
                      "cameras": [c.to_json() for c in station.camera_ids]})  # fmt: skip
            r.emit(ProgressKind.RESUME, message=f"{len(done)} of {r.n} poses done; "
                   f"{len(unmeasured)} to measure from images")  # fmt: skip
            r.remeasure(state, unmeasured)
        else:
            r.append(_start_record(station, plan, run_dir, r, start_extra))
        r.selfcheck("start" if not resume else "resume")
        if resume and todo:
            last = seq.resume_pose(read_journal(jpath))
            if last is not None:  # re-approach the last completed pose: same approach directions
                station.robot.move(last.q, Leg.JOINT, **plan_speed(plan, Leg.JOINT))
        stopped = _visit(r, seq, state, jpath)
    except HardwareError as exc:
        stopped = str(exc)
        try:
            station.robot.stop()
        except HardwareError as stop_exc:  # not confirmed: the arm may still be moving
            stopped = f"{stopped}; {stop_exc}"
    return _finish(r, seq, stopped)


def _open_run_folder(
    run_dir: Path,
    plan: Plan,
    resume: bool,
    check_resume: Callable[[JournalState], None] | None,
) -> JournalState:
    """The journal's state of the run folder: empty for a new run (the folder made), the
    interrupted run's for ``resume`` (refused when there is none, it is complete, or it ran
    another plan)."""
    jpath = run_dir / JOURNAL
    if not resume:
        if jpath.exists():
            raise InputError(
                f"{run_dir}: already holds a run; add --resume to continue it or choose a new folder"
            )
        run_dir.mkdir(parents=True, exist_ok=True)
        return JournalState()
    if not jpath.is_file():
        raise InputError(f"{run_dir}: no interrupted run to resume (no {JOURNAL})")
    state = read_journal(jpath)
    if state.start is None:
        raise InputError(f"{jpath}: empty journal")
    if state.ended:
        raise InputError(f"{run_dir}: this run is already complete; nothing to resume")
    if state.start.get("plan_hash") != plan.hash:
        raise InputError(
            f"{jpath}: the interrupted run used plan {state.start.get('plan_hash', '?')[:19]}…, "
            f"not {plan.hash[:19]}…: resume with the same plan.json"
        )
    if check_resume is not None:
        check_resume(state)
    return state


def _start_record(
    station: Station,
    plan: Plan,
    run_dir: Path,
    r: PoseRunner,
    extra: dict[str, object] | None,
) -> dict[str, object]:
    """The journal's ``start`` record of a new run."""
    return {
        "type": RecordKind.START, "schema": SCHEMA, "run_id": run_dir.name, "plan_hash": plan.hash,
        "plan_source": str(plan.source), "cell": station.cell_name, "cell_sha256": station.cell_sha256,
        "robot": station.robot_name or station.robot.model.name, "n_poses": r.n,
        "started_utc": _utc(), "epoch": r.t_epoch, "software": f"quickhealth {software_version()}",
        "instrument": station.instrument,
        "cameras": [c.to_json() for c in station.camera_ids],
        # the cell's accuracy spec travels with the run (run.json, measurements.csv)
        **({} if station.spec_mm is None else {"spec_mm": station.spec_mm}),
        **(extra or {}),
    }  # fmt: skip


def _visit(r: PoseRunner, seq: PoseSequence, state: JournalState, jpath: Path) -> str | None:
    """Every pose ``seq`` gives, then the move home; the reason when the operator stopped it."""
    while True:
        if r.cancel.is_set():
            return "cancelled by the operator; rerun with --resume to continue"
        if seq.wait_for_measurements:
            r.drain()
        pose = seq.next_pose(read_journal(jpath) if seq.wait_for_measurements else state)
        if pose is None:
            break
        r.do_pose(pose)
        if r.worker_error is not None:
            r.drain()
    end = seq.finish(read_journal(jpath))
    if end is not None:  # close the loop: back to the start
        target, leg = end
        r.emit(ProgressKind.MOVE, message="return to home")
        r.s.robot.move(target, leg, **plan_speed(r.plan, leg))
    return None


def _finish(r: PoseRunner, seq: PoseSequence, stopped: str | None) -> RunResult:
    """Wait for the measurements, the end self-check, the last record, the outputs."""
    try:
        r.drain()
    finally:
        r.pool.shutdown(wait=True)
    jpath, settings = r.dir / JOURNAL, r.cfg
    drift = None
    if stopped is None:
        r.selfcheck("end")
        drift = selfcheck_drift(read_journal(jpath).selfchecks)
        r.append({"type": RecordKind.END, "at_utc": _utc()})
    else:
        r.append({"type": RecordKind.STOP, "reason": stopped, "at_utc": _utc()})
        r.emit(ProgressKind.STOP, message=stopped)
    r.journal.close()
    final = read_journal(jpath)
    meas_path = write_outputs(r.dir, final, r.plan, r.s, drift, settings, order=seq.order)
    res = RunResult(
        run_dir=r.dir,
        n_poses=r.n,
        n_measured=sum(1 for m in final.measured.values() if m.ok),
        n_failed=len(final.failed) + sum(1 for m in final.measured.values() if not m.ok),
        stopped=stopped,
        selfcheck_drift_mm=None if drift is None else drift[0],
        selfcheck_drift_deg=None if drift is None else drift[1],
        selfcheck_ok=None
        if drift is None
        else bool(
            drift[0] <= settings.selfcheck_limit_mm and drift[1] <= settings.selfcheck_limit_deg
        ),
        measurements=meas_path,
        timings={k: float(np.mean(v)) for k, v in r.timings.items()},
    )
    r.emit(ProgressKind.DONE, status="stopped" if stopped else "complete",
           message=f"{res.n_measured} measured, {res.n_failed} failed of {res.n_poses}")  # fmt: skip
    return res


def _utc() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
