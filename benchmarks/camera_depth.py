"""Camera depth: measuring a 2448×2048 12-bit stereo pair, and 8 against 12 bits.

A 5-megapixel industrial pair (2448×2048 px, the size of a Basler acA2440 or a Sony IMX264
camera; the reference lens scaled to it) sees the reference target at the poses of a
reference plan of the digital twin.  For every pose the same scene (the same noise draw, on
the 8-bit scale) is rendered at 8 and at 12 bits.  Prints:

- the time to measure one 12-bit pair (the whole 7D measurement of ``measure_stereo``,
  median of the poses) and one 8-bit pair;
- each depth's position error against the twin's truth (mean and largest, µm) and the
  8-against-12-bit difference per pose;
- the 12-bit pairs served by pypylon's emulated cameras through the pylon backend: frames
  equal to the rendered pair (bit for bit) and the largest difference of their
  measurements from those of the rendered pairs (nm).

    .venv/bin/python benchmarks/camera_depth.py [--poses 12] [--seed 0]
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

import numpy as np

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon lists its cameras


def rig_2448x2048(rig):  # type: ignore[no-untyped-def]
    """The reference rig on 2448×2048 sensors (lens and pose kept, pixels 4000/2448 larger)."""
    from quickhealth.vision.camera import CameraModel, StereoRig

    def one(cam):  # type: ignore[no-untyped-def]
        s = 2448 / cam.image_size[0]
        K = cam.K * s
        K[2, 2] = 1.0
        K[1, 2] += (2048 - cam.image_size[1] * s) / 2
        return CameraModel(K, cam.dist, (2448, 2048))

    return StereoRig(one(rig.left), one(rig.right), rig.T_left_right)


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--poses", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from quickhealth.station.hardware.cameras.config import choose
    from quickhealth.station.planning import load_plan
    from quickhealth.station.sim.cameras import SimStereoCamera
    from quickhealth.station.sim.cell import emulated_cameras
    from quickhealth.station.sim.world import build_world
    from quickhealth.vision.pose7d import PoseMeasurement, measure_stereo
    from quickhealth.vision.render import Imaging

    work = Path(tempfile.mkdtemp(prefix="qh-depth-"))
    subprocess.run(
        [sys.executable, "-m", "quickhealth.station.cli", "plan", "--cell", "reference",
         "--n", str(3 * args.poses), "--seed", str(args.seed), "--out", str(work / "plan")],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    plan = load_plan(work / "plan" / "plan.json")
    poses = plan.poses[: args.poses]
    world = build_world("reference", twin_seed=1)
    rig = rig_2448x2048(world.rig)
    print(f"{len(poses)} poses of a reference plan, 2448×2048 px pair, target at "
          f"{min(np.linalg.norm(world.T_instr_plate(p.q, p.pan)[:3, 3]) for p in poses):.2f}–"
          f"{max(np.linalg.norm(world.T_instr_plate(p.q, p.pan)[:3, 3]) for p in poses):.2f} m")  # fmt: skip

    errs: dict[int, list[float]] = {8: [], 12: []}
    times: dict[int, list[float]] = {8: [], 12: []}
    diff_8_12 = []
    pairs12 = []
    for k, pose in enumerate(poses):
        T = world.T_instr_plate(pose.q, pose.pan)
        got = {}
        for bits in (8, 12):
            cam = SimStereoCamera(rig, lambda T=T: [(T, world.target)], seed=args.seed + k,
                                  imaging=Imaging(bits=bits))  # fmt: skip
            f = cam.capture()
            if bits == 12:
                pairs12.append((T, f.left, f.right))
            t0 = time.perf_counter()
            m = measure_stereo(rig, world.target, f.left, f.right, bits=bits if bits > 8 else None)
            times[bits].append(time.perf_counter() - t0)
            if isinstance(m, PoseMeasurement):
                got[bits] = m.position
                errs[bits].append(float(np.linalg.norm(m.position - T[:3, 3])))
        if len(got) == 2:
            diff_8_12.append(float(np.linalg.norm(got[8] - got[12])))
        print(f"  pose {k + 1:2d}: " + ", ".join(
            f"{b} bits {'%.1f µm' % (1e6 * np.linalg.norm(got[b] - T[:3, 3])) if b in got else 'not measured'}"
            for b in (8, 12)), flush=True)  # fmt: skip
    print("\nmeasuring one stereo pair (measure_stereo, whole images searched), median:")
    for bits in (12, 8):
        print(f"  {bits:2d} bits: {1e3 * np.median(times[bits]):7.0f} ms "
              f"(max {1e3 * np.max(times[bits]):.0f} ms)")  # fmt: skip
    print("position error against the twin's truth (µm):")
    for bits in (8, 12):
        e = 1e6 * np.array(errs[bits])
        print(f"  {bits:2d} bits: mean {e.mean():6.1f}  max {e.max():6.1f}  ({e.size} poses)")
    d = 1e6 * np.array(diff_8_12)
    print(f"  8 against 12 bits, same scene: mean {d.mean():.1f} µm, max {d.max():.1f} µm")

    # the 12-bit pairs through pypylon's emulated cameras and the pylon backend
    cfg = replace(choose(None, "pylon"), pixel_format="Mono12")
    holder = {"T": pairs12[0][0]}
    renderer = SimStereoCamera(rig, lambda: [(holder["T"], world.target)],
                               imaging=Imaging(bits=12))  # fmt: skip
    camera = emulated_cameras(cfg, renderer)
    exact, dmax = 0, 0.0
    try:
        for T, _, _ in pairs12:
            holder["T"] = T
            f = camera.capture()
            shown = camera._prepare.shown
            ok = np.array_equal(f.left, shown[0]) and np.array_equal(f.right, shown[1])
            exact += int(ok)
            a = measure_stereo(rig, world.target, f.left, f.right, bits=12)
            b = measure_stereo(rig, world.target, *shown, bits=12)
            if isinstance(a, PoseMeasurement) and isinstance(b, PoseMeasurement):
                dmax = max(dmax, float(np.max(np.abs(a.position - b.position))))
    finally:
        camera.close()
    print(f"pylon emulation, 12 bits: {exact} of {len(pairs12)} pairs bit for bit, "
          f"measurements within {1e9 * dmax:.3f} nm of the rendered pairs'")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
