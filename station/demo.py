"""The whole loop on the built-in simulated cell, the way a new user meets the product.

Stages (each the application-layer function the command a user runs by hand calls, so the
demo goes the real code path; the equivalent commands are printed as it goes and each step's
lines are kept in ``demo.log``):

1. **plan**      ``quickhealth plan --cell CELL``: the fixed loop for the cell (``reference``,
                 the paper's UR5 cell, unless ``--cell`` names another)
2. **run**       ``quickhealth run --sim``: UR controller simulator driven by the real ur-rtde
                 client, emulated pan motor on a pseudo-terminal, rendered stereo images,
                 7D measurements, crash-safe journal
3. **fit**       ``quickhealth identify fit``: implicit-loop ML fit with BIC order selection
4. **diagnose**  ``quickhealth diagnose``: is a physical effect missing?
5. **archive**   ``quickhealth archive add`` and ``quickhealth trend``: the run against the
                 robot's baseline
6. **report**    ``quickhealth report``: one self-contained HTML page per run, its verdict

Three runs of the same robot on the same frozen plan: the baseline, a healthy repeat a week
later (new camera noise, nothing changed) and a run "a month later" in which one error
motion of one joint has grown (wear).  The trend must flag only the last, naming the joint
and the motion.
"""

from __future__ import annotations

import io
import shutil
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from ..identify.effects import is_effect_name, parse_effect
from ..identify.errors import HardwareError, InputError, QuickhealthError
from ..identify.faults import effect_fault, geometric_faults
from .archive import Archive
from .formats import load_robot, read_measurements, read_model
from .planning.cell import load_cell
from .planning.planfile import Plan
from .run.loop import RunResult, run_plan
from .run.progress import Progress, ProgressKind
from .services.diagnosis import diagnose_model, write_diagnosis
from .services.fitting import fit_folder
from .services.planning import plan_folder
from .services.report import report_run
from .sim.cell import sim_robot_name, sim_station
from .sim.world import build_world

#: The wear the "month later" run carries: joint 2 tilts 0.5 mrad more about its x axis.
DEFAULT_DEGRADATION = {"j2.ex.c0": 5e-4}


@dataclass(frozen=True)
class DemoRun:
    """One simulated session of the demo."""

    run_id: str
    days_after_baseline: int
    degrade: dict[str, float]
    camera_seed: int
    story: str


@dataclass
class DemoRunResult:
    """What one run produced."""

    run: DemoRun
    folder: Path
    report_html: Path | None = None
    figures_mm: dict[str, float] = field(default_factory=dict)
    verdict: str = ""
    flags: list[str] = field(default_factory=list)
    diagnosis: str = ""
    seconds: float = 0.0


@dataclass
class DemoResult:
    """The demo's outcome: per-run results and whether the story came out as it should."""

    out: Path
    plan_summary: list[str]
    runs: list[DemoRunResult]
    expected_flag_ok: bool
    seconds: float
    worn_faults: list[str] = field(default_factory=list)  # the faults the worn run carries


def demo_runs(degrade: dict[str, float] | None = None) -> list[DemoRun]:
    """Baseline, healthy repeat, and the worn robot a month later."""
    wear = dict(DEFAULT_DEGRADATION if degrade is None else degrade)
    return [
        DemoRun("baseline", 0, {}, 11, "the robot as commissioned: this run is the baseline"),
        DemoRun("week-1", 7, {}, 12, "a week later, nothing changed: must not be flagged"),
        DemoRun("month-1", 35, wear, 13, "a month later, one joint worn: must be flagged"),
    ]


class _PoseCounter:
    """Progress callback of one run: logs every step, counts measured poses for the bar."""

    def __init__(
        self,
        run_id: str,
        log: io.TextIOBase,
        bar: Callable[[str, int, int], None] | None,
    ) -> None:
        self.run_id, self.log, self.bar = run_id, log, bar
        self.measured = 0
        self.lock = threading.Lock()

    def __call__(self, p: Progress) -> None:
        with self.lock:  # the run calls back from its capture and measurement threads
            self.log.write(
                f"{self.run_id} {p.kind}: [{p.index}/{p.n_poses}] {p.name} {p.status} {p.message}\n"
            )
            if p.kind == ProgressKind.MEASURED:
                self.measured += 1
                if self.bar is not None:
                    self.bar(self.run_id, self.measured, p.n_poses)


class _Log:
    """demo.log: each step as the command a user would type, and the lines it reports."""

    def __init__(self, path: Path) -> None:
        self.file = open(path, "w", encoding="utf-8")  # noqa: SIM115 - closed by close()

    def step(self, argv: Sequence[str], lines: Sequence[str]) -> None:
        self.file.write(f"\n$ quickhealth {' '.join(argv)}\n")
        self.file.writelines(f"{line}\n" for line in lines)
        self.file.flush()

    def close(self) -> None:
        self.file.close()


def run_demo(
    out: Path,
    *,
    cell: str = "reference",
    n_candidates: int = 150,
    seed: int = 0,
    speed_factor: float = 20.0,
    image_scale: float = 0.5,
    degrade: dict[str, float] | None = None,
    say: Callable[[str], None] = print,
    pose_progress: Callable[[str, int, int], None] | None = None,
) -> DemoResult:
    """Run the demo into ``out`` (created; an earlier demo there is replaced).

    Parameters
    ----------
    cell : str
        The cell (a built-in name or a file): its arm is planned, simulated and assessed.
    n_candidates : int
        Random targets the planner draws (the paper: 150).
    speed_factor : float
        How much faster than life the simulated arm moves (the loop takes ~4 min at 1×).
    image_scale : float
        Simulated sensor size relative to the reference 4000×3000 px cameras.
    say : callable
        Receives the lines a user reads.
    pose_progress : callable, optional
        ``(run_id, measured, n_poses)`` after every measured pose (progress bars).
    """
    t_start = time.monotonic()
    worn = worn_faults(cell, dict(DEFAULT_DEGRADATION if degrade is None else degrade))
    out = Path(out)
    if out.exists():
        if not (out / "demo.log").exists() and any(out.iterdir()):
            raise QuickhealthError(f"{out}: exists and is not a demo folder; choose another --out")
        shutil.rmtree(out)
    out.mkdir(parents=True)
    log = _Log(out / "demo.log")
    results: list[DemoRunResult] = []
    try:
        plan, plan_summary = _plan(cell, out / "plan", n_candidates, seed, say, log)
        t0 = datetime.now(UTC).replace(microsecond=0)
        for k, run in enumerate(demo_runs(degrade), start=1):
            t_run = time.monotonic()
            say("")
            say(f"{k + 1}. run {run.run_id}: {run.story}")
            folder = _run(cell, out, run, plan, speed_factor, image_scale, say, log, pose_progress)
            result = _assess(cell, out, folder, run, t0, say, log)
            result.seconds = time.monotonic() - t_run
            results.append(result)
    finally:
        log.close()
    flagged_ok = _story_holds(results, worn)
    return DemoResult(out, plan_summary, results, flagged_ok, time.monotonic() - t_start, worn)


def _plan(
    cell: str, out: Path, n_candidates: int, seed: int, say: Callable[[str], None], log: _Log
) -> tuple[Plan, list[str]]:
    """1. the fixed loop of the cell; the first lines of its summary."""
    argv = ["plan", "--cell", cell, "--n", str(n_candidates), "--seed", str(seed)]
    say(f"1. plan: quickhealth {' '.join(argv)}")
    res = plan_folder(load_cell(cell), n_candidates, seed, out)
    lines = [*res.result.summary(), f"plan {res.plan.hash}"]
    log.step([*argv, "--out", str(out)], lines + ["wrote " + ", ".join(map(str, res.paths))])
    summary = [ln for ln in lines if ln.strip()][:4]
    for ln in summary:
        say(f"   {ln}")
    return res.plan, summary


def _run(
    cell: str,
    out: Path,
    run: DemoRun,
    plan: Plan,
    speed_factor: float,
    image_scale: float,
    say: Callable[[str], None],
    log: _Log,
    pose_progress: Callable[[str, int, int], None] | None,
) -> Path:
    """2. the plan on the simulated cell (worn as the run says); the run folder."""
    wear = ",".join(f"{a}={b:g}" for a, b in run.degrade.items())
    say(
        f"   quickhealth run --sim --cell {cell} --plan plan/plan.json"
        + (f" --sim-degrade {wear}" if wear else "")
    )
    station, _ = sim_station(
        cell,
        twin_seed=1,
        image_scale=image_scale,
        speed_factor=speed_factor,
        degrade=run.degrade or None,
        camera_seed=run.camera_seed,
    )
    folder = out / "runs" / run.run_id
    try:
        res: RunResult = run_plan(
            station, plan, folder, progress=_PoseCounter(run.run_id, log.file, pose_progress)
        )
    finally:
        station.close()
    if res.stopped:
        raise HardwareError(f"run {run.run_id} stopped: {res.stopped}")
    say(
        f"   {res.n_measured} of {res.n_poses} poses measured, {res.n_failed} failed; "
        f"instrument self-check drift {res.selfcheck_drift_mm or 0:.4f} mm"
    )
    return folder


def _assess(
    cell_name: str,
    out: Path,
    folder: Path,
    run: DemoRun,
    t0: datetime,
    say: Callable[[str], None],
    log: _Log,
) -> DemoRunResult:
    """3.–6. fit, diagnose, archive and trend, report."""
    csv = folder / "measurements.csv"
    cell = load_cell(cell_name)
    arm = cell.robot.name
    robot = cell.robot_with_target(load_robot(arm))  # compliance: the arm's and target's masses
    robot_name = sim_robot_name(cell)
    meas = read_measurements(csv, robot.n_joints)
    fit = fit_folder(meas, robot, folder, source=str(csv))
    target = ["--cell", cell_name] if cell.target_mass > 0 else []
    log.step(
        ["identify", "fit", str(csv), "--robot", arm, *target, "--out", str(folder)],
        fit.assessment.summary(),
    )
    report = fit.files.report
    ws = report["workspace"]
    figs = {k: float(ws[f"{k}_mm"]) for k in ("mean", "std", "max")}
    say(
        f"   fit: {report['n_poses']} poses, {report['n_params']} parameters, "
        f"residual {report['rms_pos_mm']:.4f} mm / "
        f"{report.get('rms_rot_deg', float('nan')):.5f}°; workspace TCP error "
        f"mean {figs['mean']:.3f} mm, std {figs['std']:.3f} mm, max {figs['max']:.3f} mm"
    )

    diag = diagnose_model(read_model(folder / "model.json"), meas).diagnosis
    write_diagnosis(folder / "diagnosis.json", diag)
    log.step(
        [
            "diagnose",
            str(folder / "model.json"),
            str(csv),
            "--json",
            str(folder / "diagnosis.json"),
        ],
        diag.summary(top=5),
    )
    diagnosis = str(diag.verdict.value)
    if diagnosis == "missing-effect" and diag.candidates:
        diagnosis += f" (best: {diag.candidates[0].effect})"
    say(f"   diagnose: {diagnosis}")

    archive_dir = out / "archive"
    when = (t0 + timedelta(days=run.days_after_baseline)).isoformat().replace("+00:00", "Z")
    arch = Archive.open(archive_dir)
    rec = arch.add_run(robot_name, folder, run_id=run.run_id, time_utc=when)
    baseline = run.days_after_baseline == 0
    if baseline:
        arch.set_baseline(rec.robot, rec.run_id)
    log.step(
        [
            "archive",
            "add",
            str(folder),
            "--robot",
            robot_name,
            "--run-id",
            run.run_id,
            "--time",
            when,
        ]
        + ["--archive", str(archive_dir)]
        + (["--baseline"] if baseline else []),
        [f"archived {rec.robot}/{rec.run_id} ({rec.time_utc}) in {arch.folder(rec)}"],
    )
    result = DemoRunResult(run, arch.folder(rec), figures_mm=figs, diagnosis=diagnosis)

    html = result.folder / "report.html"
    argv = ["report", str(result.folder), "--out", str(html), "--robot", robot_name, "--run-id"]
    argv += [run.run_id, "--archive", str(archive_dir)]
    try:
        rep = report_run(
            result.folder, archive=arch, robot=robot_name, run_id=run.run_id, html=html
        )
    except QuickhealthError as exc:  # the demo goes on; the table says the report is missing
        log.step(argv, [f"quickhealth: error: {exc}"])
        say(f"   report: failed ({exc})")
        return result
    j = rep.report.judgement  # the one verdict, as every door gives it
    result.verdict = "baseline" if baseline else j.verdict.value
    result.flags = list(j.changes)
    say(f"   {j.headline()}")
    for line in result.flags:
        say(f"     - {line}")
    log.step(argv, [*j.lines(), f"wrote {html} and updated {rep.report_json}"])
    result.report_html = html
    return result


def _story_holds(results: list[DemoRunResult], worn_words: Sequence[str]) -> bool:
    """The healthy repeat is not flagged; the worn run is, and its first change names the
    physical fault the wear is (``worn_words``, from :func:`worn_faults`): the trend names a
    change by the fault that explains it."""
    by_id = {r.run.run_id: r for r in results}
    healthy = by_id.get("week-1")
    worn = by_id.get("month-1")
    if healthy is None or worn is None or healthy.flags or not worn.flags:
        return False
    said = [line.lower() for line in worn.flags]
    if worn_words and worn_words[0].lower() not in said[0]:
        return False
    return all(any(w.lower() in line for line in said) for w in worn_words)


def worn_faults(cell: str, wear: dict[str, float]) -> list[str]:
    """The words of the physical fault each injected change is (``j2.ex.c0``, a constant twist
    of the link from joint 2 to 3 about its x axis, is "joint 3 tilt about x"; an effect's
    name is its own fault): the fault of the dictionary whose unit change in the simulated
    twin's error model is the injected one's direction.

    Raises
    ------
    InputError
        A coefficient that is no single fault (a wear the story cannot name).
    """
    world = build_world(cell)
    spec = world.twin.truth.spec
    labels = spec.labels()
    robot = load_cell(cell).robot_with_target()
    faults = []
    for f in geometric_faults(robot):
        try:
            u = f.raw_vector(spec)
        except ValueError:  # a scale needs order 1 of its motion
            continue
        faults.append((f, u / np.linalg.norm(u)))
    out = []
    for label, size in wear.items():
        if is_effect_name(label):
            out.append(effect_fault(parse_effect(label, robot)).words)
            continue
        v = np.zeros(spec.n_params)
        if label not in labels:
            raise InputError(
                f"degradation {label!r}: not a coefficient of the error model (e.g. j2.ex.c0) "
                "nor an effect (compliance:j2)"
            )
        v[labels.index(label)] = size
        best, cos = max(
            ((f, abs(u @ v) / np.linalg.norm(v)) for f, u in faults), key=lambda t: t[1]
        )
        if cos < 0.999:
            raise InputError(
                f"degradation {label!r}: no single physical fault, so the demo could not check "
                "that the trend names it; give a fault's change (j2.ex.c0 is joint 3 tilt "
                "about x, j2.ez.c0 joint 2 zero offset) or an effect (compliance:j2)"
            )
        out.append(best.words)
    return out
