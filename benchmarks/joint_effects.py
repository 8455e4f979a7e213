"""Acceptance of the joint-state effects: a joint's warm-up (``thermal:jK``) and compliance under
the measured torque (``compliance:jK:torque``), on the digital twin and on the simulated cell.

Twin (``--twin``): an hour's run of 300 poses in view (7D, noise 0.03 mm / 0.1 mrad), the air
warming 1 K, each joint by its duty (``identify/jointload.py``), a pick-and-place payload of
0 or up to 2 kg per pose in the joint torques; 300 held-out poses of another such run.  Orders
selected by BIC (``select_orders``, as ``identify fit``), ``diagnose``, then selected again
with the true effect and with the effect a user had before (the ambient ``thermal``, the mass
form ``compliance:jK``).  ``--controls N`` adds noise-only sets with the joint columns (false
alarms of the new candidates); ``--seeds`` repeats the cases over seeds.

Simulated cell (``--sim``): the reference cell's plans (``plan --cell reference --n 300``: seed
0 for training, seed 1 held out, ~170 poses each), each run by ``quickhealth run --sim`` with
the effect hidden in the simulated arm (``--sim-degrade``) and, for the torque case, the arm
picking and placing parts of up to 2 kg between poses (``--sim-pick-place-kg 2``); the arm
runs 20× faster than life, and its joints warm as in 20× the time (a run of ~45 min).  The
runs' measurements.csv (with the controller's temp_jK and tau_jK) are fitted as above; the
floor is the held-out run's measured positions against the twin's true ones at the recorded
joints and joint states.

Printed per case: the rank of the true effect and diagnose's suggestion, the held-out 3D
position RMS / floor without the effect, with it, and with the other effect alone.

    .venv/bin/python benchmarks/joint_effects.py --twin [--controls 10] [--seeds 100,107,114]
    .venv/bin/python benchmarks/joint_effects.py --sim [--work DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from quickhealth.identify.diagnose import (  # noqa: E402
    diagnose,
    pose_residuals,
    rms_pos_mm,
    state_from_fitted,
)
from quickhealth.identify.effects import parse_effects  # noqa: E402
from quickhealth.identify.measurements import Measurements  # noqa: E402
from quickhealth.identify.robot import RobotModel  # noqa: E402
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.identify.twin import (  # noqa: E402
    make_twin,
    random_joints,
    warm_run,
)

#: (hidden effect, size SI, the effects a user had before): twin and simulated cell
CASES = [
    ("thermal:j2", 1.5e-5, ("thermal", "drift")),
    ("thermal:j3", 1.5e-5, ("thermal", "drift")),
    ("compliance:j2:torque", 2.5e-5, ("compliance:j2", "compliance:j2:lumped")),
]
QH = [sys.executable, "-m", "quickhealth.station.cli"]


def judge(
    robot: RobotModel,
    train: Measurements,
    held: Measurements,
    floor: float,
    effect: str | None,
    others: tuple[str, ...] = (),
) -> dict[str, object]:
    """select → diagnose → select with the effect and with each other one: ratios to the floor."""

    def ratio(effects: str | None) -> float:
        fx = parse_effects(effects, robot) if effects else []
        f = select_orders(robot, train, fx).fitted
        T = f.predict(held.q, **held.conditions())
        return rms_pos_mm(pose_residuals(held, T)) / floor

    plain = select_orders(robot, train).fitted
    diag = diagnose(state_from_fitted(plain), train)
    names = [c.effect for c in diag.candidates]
    T = plain.predict(held.q, **held.conditions())
    out: dict[str, object] = {
        "verdict": diag.verdict.value,
        "rank": names.index(effect) + 1 if effect in names else None,
        "suggested": ",".join(diag.suggested) or "-",
        "n_tested": diag.n_tested,
        "before": rms_pos_mm(pose_residuals(held, T)) / floor,
        "floor_mm": floor,
    }
    if effect:
        out["after"] = ratio(effect)
        out["others"] = [ratio(o) for o in others]
    return out


def twin_case(
    effect: str | None, size: float, others: tuple[str, ...], seed: int
) -> dict[str, object]:
    twin = make_twin(seed=seed, effects={effect: size} if effect else {})
    q = random_joints(twin.robot, 600, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    # an hour's runs: air +1 K, joints by their duty, 0 or up to 2 kg per pose
    train, held = warm_run(twin, q[:300], seed + 2), warm_run(twin, q[300:], seed + 3)
    T = twin.true_pose(
        held.q, held.time, held.temp, joint_temp=held.joint_temp, joint_torque=held.joint_torque
    )
    floor = rms_pos_mm(pose_residuals(held, T))
    out = judge(twin.robot, train, held, floor, effect, others)
    out["dT_j"] = np.ptp(train.joint_temp, axis=0)
    return out


def qh(*args: str, resume: int = 0) -> None:
    """Run one command; a run that stopped on a hardware fault (exit 3: on a loaded machine
    the simulated controller's stream can stall past the 0.5 s freeze check) is resumed, as
    the technician would, up to ``resume`` times."""
    p = subprocess.run([*QH, *args], capture_output=True, text=True)
    for _ in range(resume):
        if p.returncode != 3:
            break
        print(f"  resumed after: {p.stderr.strip()[-200:]}", flush=True)
        p = subprocess.run([*QH, *args, "--resume"], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"quickhealth {' '.join(args)}: exit {p.returncode}: {p.stderr[-800:]}")


def sim_runs(effect: str | None, size: float, work: Path) -> tuple[Measurements, Measurements]:
    """The training and held-out runs of the simulated cell with ``effect`` hidden (None: the
    arm without it), as a user records them; the air's temperature added as a thermometer
    beside the arm reads it (the controller simulator's flat 25 °C)."""
    from quickhealth.station.formats import read_measurements
    from quickhealth.station.sim.dynamics import AMBIENT_C

    runs = {}
    for name, seed in (("train", 0), ("held", 1)):
        plan = work / f"plan{seed}"
        if not (plan / "plan.json").exists():
            qh("plan", "--cell", "reference", "--n", "300", "--seed", str(seed), "--out", str(plan))
        out = work / f"{(effect or 'none').replace(':', '_')}_{name}"
        if not (out / "measurements.csv").exists():
            argv = ["run", "--cell", "reference", "--plan", str(plan / "plan.json"), "--out"]
            argv += [str(out), "--sim", "--sim-image-scale", "0.25", "--sim-speed-factor", "20"]
            argv += ["--unattended", "--sim-pick-place-kg", "2"]  # a payload that changes
            if effect:
                argv += ["--sim-degrade", f"{effect}={size}"]
            t0 = time.perf_counter()
            qh(*argv, resume=3)
            print(
                f"  {effect or 'no effect'} {name} run: {time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        runs[name] = read_measurements(out / "measurements.csv")
    train, held = (
        replace(runs[k], temp=np.full(runs[k].n_poses, AMBIENT_C)) for k in ("train", "held")
    )
    return train, held


def sim_robot() -> RobotModel:
    """The arm as its user knows it: the UR5 with the smart target's mass on the flange."""
    from quickhealth.identify.robot import ur5, with_payload
    from quickhealth.station.sim.process import SMART_TARGET_COM, SMART_TARGET_KG

    return with_payload(ur5(), SMART_TARGET_KG, SMART_TARGET_COM)


def sim_floor(work: Path) -> tuple[float, float]:
    """The simulated cell's noise floor: the held-out RMS (mm) of the model on the same two
    runs of the arm without a hidden effect (what the instrument, the vision's own systematic
    errors included, and the error model allow), and the held-out RMS of those measurements
    against the twin's true poses (the vision's error alone)."""
    from quickhealth.station.sim.world import build_world

    train, held = sim_runs(None, 0.0, work)
    fitted = select_orders(sim_robot(), train).fitted
    floor = rms_pos_mm(pose_residuals(held, fitted.predict(held.q, **held.conditions())))
    truth = build_world("reference", twin_seed=1).twin.true_pose(held.q)
    return floor, rms_pos_mm(pose_residuals(held, truth))


def sim_case(
    effect: str, size: float, others: tuple[str, ...], work: Path, floor: float
) -> dict[str, object]:
    """Two runs of the simulated cell with ``effect`` hidden, fitted and judged."""
    train, held = sim_runs(effect, size, work)
    out = judge(sim_robot(), train, held, floor, effect, others)
    out["dT_j"] = np.ptp(train.joint_temp, axis=0)
    out["n"] = (train.n_poses, held.n_poses)
    return out


def show(name: str, r: dict[str, object], others: tuple[str, ...] = ()) -> None:
    dT = np.asarray(r.get("dT_j", []))
    alt = ", ".join(f"{o} {v:.3f}" for o, v in zip(others, r.get("others", []), strict=True))
    print(
        f"{name:<30}{r['verdict']:>15}{r['rank']!s:>5}  {r['suggested']:<22}"
        f"{r['before']:>7.3f}{r.get('after', float('nan')):>7.3f}{r['floor_mm']:>9.4f}  "
        f"{np.array2string(dT, precision=1):<34}{alt}",
        flush=True,
    )


HEADER = (
    f"{'case':<30}{'verdict':>15}{'rank':>5}  {'suggested':<22}{'before':>7}{'with':>7}"
    f"{'floor mm':>9}  {'joints warm by (K)':<34}instead of the effect"
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--twin", action="store_true", help="the digital twin's cases")
    ap.add_argument("--sim", action="store_true", help="the simulated cell's long runs")
    ap.add_argument("--seeds", default="100", help="twin seeds, comma-separated")
    ap.add_argument("--controls", type=int, default=0, help="noise-only twin sets")
    ap.add_argument("--work", type=Path, default=None, help="sim: keep plans and runs here")
    args = ap.parse_args(argv)
    if args.twin:
        print("digital twin: held-out RMS / floor without the effect, with it, with the other")
        print(HEADER)
        for seed in (int(s) for s in args.seeds.split(",")):
            for effect, size, others in CASES:
                show(f"{effect} ({seed})", twin_case(effect, size, others, seed), others)
        alarms = 0
        for i in range(args.controls):
            r = twin_case(None, 0.0, (), 900 + 7 * i)
            alarms += r["verdict"] != "adequate"
            show(f"none ({900 + 7 * i})", r)
        if args.controls:
            print(f"noise-only sets: {alarms} false alarms in {args.controls}")
    if args.sim:
        work = args.work or Path(tempfile.mkdtemp(prefix="qh-joint-effects-"))
        work.mkdir(parents=True, exist_ok=True)
        os.environ.setdefault("QUICKHEALTH_LOCK_DIR", str(work / "lock"))
        floor, vision = sim_floor(work)
        print(
            f"simulated cell (runs in {work}): held-out RMS / floor, the floor {floor:.4f} mm: "
            "the model's held-out RMS on the same runs of the arm without the effect (the "
            f"measurements against the twin's true poses: {vision:.4f} mm)"
        )
        print(HEADER)
        for effect, size, others in CASES:
            r = sim_case(effect, size, others, work, floor)
            show(f"{effect} {r['n']}", r, others)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
