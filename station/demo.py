"""The whole loop on the built-in simulated cell, the way a new user meets the product.

Stages (each the real code path a user runs by hand; the commands are printed as it goes):

1. **plan**      ``quickhealth plan --cell reference``: the fixed loop for the paper's cell
2. **run**       ``quickhealth run --sim``: UR controller simulator driven by the real ur-rtde
                 client, emulated pan motor on a pseudo-terminal, rendered stereo images,
                 7D measurements, crash-safe journal
3. **fit**       ``quickhealth identify fit``: implicit-loop ML fit with BIC order selection
4. **diagnose**  ``quickhealth diagnose``: is a physical effect missing?
5. **archive**   ``quickhealth archive add`` and ``quickhealth trend``: the run against the
                 robot's baseline
6. **report**    ``quickhealth report``: one self-contained HTML page per run

Three runs of the same robot on the same frozen plan: the baseline, a healthy repeat a week
later (new camera noise, nothing changed) and a run "a month later" in which one error
motion of one joint has grown (wear).  The trend must flag only the last, naming the joint
and the motion.
"""

from __future__ import annotations

import contextlib
import io
import json
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

ROBOT = "sim-ur5"
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

    def __call__(self, p: Any) -> None:
        with self.lock:  # the run calls back from its capture and measurement threads
            self.log.write(
                f"{self.run_id} {p.kind}: [{p.index}/{p.n_poses}] {p.name} {p.status} {p.message}\n"
            )
            if p.kind == "measured":
                self.measured += 1
                if self.bar is not None:
                    self.bar(self.run_id, self.measured, p.n_poses)


class _Quiet:
    """Run a command-line step with its output kept in the demo log, not on the screen."""

    def __init__(self, log: io.TextIOBase) -> None:
        self.log = log

    def __call__(self, argv: Sequence[str]) -> tuple[int, str]:
        from quickhealth.station.cli import main

        buf = io.StringIO()
        self.log.write(f"\n$ quickhealth {' '.join(argv)}\n")
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            rc = main(list(argv))
        text = buf.getvalue()
        self.log.write(text)
        self.log.write(f"[exit {rc}]\n")
        self.log.flush()
        return rc, text


def run_demo(
    out: Path,
    *,
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
    import shutil

    from quickhealth.identify.errors import HardwareError, QuickhealthError
    from quickhealth.station.archive import Archive, trend_for
    from quickhealth.station.planning import load_plan
    from quickhealth.station.run import run_plan
    from quickhealth.station.sim.cell import sim_station

    t_start = time.monotonic()
    out = Path(out)
    if out.exists():
        if not (out / "demo.log").exists() and any(out.iterdir()):
            raise QuickhealthError(f"{out}: exists and is not a demo folder; choose another --out")
        shutil.rmtree(out)
    out.mkdir(parents=True)
    archive_dir = out / "archive"
    log = open(out / "demo.log", "w", encoding="utf-8")  # noqa: SIM115 - closed below
    quiet = _Quiet(log)
    results: list[DemoRunResult] = []
    try:
        # 1. plan ------------------------------------------------------------------------
        plan_dir = out / "plan"
        say(f"1. plan: quickhealth plan --cell reference --n {n_candidates} --seed {seed}")
        rc, text = quiet(
            [
                "plan",
                "--cell",
                "reference",
                "--n",
                str(n_candidates),
                "--seed",
                str(seed),
                "--out",
                str(plan_dir),
            ]
        )
        if rc != 0:
            raise QuickhealthError(f"planning failed: {text.strip().splitlines()[-1:]}")
        plan_summary = [ln for ln in text.splitlines() if ln.strip()][:4]
        for ln in plan_summary:
            say(f"   {ln}")
        plan = load_plan(plan_dir / "plan.json")
        t0 = datetime.now(UTC).replace(microsecond=0)

        for k, run in enumerate(demo_runs(degrade), start=1):
            t_run = time.monotonic()
            folder = out / "runs" / run.run_id
            say("")
            say(f"{k + 1}. run {run.run_id}: {run.story}")
            wear = ",".join(f"{a}={b:g}" for a, b in run.degrade.items())
            say(
                "   quickhealth run --sim --cell reference --plan plan/plan.json"
                + (f" --sim-degrade {wear}" if wear else "")
            )
            station, _ = sim_station(
                "reference",
                twin_seed=1,
                image_scale=image_scale,
                speed_factor=speed_factor,
                degrade=run.degrade or None,
                camera_seed=run.camera_seed,
            )
            station.robot_name = ROBOT
            progress = _PoseCounter(run.run_id, log, pose_progress)

            try:
                res = run_plan(station, plan, folder, progress=progress)
            finally:
                station.close()
            if res.stopped:
                raise HardwareError(f"run {run.run_id} stopped: {res.stopped}")
            say(
                f"   {res.n_measured} of {res.n_poses} poses measured, {res.n_failed} failed; "
                f"instrument self-check drift {res.selfcheck_drift_mm or 0:.4f} mm"
            )
            csv = folder / "measurements.csv"

            # 3. fit ---------------------------------------------------------------------
            rc, text = quiet(["identify", "fit", str(csv), "--robot", "ur5", "--out", str(folder)])
            if rc != 0:
                raise QuickhealthError(
                    f"fit of {run.run_id} failed: {text.strip().splitlines()[-1:]}"
                )
            report = json.loads((folder / "report.json").read_text())
            ws = report.get("workspace", {})
            figs = {
                "mean": float(ws.get("mean_mm", float("nan"))),
                "std": float(ws.get("std_mm", float("nan"))),
                "max": float(ws.get("max_mm", float("nan"))),
            }
            say(
                f"   fit: {report.get('n_poses')} poses, {report.get('n_params')} parameters, "
                f"residual {report.get('rms_pos_mm', float('nan')):.4f} mm / "
                f"{report.get('rms_rot_deg', float('nan')):.5f}°; workspace TCP error "
                f"mean {figs['mean']:.3f} mm, std {figs['std']:.3f} mm, max {figs['max']:.3f} mm"
            )

            # 4. diagnose ----------------------------------------------------------------
            rc, _ = quiet(
                [
                    "diagnose",
                    str(folder / "model.json"),
                    str(csv),
                    "--json",
                    str(folder / "diagnosis.json"),
                ]
            )
            diag = json.loads((folder / "diagnosis.json").read_text()) if rc == 0 else {}
            cands = diag.get("candidates", [])
            diagnosis = str(diag.get("verdict", "not run"))
            if diagnosis == "missing-effect" and cands:
                diagnosis += f" (best: {cands[0]['effect']})"
            say(f"   diagnose: {diagnosis}")

            # 5. archive and trend ---------------------------------------------------------
            when = (t0 + timedelta(days=run.days_after_baseline)).isoformat().replace("+00:00", "Z")
            rc, text = quiet(
                [
                    "archive",
                    "add",
                    str(folder),
                    "--robot",
                    ROBOT,
                    "--run-id",
                    run.run_id,
                    "--time",
                    when,
                    "--archive",
                    str(archive_dir),
                ]
                + (["--baseline"] if run.days_after_baseline == 0 else [])
            )
            if rc != 0:
                raise QuickhealthError(f"archiving {run.run_id} failed: {text.strip()}")
            arch = Archive.open(archive_dir)
            result = DemoRunResult(
                run, arch.folder(arch.get(ROBOT, run.run_id)), figures_mm=figs, diagnosis=diagnosis
            )
            if run.days_after_baseline > 0:
                tr = trend_for(arch, ROBOT)
                result.flags = list(tr.flags())
                result.verdict = "FLAGGED" if result.flags else "healthy"
                say(f"   trend against the baseline: {result.verdict}")
                for line in result.flags:
                    say(f"     - {line}")
            else:
                result.verdict = "baseline"

            # 6. report ------------------------------------------------------------------
            html = result.folder / "report.html"
            rc, text = quiet(
                [
                    "report",
                    str(result.folder),
                    "--out",
                    str(html),
                    "--robot",
                    ROBOT,
                    "--run-id",
                    run.run_id,
                    "--archive",
                    str(archive_dir),
                ]
            )
            result.report_html = html if rc == 0 and html.exists() else None
            if result.report_html is None:
                say(
                    f"   report: failed ({text.strip().splitlines()[-1:] if text.strip() else 'no output'})"
                )
            result.seconds = time.monotonic() - t_run
            results.append(result)
    finally:
        log.close()

    flagged_ok = _story_holds(results, degrade)
    return DemoResult(out, plan_summary, results, flagged_ok, time.monotonic() - t_start)


def _story_holds(results: list[DemoRunResult], degrade: dict[str, float] | None) -> bool:
    """The healthy repeat is not flagged; the worn run is, naming the worn joint and motion."""
    from quickhealth.identify.errormodel import MOTION_WORDS

    wear = dict(DEFAULT_DEGRADATION if degrade is None else degrade)
    by_id = {r.run.run_id: r for r in results}
    healthy = by_id.get("week-1")
    worn = by_id.get("month-1")
    if healthy is None or worn is None or healthy.flags or not worn.flags:
        return False
    text = " ".join(worn.flags).lower()
    for label in wear:
        joint, motion, _ = label.split(".")
        if f"joint {joint[1:]}" not in text or MOTION_WORDS[motion].lower() not in text:
            return False
    return True
