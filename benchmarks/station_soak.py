"""Station soak: random faults across runs of the reference plan on the simulated cell.

Every run of the reference plan goes through the real station path: the ur-rtde client in its
own process against the UR controller simulator (another process), the serial driver against
the pan-motor emulator, rendered cameras, ``station.run.run_plan`` with its journal.  While a
run goes, faults are injected at random moments, each followed by what a technician would do:

==================  ========================================================================
fault               recovery
==================  ========================================================================
protective_stop     release the stop (dashboard), resume the run
drop_connection     the link comes back after 0.3 s; reconnect, resume
freeze_stream       restart the controller's stream; reconnect, resume
restart             the controller reboots (away ~1 s); reconnect until it answers, resume
serial_garbage      line noise before the pan motor's next replies; the run goes on (or resumes)
abort               the operator aborts during a move; resume
bad_move            the controller's joint speed limits drop (a safety-configuration change):
                    the next move is beyond them and ends in a protective stop; the limits
                    are put back, the stop unlocked on the dashboard, resume
power_off           the arm is powered off; dashboard ``power on``, ``brake release``, resume
pause               the program is paused from the dashboard; resume (the program restarts)
unknown_command     the controller stops the program with a compile error at the next
                    command (a command it does not know); resume
kill9               ``kill -9`` of the run's process; ``--resume`` in a new process
camera_unplug       the left camera is unplugged: the run stops in one line; plugged back in,
                    resume
camera_timeout      the left camera's trigger is lost (a missing edge): the run stops in one
                    line; the trigger cable seated again, resume
camera_dropped_frame  the right camera's next frame arrives incomplete: captured again, the
                    run goes on
camera_out_of_step  a stray edge on the left camera alone: the pair is out of step, captured
                    again, the run goes on
camera_reboot       the left camera reboots (away 1 s): opened and configured again, the run
                    goes on (or resumes, when the reboot outlasts the captures' attempts)
==================  ========================================================================

The cameras are pypylon's emulated cameras behind the station's pylon backend, serving the
rendered scene (``run --sim --cameras pylon``).  Faults a camera recovers from by itself do
not end the run: the next fault is injected into the same run.

The runs execute in worker processes (this script with ``--worker``), so a crash of the
interpreter is seen and counted, and ``kill -9`` is real.  A worker reports each fault on
its standard output the moment it injects it, so the faults of a worker that then fails
still count: as injected and not survived.  At the end of every run its journal is read: a
pose of the plan without a record is *lost*, a pose captured twice is *measured twice*.
Prints: faults injected and survived, poses lost, poses measured twice, interpreter crashes
(target: all survived, 0, 0, 0).  Every healthy run injects at least one fault, so at most
``--max-runs`` runs are made (default: as many as faults), and three runs in a row that
inject nothing (workers failing before their first fault) end the soak too, as a FAIL.

    .venv/bin/python benchmarks/station_soak.py [--faults 200] [--seed 0] [--max-runs N]
                                                [--camera-share 0.35]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "helpers"))
from qh_dashboard import dashboard  # noqa: E402  (a technician's dashboard client)

IN_RUN = (
    "protective_stop",
    "drop_connection",
    "freeze_stream",
    "restart",
    "serial_garbage",
    "abort",
    "bad_move",
    "power_off",
    "pause",
    "unknown_command",
    "camera_unplug",
    "camera_timeout",
    "camera_dropped_frame",
    "camera_out_of_step",
    "camera_reboot",
)
KINDS = (*IN_RUN, "kill9")
CAMERA = tuple(k for k in IN_RUN if k.startswith("camera_"))
ROBOT = tuple(k for k in IN_RUN if k not in CAMERA)
CAMERA_SHARE = 0.35  # of the faults injected during runs (at least 50 of 200 in all)
# Camera faults the triggered pair absorbs (a recapture) without stopping the run.
ABSORBED = ("camera_dropped_frame", "camera_out_of_step", "camera_reboot")
SPEED = 5.0  # the simulated arm moves this many times faster than life
IMAGE_SCALE = 0.25
# The controller's state machine a little faster than life, as the arm is.
DELAYS = "boot=0.6,power_on=0.3,brake_release=0.4,unlock_after=1.0"


def _plan_path(work: Path) -> Path:
    """The reference plan (150 candidates, seed 0), planned once through the command line."""
    out = work / "plan"
    if not (out / "plan.json").is_file():
        subprocess.run(
            [sys.executable, "-m", "quickhealth.station.cli", "plan", "--cell", "reference",
             "--n", "150", "--seed", "0", "--out", str(out)],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
    return out / "plan.json"


# ---------------------------------------------------------------------------------------
# Worker: one run folder until its run is complete, faults injected in between
# ---------------------------------------------------------------------------------------


def _inject(kind: str, cell, station) -> None:  # type: ignore[no-untyped-def]
    sim = cell.controller
    if kind.startswith("camera_"):
        cell.camera._prepare.inject(kind.removeprefix("camera_"))  # the emulated cameras' feed
    elif kind == "serial_garbage":
        cell.emulator.inject("garbage", count=3)
    elif kind == "abort":
        deadline = time.monotonic() + 5.0
        while not sim.state()["moving"] and time.monotonic() < deadline:
            time.sleep(0.005)
        t0 = time.monotonic()
        station.robot.stop()
        returned = time.monotonic() - t0
        while sim.state()["moving"] and time.monotonic() - t0 < 5.0:
            time.sleep(0.002)
        _say("abort", stop_returned_s=returned, still_s=time.monotonic() - t0)
    elif kind == "restart":
        try:
            sim.fault("restart", down_s=1.0)
        except ValueError:  # a simulator without restarts: a long link drop is the same to us
            sim.fault("drop_connection")
            threading.Timer(1.0, sim.fault, args=("clear",)).start()
    elif kind == "bad_move":
        sim.fault("joint_speed_limit", scale=0.02)
    elif kind == "pause":
        dashboard(sim.host, "pause")
    else:
        sim.fault(kind)


def _until(host: str, line: str, want: str, timeout: float = 20.0) -> None:
    """Repeat a dashboard query until its reply starts with ``want``."""
    deadline = time.monotonic() + timeout
    while not dashboard(host, line)[0].startswith(want):
        if time.monotonic() > deadline:
            raise RuntimeError(f"dashboard {line!r} never answered {want!r}")
        time.sleep(0.1)


def _recover(kind: str, cell, station) -> None:  # type: ignore[no-untyped-def]
    sim = cell.controller
    if kind.startswith("camera_"):
        cell.camera._prepare.clear()  # plugged back in, the trigger cable seated
        return  # the arm only stopped (the next run starts it): nothing to recover there
    if kind == "serial_garbage":
        cell.emulator.clear()
        return
    if kind in ("protective_stop", "freeze_stream"):
        sim.fault("clear")
    elif kind == "drop_connection":
        time.sleep(0.3)
        sim.fault("clear")
    elif kind == "bad_move":  # the safety limits put back, the stop unlocked (if it came)
        sim.fault("joint_speed_limit", scale=1.0)
        if dashboard(sim.host, "safetystatus")[0].endswith("PROTECTIVE_STOP"):
            _until(sim.host, "unlock protective stop", "Protective stop releasing")
    elif kind == "power_off":
        dashboard(sim.host, "power on")
        _until(sim.host, "robotmode", "Robotmode: IDLE")
        dashboard(sim.host, "brake release")
        _until(sim.host, "robotmode", "Robotmode: RUNNING")
    link = kind in ("drop_connection", "freeze_stream", "restart")
    technician = kind in ("bad_move", "power_off", "pause", "unknown_command")
    deadline = time.monotonic() + 30.0
    while True:  # reconnect until the controller answers (a restart takes a moment)
        try:
            # After a link fault the technician presses c: a new client, whatever the old
            # one still believes (its socket may not have noticed the drop yet).
            station.robot.reconnect() if link else station.robot.connect()
            if station.robot.status().ready:
                return
            if not technician:  # the new faults are recovered as above, never cleared
                sim.fault("clear")
        except Exception:  # noqa: BLE001 - the controller is still away: try again
            if time.monotonic() > deadline:
                raise
        time.sleep(0.3)


def _say(event: str, **what: object) -> None:
    """One event line on the worker's standard output, at once (the driver reads every line,
    also from a worker that fails later)."""
    print(json.dumps({"event": event, **what}), flush=True)


def worker(
    run_dir: Path, plan_path: Path, n_faults: int, seed: int, camera_share: float = CAMERA_SHARE
) -> int:
    from dataclasses import replace

    from quickhealth.identify.errors import HardwareError
    from quickhealth.station.hardware.cameras.config import CameraSpec, choose
    from quickhealth.station.planning import load_plan
    from quickhealth.station.run.journal import JOURNAL
    from quickhealth.station.run.loop import run_plan
    from quickhealth.station.sim.cell import sim_station

    os.environ.setdefault("PYLON_CAMEMU", "2")
    rng = random.Random(seed)
    plan = load_plan(plan_path)
    cameras = replace(  # pypylon's emulated pair, fixed exposure, as a cell file would set it
        choose(None, "pylon"),
        left=CameraSpec("", 0, 10_000.0),
        right=CameraSpec("", 1, 10_000.0),
        timeout_s=0.5,
    )
    station, cell = sim_station(
        "reference",
        image_scale=IMAGE_SCALE,
        speed_factor=SPEED,
        sim_options={"delays": DELAYS},
        cameras=cameras,
    )
    feed = cell.camera._prepare
    faults = 0
    try:
        while True:
            fired: list[str] = []  # the faults of this call of run_plan, in order
            done = threading.Event()

            def inject_while_running(
                fired: list[str] = fired,
                done: threading.Event = done,
                budget: int = n_faults - faults,
            ) -> None:
                # One fault at a random moment; a camera fault the pair absorbs is followed by
                # another in the same run, any other ends this run's injections.
                while len(fired) < budget:
                    if done.wait(rng.uniform(0.3, 4.0)):
                        return
                    kind = rng.choice(CAMERA if rng.random() < camera_share else ROBOT)
                    fired.append(kind)
                    _say("injected", kind=kind)
                    _inject(kind, cell, station)
                    if kind not in ABSORBED:
                        return
                    while feed.queued and not done.wait(0.05):
                        pass  # acted on at the next capture

            injector = threading.Thread(target=inject_while_running, daemon=True)
            injector.start()
            resume = (run_dir / JOURNAL).is_file()
            try:
                stopped = run_plan(station, plan, run_dir, resume=resume).stopped
            except HardwareError as exc:  # the fault came during the pre-flight: nothing moved
                stopped = str(exc)
            done.set()
            injector.join()
            for kind in fired:
                _recover(kind, cell, station)
                faults += 1
                _say("recovered", kind=kind, stopped=stopped)
            if fired:
                print(f"faults {', '.join(fired)}: {stopped}", file=sys.stderr, flush=True)
            elif stopped is not None:  # a stop nobody injected: not survived
                raise HardwareError(f"the run stopped by itself: {stopped}")
            if stopped is None:  # the run is complete
                break
    finally:
        station.close()
    _say("done")
    return 0


# ---------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------


def journal_check(run_dir: Path, n_poses: int) -> tuple[int, int, bool]:
    """(poses lost, poses measured twice, run ended) from a run's journal and its CSV.

    A capture whose images were not on disk when the process died is captured again on
    resume (by design); what must never repeat is a measurement: a pose measured twice in
    the journal or listed twice in measurements.csv.
    """
    from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal

    if not (run_dir / JOURNAL).is_file():
        return n_poses, 0, False
    recs = [rec for _, rec, _ in iter_records(run_dir / JOURNAL)]
    done = {rec["index"] for rec in recs if rec.get("type") in ("measured", "failed")}
    measured = Counter(rec["index"] for rec in recs if rec.get("type") == "measured")
    st = read_journal(run_dir / JOURNAL)
    lost = sum(1 for i in range(1, n_poses + 1) if i not in done)
    twice = sum(c - 1 for c in measured.values() if c > 1)
    csv = run_dir / "measurements.csv"
    if csv.is_file():
        lines = [ln for ln in csv.read_text().splitlines() if ln and not ln.startswith("#")]
        col = lines[0].split(",").index("pose_id")
        ids = Counter(ln.split(",")[col] for ln in lines[1:])
        twice = max(twice, sum(c - 1 for c in ids.values() if c > 1))
    return lost, twice, bool(st.ended)


def _events(out: str) -> list[dict]:
    """The event lines of a worker's standard output (anything else is skipped)."""
    events = []
    for line in out.splitlines():
        try:
            ev = json.loads(line)
        except ValueError:
            continue
        if isinstance(ev, dict) and "event" in ev:
            events.append(ev)
    return events


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--faults", type=int, default=200, help="faults to inject in all (default 200)")
    ap.add_argument("--per-run", type=int, default=12, help="faults per run of the plan")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--camera-share",
        type=float,
        default=CAMERA_SHARE,
        help=f"share of camera faults among the in-run faults (default {CAMERA_SHARE})",
    )
    ap.add_argument(
        "--max-runs",
        type=int,
        default=None,
        help="stop after this many runs of the plan (default: as many as --faults)",
    )
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--plan", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        return worker(args.worker, args.plan, args.per_run, args.seed, args.camera_share)

    from quickhealth.station.planning import load_plan

    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="qh-soak-"))
    plan_path = _plan_path(work)
    n_poses = len(load_plan(plan_path).poses)
    print(f"reference plan: {n_poses} poses; {args.faults} faults, about {args.per_run} a run")
    injected: Counter[str] = Counter()
    survived: Counter[str] = Counter()
    lost = twice = crashes = failures = runs = 0
    aborts: list[dict[str, float]] = []
    max_runs = args.max_runs or max(1, args.faults)
    barren = 0  # runs in a row that injected no fault
    t0 = time.monotonic()
    while sum(injected.values()) < args.faults:
        if runs >= max_runs or barren >= 3:
            why = "--max-runs" if runs >= max_runs else "3 runs in a row injected no fault"
            print(f"  stopped after {runs} runs ({why}): the workers keep failing", flush=True)
            break
        runs += 1
        run_dir = work / f"run{runs:03d}"
        budget = min(args.per_run, args.faults - sum(injected.values()))
        kills = sum(1 for _ in range(budget) if rng.random() < 1 / len(KINDS))
        in_run = budget - kills
        pending: list[str] = []
        worker_failed = False
        for k in range(kills + 1):
            cmd = [sys.executable, __file__, "--worker", str(run_dir), "--plan", str(plan_path),
                   "--per-run", str(in_run if k == kills else 0), "--seed", str(rng.randrange(1 << 30)),
                   "--camera-share", str(args.camera_share)]  # fmt: skip
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            if k < kills:  # kill -9 mid-run, then --resume in a new process
                time.sleep(rng.uniform(6.0, 14.0))
                if proc.poll() is None:
                    os.kill(proc.pid, signal.SIGKILL)
                    injected["kill9"] += 1
                    pending.append("kill9")
                proc.communicate()
                continue
            out, err = proc.communicate()
            if proc.returncode != 0 and "holds the UR ports" in err:
                # Another simulator on this host (a test run beside the soak): not a station
                # fault.  Run the same worker again once the ports are free.
                print(f"  run {runs}: the UR ports were busy; trying again", flush=True)
                proc = subprocess.Popen(
                    cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
                )
                out, err = proc.communicate()
            # Every fault the worker injected counts, whether or not the worker then failed.
            for ev in _events(out):
                if ev["event"] == "injected":
                    injected[ev["kind"]] += 1
                    pending.append(ev["kind"])
                elif ev["event"] == "abort":
                    aborts.append(ev)
            if proc.returncode != 0:
                worker_failed = True
                crashes += int(proc.returncode < 0)  # killed by a signal we did not send
                failures += 1
                tail = (err.strip().splitlines() or ["?"])[-1]
                log = work / f"worker-{runs:03d}-{k}.txt"
                log.write_text(err)
                print(f"  run {runs}: worker exit {proc.returncode}: {tail}", flush=True)
                print(f"    (its output: {log})", flush=True)
        barren = 0 if pending else barren + 1
        lo, tw, ended = journal_check(run_dir, n_poses)
        lost += lo
        twice += tw
        ok = ended and lo == 0 and tw == 0 and not worker_failed
        for k in pending:
            survived[k] += int(ok)
        print(
            f"  run {runs}: {len(pending)} faults "
            f"({sum(k.startswith('camera_') for k in pending)} camera; "
            f"{', '.join(sorted(set(pending))) or '-'}), "
            f"{'complete' if ended else 'NOT complete'}, lost {lo}, twice {tw}  "
            f"[{time.monotonic() - t0:.0f} s]",
            flush=True,
        )
    n_inj, n_surv = sum(injected.values()), sum(survived.values())
    print("\nfault              injected  survived")
    for k in KINDS:
        print(f"  {k:<17}{injected[k]:>8}{survived[k]:>10}")
    n_cam = sum(v for k, v in injected.items() if k.startswith("camera_"))
    print(f"faults survived      {n_surv} of {n_inj} ({n_cam} camera faults)")
    print(f"poses lost           {lost}")
    print(f"poses measured twice {twice}")
    print(f"interpreter crashes  {crashes}")
    print(f"workers that failed  {failures}")
    if aborts:
        still = sorted(a["still_s"] for a in aborts)
        print(
            f"abort to standstill  median {1e3 * still[len(still) // 2]:.0f} ms, "
            f"max {1e3 * still[-1]:.0f} ms over {len(still)} aborts (target: < 1 s)"
        )
    print(f"runs {runs}, {time.monotonic() - t0:.0f} s; load average {os.getloadavg()[0]:.1f}")
    good = (
        n_inj >= args.faults
        and n_surv == n_inj
        and lost == 0
        and twice == 0
        and crashes == 0
        and failures == 0
    )
    print("PASS" if good else "FAIL", "(target: all survived, 0 lost, 0 twice, 0 crashes)")
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
