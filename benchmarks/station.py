"""Station benchmark: the time each pose adds beyond robot motion and settling.

Runs the real per-pose loop (``station.run.run_plan``: pan, capture, quick detection check,
atomic image writes, fsynced journal; the 7D measurement in the background worker) on the
pure-Python robot (real motion profiles at 2× speed, so the background work overlaps a move
as it would on the cell), the pan motor emulator on a pseudo-terminal,
and a camera that replays pre-rendered full-resolution stereo pairs (4000×3000 px, the
reference design) of the digital twin at each pose, so "capture" costs what a real camera
read-out costs here, not what rendering costs.

Prints, per pose: pan wait, capture, quick check, journaling (images + journal record) and
their sum (target ≤ 150 ms), and the background measurement time that overlaps the next move.

    .venv/bin/python benchmarks/station.py [--poses 6] [--scale 1.0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--poses", type=int, default=6)
    ap.add_argument("--scale", type=float, default=1.0, help="image scale (1 = 4000×3000)")
    args = ap.parse_args()

    from quickhealth.identify.transforms import inv_T
    from quickhealth.station.hardware.cameras import StereoFrame
    from quickhealth.station.hardware.motor import SerialPanMotor
    from quickhealth.station.hardware.target import T_target_plate
    from quickhealth.station.planning import load_cell
    from quickhealth.station.planning.planfile import plan_from_dict, plan_to_dict
    from quickhealth.station.planning.planner import plan_loop
    from quickhealth.station.run.loop import run_plan
    from quickhealth.station.run.settings import RunSettings
    from quickhealth.station.sim.cameras import scaled_rig
    from quickhealth.station.sim.fake_robot import FakeRobot
    from quickhealth.station.sim.motor_emulator import MotorEmulator
    from quickhealth.station.sim.world import build_world
    from quickhealth.station.station import Station
    from quickhealth.vision.render import render_stereo

    cell = load_cell("reference")
    world = build_world("reference", twin_seed=1)
    print("planning …", flush=True)
    plan = plan_from_dict(plan_to_dict(plan_loop(cell, 24, seed=1)), "bench")
    plan = dataclasses.replace(plan, poses=plan.poses[: args.poses])
    rig = scaled_rig(world.rig, args.scale)

    class ReplayCamera:
        """Pre-rendered pairs, chosen by the robot's current joints (a real camera's read-out)."""

        def __init__(self) -> None:
            self.rig = rig
            self.frames = {}
            q = cell.home
            app = np.ones(6)
            for p in plan.poses:
                app = np.where(np.abs(p.q - q) > 1e-9, np.sign(p.q - q), app)
                q = p.q
                T = world.T_instr_target0(p.q, app) @ T_target_plate(p.pan)
                t0 = time.monotonic()
                self.frames[p.name] = (p.q, render_stereo(rig, T, world.target))
                print(f"  rendered {p.name} in {time.monotonic() - t0:.1f} s", flush=True)
            self.home = render_stereo(rig, world.T_instr_board, world.board)

        def capture(self) -> StereoFrame:
            qa = robot.joints()
            best = min(self.frames.values(), key=lambda f: float(np.max(np.abs(f[0] - qa))))
            L, R = best[1] if np.max(np.abs(best[0] - qa)) < 1e-3 else self.home
            t = time.monotonic()
            return StereoFrame(L.copy(), R.copy(), t, t)

        def close(self) -> None:
            pass

    print(f"rendering {len(plan.poses)} stereo pairs at {rig.left.image_size} px …", flush=True)
    cam = ReplayCamera()
    robot = FakeRobot(cell.home, time_scale=2.0)
    emu = MotorEmulator(speed_deg_s=2000.0).start()
    motor = SerialPanMotor(emu.port)
    station = Station(
        robot=robot, motor=motor, camera=cam, target=world.target,
        T_instr_base=inv_T(cell.T_world_cam_left) @ cell.T_world_base,
        T_flange_target=cell.T_flange_target, board=world.board,
        T_instr_board=world.T_instr_board, cell_name=cell.name, cell_sha256=cell.sha256,
        closers=[emu.stop, motor.close],
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        t0 = time.monotonic()
        res = run_plan(station, plan, Path(d) / "run", settings=RunSettings())
        wall = time.monotonic() - t0
        timing = json.loads((Path(d) / "run" / "run.json").read_text())["timing"]
        size = sum(f.stat().st_size for f in (Path(d) / "run" / "images").iterdir())
    station.close()
    t = res.timings
    added = (
        t.get("pan_wait_s", 0) + t.get("capture_s", 0) + t.get("check_s", 0) + t.get("journal_s", 0)
    )
    print(
        f"\n{res.n_measured}/{res.n_poses} poses measured, {res.n_failed} failed; run {wall:.1f} s"
    )
    print(f"images: {size / len(plan.poses) / 1e6:.1f} MB per pose (PNG level 1)")
    print("per pose, mean (ms):")
    for k in ("pan_wait_s", "capture_s", "check_s", "journal_s"):
        print(f"  {k[:-2]:<10} {t.get(k, 0) * 1e3:7.1f}")
    print(f"  {'TOTAL':<10} {added * 1e3:7.1f}   (target ≤ 150 ms beyond motion and settling)")
    print(
        f"  images     {t.get('images_s', 0) * 1e3:7.1f}   (background worker: 2 atomic PNG writes)"
    )
    print(
        f"  measure    {t.get('measure_s', 0) * 1e3:7.1f}   (background worker: the 7D measurement)"
    )
    print(f"  move       {t.get('move_s', 0) * 1e3:7.1f}   (robot motion at 2x speed; not counted)")
    print(f"  settle     {t.get('settle_s', 0) * 1e3:7.1f}   (not counted)")
    if timing:
        print(
            "from the journal: the measurement of pose k overlaps the arm's work on pose k+1 "
            f"by {100 * timing['overlap_median']:.0f} % (median over {timing['pairs']} poses); "
            f"{timing['done_before_next_capture']} of {timing['pairs']} done before the next "
            f"pair was taken; measure {timing['measure_s_median']:.3f} s, arm "
            f"{timing['arm_s_median']:.3f} s per pose; the loop waited {timing['waited_s']:.2f} s"
        )
    return 0 if res.n_measured == res.n_poses else 1


if __name__ == "__main__":
    sys.exit(main())
