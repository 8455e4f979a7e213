"""The facade: the only thing the technician's App talks to.

It wraps the pieces the screens show and returns the small frozen records of
:mod:`quickhealth.station.tui.views`:

- devices and their state, pre-flight, run control (``station.station``, ``station.run``);
- the plan and its dry run (``station.planning``);
- results: BIC order selection and the ML fit (``identify.select``, ``identify.fit``), the
  workspace error and the joint curves with bands (``identify.workspace``, ``identify.trend``);
- diagnosis and the add-an-effect refit with held-out error before and after
  (``identify.diagnose``, ``identify.fit``);
- history: the archive and the trend (``station.archive``, ``identify.trend``).

Every method may block (motion, fits); the App calls them from thread workers.  Run control
(:meth:`pause`, :meth:`resume`, :meth:`abort`) is thread-safe and returns at once; ``abort``
stops the robot before anything else.  Plots that matter are written as PNG into the run
folder as well.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ...identify.errors import InputError
from ...identify.robot import RobotModel
from ..archive import Archive
from ..formats import format_measurements, load_robot, read_measurements
from ..hardware.legs import Leg
from ..planning import load_cell, load_plan
from ..planning.cell import Cell
from ..planning.planfile import Plan, plan_from_dict, plan_to_dict
from ..planning.planner import plan_loop
from ..reporting.verdict import Spec, ThresholdFigure, spec_of_meta
from ..run.settings import RunSettings
from ..services.checking import load_baseline, quick_check
from ..services.fitting import write_fit
from ..services.options import FitOptions
from ..station import HardwareConfig, real_station
from ..station import Station as Hardware
from . import jobs
from .analysis import Analysis
from .cell import CellControl
from .history import robot_history, shown_path
from .offload import offload, warm_up
from .views import (
    Check,
    Connection,
    Diagnosis,
    DryRun,
    Health,
    History,
    JointCoverage,
    PlanView,
    PoseStatus,
    Preflight,
    Refit,
    RunProgress,
)

# ------------------------------------------------------------------------------------------
# The station
# ------------------------------------------------------------------------------------------


class Facade:
    """Everything the technician's App can ask of the station (see the module docstring).

    Build it with :meth:`open` (the real cell), :func:`.simulated.open_simulated` /
    :func:`.simulated.in_process` (the built-in simulated cell) or :meth:`from_data` (an
    existing measurement file, e.g. to diagnose it).
    """

    def __init__(
        self,
        *,
        robot: RobotModel,
        robot_name: str,
        archive_root: Path | None,
        run_id: str,
        cell_name: str = "reference",
        spec: Spec | None = None,
        analysis: Analysis | None = None,
        sim: bool = True,
        hardware: Hardware | None = None,
        plan: Plan | None = None,
        plan_path: Path | None = None,
        run_settings: RunSettings | None = None,
        max_order: int = FitOptions.max_order,
        cell_spec: Cell | None = None,
    ) -> None:
        self.robot = robot
        self.cell_spec = cell_spec  # the cell's geometry (a quick check's collision checks)
        self.robot_name = robot_name
        self.archive = Archive.open(archive_root)  # None: every door's default (docs)
        self.run_id = run_id
        self.run_dir = self.archive.run_path(robot_name, run_id)
        self.cell_name = cell_name
        self.spec = spec  # the accuracy spec every verdict here judges against (None: none)
        self.sim = sim
        self.analysis = analysis
        if analysis is not None:
            analysis.out_dir = self.run_dir
        warm_up()
        self.max_order = max_order
        self.plan = plan
        self.plan_path = plan_path
        self.cell: CellControl | None = None
        # the simulated cell's handles (controller simulator, emulator) under --sim: set by
        # .simulated, which the real path never imports
        self.simcell: object | None = None
        if hardware is not None and plan is not None:
            self.cell = CellControl(
                hardware, plan, self.run_dir, settings=run_settings, on_finished=self._measured
            )
        self._lock = threading.RLock()
        self._health: Health | None = None
        if self.analysis is None and (self.run_dir / "measurements.csv").is_file():
            self._measured(self.run_dir / "measurements.csv")

    @classmethod
    def open(
        cls,
        *,
        cell: str = "reference",
        plan: Path | None = None,
        archive: Path | None = None,
        robot_name: str | None = None,
        robot_ip: str | None = None,
        motor_port: str | None = None,
        cameras: str | None = None,
        calibration: str | None = None,
        n_poses: int = 150,
        threshold_mm: float | None = None,
        run_id: str | None = None,
        say: Callable[[str], None] | None = None,
    ) -> Facade:
        """The facade for ``quickhealth tui`` on the real cell: UR robot, serial pan motor,
        the configured stereo pair (``quickhealth tui --sim``: :func:`~.simulated.open_simulated`).

        The hardware is the run's :class:`~quickhealth.station.station.Station`, assembled
        from the same :class:`~quickhealth.station.station.HardwareConfig` as ``run`` and
        ``check`` (``cameras``: ``--cameras`` as they take it).  ``say`` receives a line
        before each slow step (planning, connecting).  The robot is the cell's arm carrying
        the cell's smart target, named ``robot_name`` (default: the arm's name) in the
        archive."""
        tell = say or (lambda line: None)
        if not (robot_ip and motor_port and calibration):
            raise InputError("tui: a real station needs --robot-ip, --motor-port and --calibration")
        config = HardwareConfig.from_options(
            cell,
            robot_ip=robot_ip,
            motor_port=motor_port,
            cameras=cameras,
            calibration=calibration,
            robot_name=robot_name,
        )
        c, the_plan = cell_and_plan(cell, plan, n_poses, tell)
        tell(f"connecting to the robot at {robot_ip}…")
        hw = real_station(config)
        return cls(
            robot=c.robot_with_target(),
            robot_name=robot_name or c.robot.name,
            archive_root=archive,
            run_id=run_id or new_run_id(),
            cell_name=c.name,
            spec=spec_for(c, threshold_mm),
            sim=False,
            hardware=hw,
            plan=the_plan,
            plan_path=plan,
            cell_spec=c,
        )

    @classmethod
    def from_data(
        cls,
        measurements: str | Path,
        heldout: str | Path | None = None,
        *,
        robot: str = "ur5",
        robot_name: str = "ur5",
        archive_root: str | Path | None = None,
        run_id: str | None = None,
        threshold_mm: float | None = None,
        max_order: int = FitOptions.max_order,
    ) -> Facade:
        """A facade on an existing measurement file (CSV v1): results, diagnose, history."""
        model = load_robot(robot)
        meas = read_measurements(measurements, model.n_joints)
        held = None if heldout is None else read_measurements(heldout, model.n_joints)
        rid = run_id or meas.meta.get("run_id") or Path(measurements).resolve().parent.name
        return cls(
            robot=model,
            robot_name=robot_name,
            archive_root=None if archive_root is None else Path(archive_root),
            run_id=rid,
            cell_name=meas.meta.get("cell", "–"),
            spec=spec_for(None, threshold_mm, meas.meta),
            analysis=Analysis(model, meas, held, max_order=max_order, source=measurements),
            sim=False,
        )

    # ----- words for the screens -------------------------------------------------------------
    def title(self) -> str:
        """One line: robot, cell, simulated or real."""
        return f"{self.robot_name} · {self.cell_name} cell · {'simulated' if self.sim else 'real'}"

    def cell_line(self) -> str:
        """The Station screen's first lines: cell, run, spec, archive, plan (Rich markup)."""
        line = f"Robot [b]{self.robot_name}[/b] · cell [b]{self.cell_name}[/b] · run [b]{self.run_id}[/b]"
        line += f"\n{self.spec_words()}"
        line += f"\nArchive [b]{shown_path(self.archive.root)}[/b]"
        if self.plan is not None:
            where = self.plan_path.name if self.plan_path is not None else "planned now"
            line += (
                f"\nPlan [b]{where}[/b]: {len(self.plan.poses)} poses, "
                f"hash {self.plan.hash.removeprefix('sha256:')[:12]}"
            )
        return line

    # ----- devices ---------------------------------------------------------------------------
    def connect(self) -> tuple[Connection, ...]:
        """Connect (or reconnect) every device; their state afterwards."""
        if self.cell is not None:
            self.cell.connect()
        return self.connections()

    def connections(self) -> tuple[Connection, ...]:
        """Robot (mode and safety), stereo camera, pan motor, and whether each answers."""
        if self.cell is None:
            why = "no station: opened on a measurement file"
            return (
                Connection("robot", "down", why),
                Connection("stereo camera", "down", why),
                Connection("pan motor", "down", why),
            )
        return self.cell.connections()

    def preflight(self) -> Preflight:
        """Every check that must pass before the arm moves (none moves it)."""
        if self.cell is None:
            return Preflight(
                (Check("station", False, "opened on a measurement file: nothing to run"),)
            )
        return self.cell.preflight()

    # ----- plan ------------------------------------------------------------------------------
    def plan_view(self) -> PlanView:
        """The frozen plan as the planner summarised it, with per-joint coverage histograms."""
        plan = self.plan
        if plan is None:
            raise InputError("no plan: start with --plan PLAN.json, or with --sim to plan the cell")
        summ = plan.summary
        joints = summ.get("joints", {})
        bins = int(joints.get("bins", 12)) * 2
        lo = np.asarray(joints.get("usable_min_deg", np.degrees(plan.robot.q_min)), float)
        hi = np.asarray(joints.get("usable_max_deg", np.degrees(plan.robot.q_max)), float)
        cover = joints.get("coverage", [float("nan")] * len(lo))
        q = np.degrees(plan.q)
        coverage = tuple(
            JointCoverage(
                joint=f"j{j + 1}",
                counts=tuple(
                    int(c) for c in np.histogram(q[:, j], bins=bins, range=(lo[j], hi[j]))[0]
                ),
                lo_deg=float(lo[j]),
                hi_deg=float(hi[j]),
                covered=float(cover[j]),
            )
            for j in range(q.shape[1])
        )
        legs = summ.get("legs", {})
        dropped = {k: int(v) for k, v in summ.get("dropped", {}).items() if v}
        ev = joints.get("evenness")
        return PlanView(
            cell=plan.cell_name,
            path=str(self.plan_path or "(planned now)"),
            plan_hash=plan.hash.removeprefix("sha256:"),
            n_generated=int(summ.get("generated", len(plan.poses))),
            n_kept=len(plan.poses),
            dropped=dropped,
            n_linear=int(legs.get("linear", 0)),
            n_joint=int(legs.get("joint", 0)),
            coverage=coverage,
            evenness=None if ev is None else float(np.mean(ev)),
            loop_time_s=float(summ.get("loop_time_s", float("nan"))),
        )

    def dry_run(self) -> DryRun:
        """Drive the plan's legs on the simulated arm (no capture): does every move go through?

        Runs on a pure-Python simulated controller at 50× speed from the first pose, so the
        reported loop time is the simulated arm's, scaled back to real time.
        """
        from ..sim.fake_robot import FakeRobot  # the simulator's arm model (not the twin)

        plan = self.plan
        if plan is None:
            raise InputError("no plan to dry-run")
        scale = 50.0
        robot = FakeRobot(plan.poses[0].q, time_scale=scale, model=plan.robot)
        m = plan.motion
        problems: list[str] = []
        t0 = robot.now()
        for p in plan.poses[1:]:
            linear = p.leg == Leg.LINEAR
            try:
                robot.move(
                    p.q,
                    p.leg,
                    speed=m.linear_speed if linear else m.joint_speed,
                    accel=m.linear_accel if linear else m.joint_accel,
                )
            except Exception as exc:  # the dry run reports every refusal, it does not stop
                problems.append(f"{p.name}: {exc}")
        duration = robot.now() - t0 + len(plan.poses) * m.settle_s
        robot.close()
        return DryRun(not problems, len(plan.poses), duration, tuple(problems))

    # ----- results ---------------------------------------------------------------------------
    def has_measurements(self) -> bool:
        """True when there is data to fit."""
        return self.analysis is not None and self.analysis.meas.n_poses > 0

    def results_stale(self) -> bool:
        """True when the data or the effects changed since the last :meth:`results`."""
        h = self._health
        a = self.analysis
        return a is not None and (
            h is None or h.n_poses != a.meas.n_poses or h.effects != a.effects
        )

    def spec_words(self) -> str:
        """The accuracy spec the verdicts here judge against, in words."""
        if self.spec is None:
            return "Spec: none set (runs are judged against their baseline only)"
        return f"Spec: {self.spec.words()}"

    def results(self) -> Health:
        """Fit the run and write it as ``identify fit`` does (model.json, report.json,
        residuals.csv), archive it, report it as ``quickhealth report`` does (the report's
        sections and verdict in report.json) and summarise it with that verdict."""
        with self._lock:  # one fit, archive and report at a time: a second call waits, then
            return self._results()  # finds this one's summary

    def _results(self) -> Health:
        if self.analysis is None:
            raise InputError("no measurements yet: run the plan first")
        if self._health is not None and not self.results_stale():
            return self._health
        a = self.analysis.assessment()
        d = self.run_dir
        extra = {}
        if not (d / "measurements.csv").exists():  # the data as measured, not re-rounded
            src = self.analysis.source
            extra["measurements.csv"] = (
                Path(src).read_text(encoding="utf-8")
                if src is not None and Path(src).is_file()
                else format_measurements(a.measurements)
            )
        write_fit(d, a, source=self.analysis.source, extra=extra)
        self.archive.add_run(self.robot_name, d, run_id=self.run_id)
        judgement = offload(  # the report writes the verdict and the index's healthy flag
            jobs.report_job,
            str(d),
            str(self.archive.root),
            self.archive.url,
            self.robot_name,
            self.run_id,
            self.spec,
        )
        h = self.analysis.health(
            run_id=self.run_id, robot_name=self.robot_name, judgement=judgement
        )
        pngs = offload(
            jobs.results_pngs_job,
            h.hist_counts,
            h.hist_edges_mm,
            h.spec_mm,
            h.curves,
            str(d),
        )
        h = replace(h, pngs=pngs)
        self._health = h
        return h

    def diagnose(self) -> Diagnosis:
        """Measured versus model per pose and the ranked candidate effects."""
        if self.analysis is None:
            raise InputError("no measurements yet: run the plan first")
        return self.analysis.diagnose()

    def add_effect(
        self, effect: str, on_step: Callable[[int, int, str], None] | None = None
    ) -> Refit:
        """Add ``effect`` to the model; held-out error before and after."""
        if self.analysis is None:
            raise InputError("no measurements yet: run the plan first")
        return self.analysis.add_effect(effect, on_step)

    # ----- quick check -----------------------------------------------------------------------
    def quick_check(self, on_step: Callable[[int, int, str], None] | None = None) -> list[str]:
        """The quick check of this robot against its archived baseline (the arm moves): the
        check's summary lines; recorded in the archive as a check, not as a run
        (:func:`~quickhealth.station.services.checking.quick_check`).  ``on_step(done, total,
        line)``: the check's own poses measured so far of the most it may take (the plan's)."""
        if self.cell is None or self.plan is None or self.cell_spec is None:
            raise InputError("no station attached: start with --sim or --robot-ip")
        try:
            rec = self.archive.baseline(self.robot_name)
        except InputError:
            rec = None
        if rec is None:
            raise InputError(
                f"robot {self.robot_name} has no baseline run in the archive "
                f"{self.archive.root}: run the full loop (3, r), fit it (4), then check; "
                "or set one with b on History (6)"
            )
        baseline = load_baseline(self.archive.folder(rec))
        check_id = f"check-{new_run_id()}"
        out = self.archive.check_path(self.robot_name, check_id)
        step = on_step or (lambda done, total, line: None)
        total = len(self.plan.poses)
        measured = [0]

        def progress(p: object) -> None:
            kind = getattr(p, "kind", "")
            if kind == "measured" and getattr(p, "status", "") == "measured":
                measured[0] += 1
            if kind in ("pose", "measured", "stop", "done"):
                what = " ".join(x for x in (getattr(p, "name", ""), getattr(p, "status", "")) if x)
                step(measured[0], total, f"{kind}: {what}")

        def say(line: str) -> None:
            step(measured[0], total, line)

        def work(hw: Hardware, cancel: threading.Event) -> object:
            return quick_check(
                hw, self.plan, self.cell_spec, baseline, out, run_settings=self.cell.settings,
                progress=progress, cancel=cancel, say=say,
            )  # fmt: skip

        step(0, total, f"quick check against the baseline {rec.run_id}")
        res = self.cell.exclusive(work)
        self.archive.add_check(self.robot_name, out, check_id=check_id)
        return res.summary()  # type: ignore[attr-defined, no-any-return]

    # ----- baseline and history --------------------------------------------------------------
    def set_baseline(self, run_id: str | None = None) -> str:
        """Make ``run_id`` (default: this run) the robot's baseline in the archive; one line."""
        rid = run_id or self.run_id
        self.archive.set_baseline(self.robot_name, rid)  # the run must be archived
        return f"baseline of {self.robot_name}: run {rid} (later runs and checks compare with it)"

    def history(self) -> History:
        """This robot's archived runs and quick checks with their verdicts, the latest run's
        verdict lines and the trend (:func:`.history.robot_history`)."""
        return robot_history(self.archive, self.robot_name, self.spec, self.run_dir / "trend.png")

    # ----- run -------------------------------------------------------------------------------
    @property
    def can_run(self) -> bool:
        """True when a cell is attached (not just a measurement file)."""
        return self.cell is not None

    @property
    def running(self) -> bool:
        """True while a run is moving the arm (or paused between poses)."""
        return self.cell is not None and self.cell.running

    @property
    def paused(self) -> bool:
        """True when the run waits between poses."""
        return self.cell is not None and self.cell.paused

    def pose_table(self) -> tuple[PoseStatus, ...]:
        """Every pose of the plan (or of the measured data) with its status so far."""
        if self.cell is not None:
            return self.cell.pose_table()
        if self.analysis is not None:
            ids = self.analysis.meas.pose_id or tuple(
                f"p{i:04d}" for i in range(self.analysis.meas.n_poses)
            )
            q = np.degrees(self.analysis.meas.q)
            return tuple(
                PoseStatus(i, pid, "done", tuple(float(v) for v in q[i]))
                for i, pid in enumerate(ids)
            )
        return ()

    def run(self, on_progress: Callable[[RunProgress], None]) -> RunProgress:
        """Run (or continue) the plan; blocks until it finishes, is aborted or faults."""
        if self.cell is None:
            raise InputError("no station to run: opened on a measurement file")
        return self.cell.run(on_progress)

    def pause(self) -> None:
        """Stop after the current pose and wait for :meth:`resume`."""
        if self.cell is not None:
            self.cell.pause()

    def resume(self) -> None:
        """Continue a paused run."""
        if self.cell is not None:
            self.cell.resume()

    def abort(self) -> None:
        """Stop the robot first, then end the run after the current pose (journal kept)."""
        if self.cell is not None:
            self.cell.abort()

    def reconnect(self) -> None:
        """After a fault: reconnect and check the robot is ready again (raises if not)."""
        if self.cell is None:
            raise InputError("no station to reconnect")
        self.cell.reconnect()

    def _measured(self, path: Path) -> None:
        """A run wrote measurements.csv: it becomes the data the results and diagnosis use."""
        meas = read_measurements(path, self.robot.n_joints)
        if self.analysis is None or self.analysis.meas.n_poses != meas.n_poses:
            self.analysis = Analysis(self.robot, meas, max_order=self.max_order, source=path)
            self.analysis.out_dir = self.run_dir

    def n_remaining(self) -> int:
        """Poses of the plan not measured yet."""
        return sum(p.status not in ("done", "failed") for p in self.pose_table())

    def shutdown(self) -> None:
        """Stop the robot if a run is going and close the devices (the App is quitting)."""
        if self.cell is not None:
            self.cell.close()


# ------------------------------------------------------------------------------------------
# Building a cell
# ------------------------------------------------------------------------------------------


def make_plan(cell: Cell, n_candidates: int, seed: int = 0) -> Plan:
    """Plan the cell now (the planner's steps 1–5) and validate it as a frozen plan file would be."""
    res = plan_loop(cell, n_candidates, seed)
    if not res.poses:
        raise InputError(f"planning {cell.name} with {n_candidates} candidates kept no pose")
    return plan_from_dict(plan_to_dict(res), f"plan of {cell.name} (n={n_candidates}, seed={seed})")


def cell_and_plan(
    cell: str, plan: Path | None, n_poses: int, tell: Callable[[str], None]
) -> tuple[Cell, Plan]:
    """The cell (file or built-in name) and its plan: ``plan`` if given, else planned now."""
    c = load_cell(cell)
    if plan is None:
        tell(f"planning cell {c.name}: {n_poses} candidate targets…")
    return c, (load_plan(plan) if plan is not None else make_plan(c, n_poses, 0))


def new_run_id() -> str:
    """A run id from the time now (UTC): ``2026-11-01-020000``."""
    return datetime.now(UTC).strftime("%Y-%m-%d-%H%M%S")


def spec_for(
    cell: Cell | None, threshold_mm: float | None, meta: dict[str, str] | None = None
) -> Spec | None:
    """The accuracy spec of a TUI session: ``--threshold-mm`` if given, else the cell's
    ``spec_mm`` (a measurement file's: the one its run recorded), else none."""
    if threshold_mm is not None:
        return Spec(float(threshold_mm), ThresholdFigure.MAX, "--threshold-mm")
    if cell is not None and cell.spec_mm is not None:
        return Spec(cell.spec_mm, ThresholdFigure.MAX, f"cell {cell.name}")
    return spec_of_meta(meta or {})
