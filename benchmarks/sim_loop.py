"""The reference plan's loop program on the simulated controller: every pose visited?

Plans ``quickhealth plan --cell reference --n 150 --seed 0`` (the soak's plan, 74 poses),
starts the UR controller simulator (its own process) and sends the ``loop.script`` that
``plan`` wrote to the secondary interface (30002), as a cell would.  This script plays the
station over RTDE (``tests/helpers/qh_rtde_guide.py``, written from UR's RTDE guide): at each
pose the program announces in its handshake register it reads the actual joints and the
controller's reported TCP pose from the stream and acknowledges.  Prints, per speed factor,
the poses announced against the plan's and the largest distance between the reported TCP and
the planned pose as this controller computes it (its factory calibration, the plan's TCP);
target: every pose, within 0.1 mm.

    .venv/bin/python benchmarks/sim_loop.py [--speed 20 5] [--version 5.11.1]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

TARGET_MM = 0.1


def main() -> int:
    from qh_rtde_guide import run_loop

    from quickhealth.station.cli import main as cli
    from quickhealth.station.planning import load_plan
    from quickhealth.station.sim.arm import T_from_pose, pose_from_T
    from quickhealth.station.sim.kinematics import factory_calibration
    from quickhealth.station.sim.process import start_sim_controller
    from quickhealth.station.sim.states import TESTING
    from quickhealth.station.sim.world import build_world

    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--speed", type=float, nargs="+", default=[20.0, 5.0])
    ap.add_argument("--version", default="5.11.1", help="controller version the simulator reports")
    ap.add_argument("--n", default="150")
    ap.add_argument("--seed", default="0")
    args = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="qh-loop-")) / "plan"
    assert (
        cli(["plan", "--cell", "reference", "--n", args.n, "--seed", args.seed, "--out", str(out)])
        == 0
    )
    plan = load_plan(out / "plan.json")
    text = (out / "loop.script").read_text()
    model = factory_calibration(build_world("reference", twin_seed=1).twin.robot, 1)
    q_plan = np.stack([p.q for p in plan.poses])
    want = (model.fk(q_plan) @ T_from_pose(pose_from_T(plan.T_flange_target)))[:, :3, 3]
    good = True
    print(f"\nreference plan: {len(plan.poses)} poses; loop.script sent to 30002 ({args.version})")
    print("speed  poses  in order  max |q - plan| rad  max TCP error mm  time s  result")
    for speed in args.speed:
        sim = start_sim_controller(
            control_port=30089,
            speed_factor=speed,
            delays=TESTING.spec(),
            controller_version=args.version,
        )
        try:
            t0 = time.monotonic()
            seen, qs, tcps = run_loop(
                sim, text, plan.motion.handshake_register, plan.home, timeout=1200
            )
            dt = time.monotonic() - t0
            error = sim.state()["program_error"]
        finally:
            sim.stop()
        ordered = seen == [p.index for p in plan.poses]
        n = min(len(seen), len(q_plan))
        dq = float(np.max(np.abs(qs[:n] - q_plan[:n]))) if n else float("nan")
        err = (
            float(np.max(np.linalg.norm(tcps[:n, :3] - want[:n], axis=1))) * 1e3
            if n
            else float("nan")
        )
        ok = ordered and not error and err <= TARGET_MM
        good &= ok
        print(
            f"{speed:5g}  {len(seen):5d}  {str(ordered):>8}  {dq:18.2e}  {err:16.4f}  {dt:6.1f}  "
            f"{'PASS' if ok else 'FAIL'}{'  ' + error if error else ''}"
        )
    print(f"target: every pose, in order, reported TCP within {TARGET_MM} mm of the planned pose")
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
