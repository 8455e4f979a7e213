"""``identify predict`` on a 200 000-row measurement CSV: peak memory and wall time.

Issue 13's bound: at most 2 GB and 30 s.  The file is a full CSV v1 measurement file
(q1..q6, x, y, z, pitch, yaw, roll, pose_id; ~40 MB) of the digital twin; the model is a fit
of the twin at Chebyshev order 2.  The command runs as the installed console script under
``/usr/bin/time -v``; the script prints its maximum resident set size and elapsed time.

Run: ``.venv/bin/python benchmarks/predict_large.py [--rows N]`` (about a minute).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rows", type=int, default=200_000)
    a = ap.parse_args()
    twin = make_twin(seed=2)
    d = Path(tempfile.mkdtemp(prefix="qh-predict-large-"))
    q = random_joints(twin.robot, 150, seed=3, T_instr_base=twin.truth.T_instr_base)
    spec = ErrorModelSpec.uniform(6, 2, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, twin.measure(q, seed=4), spec, noise=InstrumentNoise(3e-5, 1e-4))
    formats.write_model(d / "model.json", fm)
    qb = random_joints(twin.robot, a.rows, seed=5, T_instr_base=twin.truth.T_instr_base)
    m = twin.measure(qb, seed=6)
    m = replace(m, pose_id=tuple(f"P{i:06d}" for i in range(a.rows)))
    formats.write_measurements(d / "big.csv", m)
    size = (d / "big.csv").stat().st_size / 1e6
    exe = Path(sys.executable).with_name("quickhealth")
    cmd = ["/usr/bin/time", "-v", str(exe), "identify", "predict", str(d / "model.json"),
           str(d / "big.csv"), "--out", str(d / "pred.csv"), "--threshold-mm", "1"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True)
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", r.stderr).group(1)
    print(r.stdout.strip().splitlines()[0] if r.stdout.strip() else r.stderr[-500:])
    print(
        f"predict on {a.rows} rows ({size:.0f} MB CSV): exit {r.returncode}, "
        f"max RSS {rss / 1024:.0f} MiB, wall {wall}"
    )
    lines = sum(1 for _ in open(d / "pred.csv")) - 1 if (d / "pred.csv").exists() else 0
    print(f"pred.csv rows: {lines}  (files in {d})")


if __name__ == "__main__":
    main()
