"""Benchmark: the user's path through the command line on every real data set in ../shared/real.

For each set, as a user types it: import (``import tracker --preset ipa-ur10`` /
``identify import-wam``), ``identify fit`` on the fitting part, ``diagnose``, ``identify fit
--effects`` with what diagnose suggests, and ``identify predict`` on the held-out part; also
the classic kinematic calibration (``identify fit --max-order 0``: the constant, geometric
model) on the same split.  Nothing is fitted, selected or tuned on a held-out row.

Splits: the UR10 T-Mac series by goal pose, every fifth goal held out (tests/helpers/qh_real.py,
docs/identify.md); the WAM as published (grid.csv fitted, random.csv held out).  The Doosan
ChArUco set has no joint readings (camera images and tool poses): it is the vision tests'
set and has no assessment to run (printed as such).

Printed: one row per model: held-out mean / RMS / max |measured − model| (mm), the health
figure (workspace TCP error mean against the registered nominal robot, mm), band95
coverage of the held-out rows, and the wall time of the fit.

    .venv/bin/python benchmarks/real_data.py [--real ../shared/real]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

import qh_real as R  # noqa: E402

QH = [sys.executable, "-m", "quickhealth.station.cli"]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def qh(*args: str) -> tuple[float, str]:
    """Run one command; its wall time and stdout (exit status must be 0)."""
    t0 = time.perf_counter()
    p = subprocess.run([*QH, *args], capture_output=True, text=True, env=ENV)
    if p.returncode != 0:
        raise SystemExit(f"quickhealth {' '.join(args)}: exit {p.returncode}: {p.stderr[-500:]}")
    return time.perf_counter() - t0, p.stdout


def held_out(pred: Path) -> dict[str, float]:
    with open(pred, newline="") as f:
        rows = list(csv.DictReader(f))
    e = np.array([float(r["meas_minus_model_mm"]) for r in rows])
    b = np.array([float(r["band95_mm"]) for r in rows])
    return {
        "mean": e.mean(),
        "rms": float(np.sqrt(np.mean(e**2))),
        "max": e.max(),
        "cover": float(np.mean(e <= b)),
    }


def user_path(name: str, d: Path, train: Path, held: Path, robot: str) -> list[tuple[str, ...]]:
    """fit, diagnose, fit with the advice, predict; and the classic calibration.  Full-pose
    data are also fitted position only (the same rows' x, y, z): the 6-DoF fit must never be
    worse than that (issue 31)."""
    from quickhealth.station import formats

    rows = []
    meas = formats.read_measurements(train, formats.load_robot(robot).n_joints)
    runs = [("classic kinematic calibration (--max-order 0)", "classic", ["--max-order", "0"], train),
            ("identify fit (defaults)", "fit", [], train)]  # fmt: skip
    if meas.has_orientation:
        pos = d / "train_xyz.csv"
        formats.write_measurements(pos, meas.position_only())
        runs += [(f"{label}, position only (the same rows)", f"{out}_xyz", extra, pos)
                 for label, out, extra, _ in runs]  # fmt: skip
    for label, out, extra, data in runs:
        t, _ = qh(
            "identify",
            "fit",
            str(data),
            "--robot",
            robot,
            "--out",
            str(d / out),
            "--quiet",
            *extra,
        )
        qh(
            "identify",
            "predict",
            str(d / out / "model.json"),
            str(held),
            "--out",
            str(d / f"{out}.csv"),
        )
        rep = json.loads((d / out / "report.json").read_text())
        rows.append((name, label, held_out(d / f"{out}.csv"), rep["workspace"]["mean_mm"], t))
    td, _ = qh(
        "diagnose",
        str(d / "fit" / "model.json"),
        str(train),
        "--json",
        str(d / "diag.json"),
        "--quiet",
    )
    advice = json.loads((d / "diag.json").read_text())["suggested"]
    if advice:
        t, _ = qh("identify", "fit", str(train), "--robot", robot, "--out", str(d / "advised"), "--quiet",
                  "--effects", ",".join(advice))  # fmt: skip
        qh(
            "identify",
            "predict",
            str(d / "advised" / "model.json"),
            str(held),
            "--out",
            str(d / "advised.csv"),
        )
        rep = json.loads((d / "advised" / "report.json").read_text())
        rows.append((name, f"+ diagnose's advice ({', '.join(advice)})", held_out(d / "advised.csv"),
                     rep["workspace"]["mean_mm"], t))  # fmt: skip
    print(f"{name}: diagnose {td:.1f} s, suggested {advice or 'nothing'}", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real")
    args = ap.parse_args()
    real = args.real
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows: list[tuple[str, ...]] = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for folder in sorted(p for p in real.iterdir() if p.is_dir()) if real.is_dir() else []:
            if folder.name == "ipa-ur10":
                u = d / "ur10"
                u.mkdir()
                qh("import", "tracker", str(folder / "measurements_joint_configurations.csv"),
                   "--preset", "ipa-ur10", "--out", str(u / "all.csv"))  # fmt: skip
                train, held = R.write_ur10_split(
                    u, folder / "measurements_joint_configurations.csv"
                )
                rows += user_path("UR10 T-Mac (ipa-ur10)", u, train, held, str(R.UR10_ROBOT))
            elif folder.name == "wam-laser-tracker":
                w = d / "wam"
                w.mkdir()
                qh("identify", "import-wam", str(folder / "grid.csv"), "--robot", str(R.WAM_ROBOT),
                   "--out", str(w / "grid.csv"))  # fmt: skip
                qh(
                    "identify",
                    "import-wam",
                    str(folder / "random.csv"),
                    "--sign",
                    "+1",
                    "--out",
                    str(w / "random.csv"),
                )
                rows += user_path(
                    "Barrett WAM", w, w / "grid.csv", w / "random.csv", str(R.WAM_ROBOT)
                )
            else:
                print(f"{folder.name}: no joint readings (camera images and tool poses): the vision "
                      "tests' set, no assessment to run")  # fmt: skip
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print()
    print(
        "| data | model | held-out mean / RMS / max (mm) | health figure (mm) | band95 coverage | fit (s) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for name, label, h, health, t in rows:
        print(f"| {name} | {label} | {h['mean']:.3f} / {h['rms']:.3f} / {h['max']:.3f} | {health:.3f} | "
              f"{100 * h['cover']:.1f} % | {t:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
