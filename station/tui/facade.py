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
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ...identify.assess import Assessment
from ...identify.diagnose import Diagnosis as Diagnosed
from ...identify.errormodel import MOTION_WORDS, MOTIONS
from ...identify.errors import InputError
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.robot import RobotModel
from ...identify.trend import assess_trend
from ..archive import Archive, check_lines, run_state
from ..formats import format_measurements, load_robot, read_measurements, read_report
from ..hardware.legs import Leg
from ..planning import load_cell, load_plan
from ..planning.cell import Cell
from ..planning.planfile import Plan, plan_from_dict, plan_to_dict
from ..planning.planner import plan_loop
from ..reporting.verdict import Judgement, Spec, ThresholdFigure, recorded_verdict, spec_of_meta
from ..run.settings import RunSettings
from ..services.checking import load_baseline, quick_check
from ..services.fitting import write_fit
from ..services.options import FitOptions
from ..station import HardwareConfig, real_station
from ..station import Station as Hardware
from . import jobs
from .cell import CellControl
from .offload import offload, warm_up
from .views import (
    Candidate,
    Check,
    Connection,
    Diagnosis,
    DryRun,
    Health,
    History,
    HistoryRow,
    JointCoverage,
    JointCurve,
    PlanView,
    PoseResidual,
    PoseStatus,
    Preflight,
    Refit,
    RunProgress,
)

MOTION_UNITS = {"dx": "mm", "dy": "mm", "dz": "mm", "ex": "mrad", "ey": "mrad", "ez": "mrad"}


@dataclass
class _Model:
    """The current assessment of the current data (mutable session state, not a result)."""

    assessment: Assessment
    effects: tuple[str, ...]
    n_poses: int


def _slug(name: str) -> str:
    return name.replace(":", "_")


class Analysis:
    """Fit, results, diagnosis and refit of one data set (a run's measurements).

    ``heldout`` is data of the same robot and set-up the fit never sees (e.g. a second
    measurement file); without it the before/after comparison cross-validates the run.
    ``out_dir``, when set, receives the PNG figures.  ``source`` is the measurement file (the
    report's ``input``).  The fit's options are every door's (:class:`FitOptions`) but for
    ``max_order`` and the effects added here.
    """

    def __init__(
        self,
        robot: RobotModel,
        meas: Measurements,
        heldout: Measurements | None = None,
        *,
        max_order: int = FitOptions.max_order,
        effects: tuple[str, ...] = (),
        source: str | Path | None = None,
    ) -> None:
        self.robot = robot
        self.meas = meas
        self.heldout = heldout
        self.max_order = max_order
        self.effects = tuple(effects)
        self.source = None if source is None else str(source)
        self._lock = threading.Lock()
        self._model: _Model | None = None
        self._diag: tuple[tuple[int, int], Diagnosed] | None = None
        self.out_dir: Path | None = None

    @property
    def options(self) -> FitOptions:
        """The options of the current fit."""
        return FitOptions(effects=self.effects, max_order=self.max_order)

    # ----- fitting ---------------------------------------------------------------------------
    def assess(self, effects: tuple[str, ...] | None = None) -> Assessment:
        """The assessment (BIC order selection, ML fit, workspace, curves) with ``effects``
        (default: the current ones), as ``identify fit`` runs it
        (:func:`~quickhealth.station.services.fitting.assess`)."""
        opts = self.options if effects is None else replace(self.options, effects=effects)
        return offload(jobs.assess_job, self.robot, self.meas, opts)

    def assessment(self) -> Assessment:
        """The current assessment of all the data (once, again when effects or data change)."""
        with self._lock:
            m = self._model
            if m is None or m.effects != self.effects or m.n_poses != self.meas.n_poses:
                m = _Model(self.assess(), self.effects, self.meas.n_poses)
                self._model = m
            return m.assessment

    def model(self) -> FittedModel:
        """The current model of all the data (the assessment's fitted model)."""
        return self.assessment().fitted

    # ----- screens ---------------------------------------------------------------------------
    def health(self, *, run_id: str, robot_name: str, judgement: Judgement) -> Health:
        """The health summary of the current model, with the verdict of its report."""
        a = self.assessment()
        fitted, ws = a.fitted, a.workspace
        worst = offload(jobs.regions_job, fitted)
        curves = []
        for jc in a.curves:
            for m, motion in enumerate(MOTIONS):
                if not np.any(jc.values[m]) and not np.any(jc.half_width[m]):
                    continue  # not in the model
                curves.append(
                    JointCurve(
                        joint=f"j{jc.joint}",
                        motion=motion,
                        words=MOTION_WORDS[motion],
                        unit=MOTION_UNITS[motion],
                        q_deg=np.degrees(jc.theta),
                        value=jc.values[m] * 1e3,
                        band=jc.half_width[m] * 1e3,
                    )
                )
        base = judgement.baseline
        return Health(
            run_id=run_id,
            robot=robot_name,
            mean_mm=ws.mean * 1e3,
            std_mm=ws.std * 1e3,
            max_mm=ws.max * 1e3,
            spec_mm=None if judgement.spec is None else judgement.spec.mm,
            spec_figure=ThresholdFigure.MAX if judgement.spec is None else judgement.spec.figure,
            verdict=judgement.verdict,
            reason=judgement.reason,
            verdict_lines=judgement.lines(),
            baseline_mean_mm=None if base is None or judgement.this_is_baseline else base.mean_mm,
            hist_counts=tuple(int(c) for c in ws.hist_counts),
            hist_edges_mm=tuple(float(e) * 1e3 for e in ws.hist_edges),
            curves=tuple(curves),
            worst=worst,
            rms_pos_mm=float(fitted.rms_pos * 1e3),
            n_poses=self.meas.n_poses,
            effects=tuple(e.name for e in fitted.effects),
        )

    def diagnose(self) -> Diagnosis:
        """Residuals per pose and the ranked candidate effects of the current model."""
        fitted = self.model()
        key = (id(fitted), self.meas.n_poses)
        if self._diag is None or self._diag[0] != key:
            self._diag = (key, offload(jobs.diagnose_job, fitted, self.meas))
        diag = self._diag[1]
        # measured and model positions in the robot base frame (the registered base), mm
        T_ib = fitted.registration[0]
        res = fitted.residual_pos @ T_ib[:3, :3] * 1e3  # measured − model
        pos = (self.meas.pos - T_ib[:3, 3]) @ T_ib[:3, :3] * 1e3
        ids = self.meas.pose_id or tuple(f"p{i:04d}" for i in range(self.meas.n_poses))
        residuals = tuple(
            PoseResidual(
                pose_id=ids[i],
                measured_mm=tuple(float(v) for v in pos[i]),  # type: ignore[arg-type]
                model_mm=tuple(float(v) for v in pos[i] - res[i]),  # type: ignore[arg-type]
                err_mm=float(np.linalg.norm(res[i])),
            )
            for i in range(self.meas.n_poses)
        )
        cands = tuple(
            Candidate(c.effect, float(c.score), float(c.predicted_rms_drop_mm), c.evidence)
            for c in diag.candidates[:12]
            if c.significant or len(diag.candidates) <= 12
        )
        return Diagnosis(str(diag.verdict.value), self.effects, residuals, cands)

    def add_effect(
        self, effect: str, on_step: Callable[[int, int, str], None] | None = None
    ) -> Refit:
        """Fit without and with ``effect``; held-out (or cross-validated) error before and after.

        The effect then stays in the model, so the next diagnosis looks for what is still
        missing.  ``on_step(done, total, what)`` reports each fit.
        """
        step = on_step or (lambda done, total, what: None)
        folds = 5
        total = 2 if self.heldout is not None else 2 + 2 * folds
        done = [0]

        def progress(line: str) -> None:
            done[0] = min(done[0] + 1, total)
            step(done[0], total, line)

        step(0, total, f"fitting with {effect}…")
        png = None if self.out_dir is None else str(self.out_dir / f"refit_{_slug(effect)}.png")
        cmp = offload(
            jobs.compare_job,
            self.model(),
            self.meas,
            effect,
            self.heldout,
            folds,
            png,
            progress=progress,
        )
        after = offload(jobs.evaluate_job, cmp.fitted_after, self.meas)
        with self._lock:
            self.effects = tuple(e.name for e in cmp.fitted_after.effects)
            self._model = _Model(after, self.effects, self.meas.n_poses)
        step(total, total, "done")
        b, a = cmp.before, cmp.after
        return Refit(
            effects_before=self.effects[: -len(cmp.effects)],
            effects_after=self.effects,
            before_mm=b.pos_mm,
            after_mm=a.pos_mm,
            before_axes_mm=(b.x_mm, b.y_mm, b.z_mm),
            after_axes_mm=(a.x_mm, a.y_mm, a.z_mm),
            heldout=f"{cmp.method}, {cmp.n_eval} poses",
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
        """This robot's archived runs and quick checks, oldest first, each with the verdict its
        report (a check: its own) gave; the latest run's verdict lines; the trend's words."""
        root = shown_path(self.archive.root)
        try:
            recs = self.archive.runs(self.robot_name)
        except InputError:
            return History(self.robot_name, (), "no runs archived yet", archive=root)
        rows = []
        latest: tuple[str, ...] = ()
        for r in recs:
            doc = _report_json(self.archive.folder(r))
            got = recorded_verdict(doc)
            verdict, reason = (got[0].value, got[1]) if got else ("not judged", "no report yet")
            section = doc.get("verdict") if isinstance(doc.get("verdict"), dict) else {}
            latest = tuple(str(x) for x in section.get("lines", ())) or (
                f"{verdict.upper()}: {reason}",
            )
            rows.append(
                HistoryRow(
                    run_id=r.run_id,
                    when=r.time_utc[:16].replace("T", " "),
                    mean_mm=r.mean_mm,
                    std_mm=r.std_mm,
                    max_mm=r.max_mm,
                    verdict=verdict,
                    baseline=r.baseline,
                    reason=reason,
                )
            )
        checks = self.archive.checks(self.robot_name)
        for c in checks:
            rows.append(
                HistoryRow(
                    run_id=c.check_id,
                    when=c.time_utc[:16].replace("T", " "),
                    mean_mm=float("nan"),
                    std_mm=float("nan"),
                    max_mm=float("nan"),
                    verdict=c.verdict,
                    kind="check",
                    reason=f"{c.poses} poses vs baseline {c.baseline_run_id}"
                    + (f": {c.changes}" if c.changes else ""),
                )
            )
        rows.sort(key=lambda x: x.when)
        base = next((i for i, r in enumerate(recs) if r.baseline), 0)
        spec = self.spec
        result = assess_trend(
            [run_state(self.archive, r) for r in recs],
            base,
            threshold_mm=None if spec is None else spec.mm,
            threshold_figure=ThresholdFigure.MAX.value if spec is None else spec.figure.value,
        )
        prog = result.prognoses.get(ThresholdFigure.MAX.value if spec is None else spec.figure)
        words = "; ".join(result.change_flags()[:2]) or "no change since the baseline"
        if prog is not None and len(recs) > 2:
            words += "; " + prog.words()
        runs = tuple(x for x in rows if x.kind == "run")
        png = offload(
            jobs.trend_png_job,
            runs,
            None if spec is None else spec.mm,
            str(self.run_dir / "trend.png"),
        )
        return History(
            self.robot_name,
            tuple(rows),
            words,
            flagged=bool(latest) and latest[0].startswith("FLAGGED"),
            pngs=(png,),
            checks=tuple(check_lines(checks)),
            latest=latest,
            archive=root,
        )

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


def shown_path(p: Path) -> str:
    """A folder as the screens show it: relative to the working folder when inside it, from
    ``~`` when inside the home folder, else absolute."""
    for base, prefix in ((Path.cwd(), "./"), (Path.home(), "~/")):
        try:
            return prefix + str(p.relative_to(base))
        except ValueError:
            continue
    return str(p)


def _report_json(folder: Path) -> dict[str, object]:
    """A run folder's report.json as a dict ({} when absent or unreadable)."""
    try:
        doc = read_report(folder / "report.json")
    except (InputError, OSError):
        return {}
    return doc if isinstance(doc, dict) else {}
