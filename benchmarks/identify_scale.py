"""Benchmark: how the whole ``identify fit``, ``diagnose`` and ``fit --effects`` processes grow
with the number of poses.

What a metrologist with a laser tracker waits for: whole processes (start-up, reading, the
order search, the workspace map, writing), their wall time and peak resident memory (the
process's own ``ru_maxrss`` from ``wait4``).  Data: the digital twin (``quickhealth twin``,
7D, 0.03 mm / 0.1 mrad) at 150, 1,000, 5,000, 10,000 and 20,000 poses, and the shared UR10
tracker series (fixtures/ipa-ur10, all 1,495 rows, as ``import tracker --preset ipa-ur10``
writes it), also resampled by pose to ``--real-rows`` (9,529, the size of the unseen series
that took 214 s) beside a twin of as many poses: the real fit must stay within 2× the twin's
(CPU time, printed; wall time follows the machine's load).  ``fit --effects`` adds three cyclic terms (cyclic:j1:h9, cyclic:j2:h17,
cyclic:j3:h5).  The growth exponent is the slope of log(time) against log(poses) from 1,000
to 20,000 (1 = linear).  Targets (issue "Fits that scale"): 10,000 poses fit ≤ 60 s and
≤ 1 GB, diagnose ≤ 30 s, fit --effects ≤ 60 s; 150 poses fit ≤ 1.0 s.

    .venv/bin/python benchmarks/identify_scale.py [--sizes 150,1000,5000,10000,20000] [--repeats 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
QH = [sys.executable, "-m", "quickhealth.station.cli"]
EFFECTS = "cyclic:j1:h9,cyclic:j2:h17,cyclic:j3:h5"
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


CPU: dict[str, list[float]] = {}  # label → CPU times (user + system) of its fits


def run(argv: list[str], label: str = "") -> tuple[float, float]:
    """Wall time (s) and peak resident memory (MB) of one whole process (its CPU time is kept
    in :data:`CPU` under ``label``)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    CPU.setdefault(label, []).append(usage.ru_utime + usage.ru_stime)
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        err = p.stderr.read().decode() if p.stderr else ""
        raise SystemExit(f"{' '.join(argv[3:])}: exit {p.returncode}: {err[-400:]}")
    return wall, usage.ru_maxrss / 1024.0


def cases(d: Path, sizes: list[int], real_rows: int) -> list[tuple[str, int, Path, str]]:
    """(label, poses, measurement file, robot) of every data set."""
    out = []
    if real_rows:
        sizes = sorted(set(sizes) | {real_rows})
    for n in sizes:
        f = d / f"twin{n}.csv"
        subprocess.run([*QH, "twin", "--n", str(n), "--seed", "5", "--out", str(f)], check=True,
                       stdout=subprocess.DEVNULL, env=ENV)  # fmt: skip
        out.append((f"twin {n}", n, f, "ur5"))
    ur10 = d / "ur10.csv"
    subprocess.run([*QH, "import", "tracker", str(ROOT / "fixtures/ipa-ur10/measurements_joint_configurations.csv"),
                    "--preset", "ipa-ur10", "--out", str(ur10)], check=True, stdout=subprocess.DEVNULL)  # fmt: skip
    out.append(("UR10 tracker (real)", 1495, ur10, str(ROOT / "fixtures/robots/ur10.toml")))
    if real_rows:  # the same series resampled by pose to a tracker night's size
        sys.path.insert(0, str(ROOT / "tests" / "helpers"))
        import qh_real as R

        from quickhealth.station import formats
        from quickhealth.station.formats.tracker import PRESETS, read_tracker

        m = read_tracker(R.UR10_FILE, PRESETS["ipa-ur10"])
        idx = np.sort(np.random.default_rng(0).choice(m.n_poses, real_rows, replace=True))
        big = d / f"ur10_{real_rows}.csv"
        formats.write_measurements(big, m.subset(idx))
        out.append((f"UR10 tracker (real), resampled to {real_rows:,} rows", real_rows, big,
                    str(ROOT / "fixtures/robots/ur10.toml")))  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="150,1000,5000,10000,20000")
    ap.add_argument("--repeats", type=int, default=1, help="runs per figure (median)")
    ap.add_argument("--real-rows", type=int, default=9529,
                    help="the UR10 series resampled by pose to this many rows (0: none)")  # fmt: skip
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for label, n, f, robot in cases(d, sizes, args.real_rows):
            fig: dict[str, tuple[float, float]] = {}
            for what in ("fit", "diagnose", "fit --effects"):
                out = d / f"{label.replace(' ', '_')}_{what.replace(' ', '_')}"
                if what == "diagnose":
                    argv = [*QH, "diagnose", str(d / f"{label.replace(' ', '_')}_fit" / "model.json"),
                            str(f), "--json", str(out) + ".json", "--quiet"]  # fmt: skip
                else:
                    argv = [
                        *QH,
                        "identify",
                        "fit",
                        str(f),
                        "--robot",
                        robot,
                        "--out",
                        str(out),
                        "--quiet",
                        "--force",
                    ]
                    argv += ["--effects", EFFECTS] if what == "fit --effects" else []  # fmt: skip
                runs = [run(argv, f"{label} {what}") for _ in range(args.repeats)]
                fig[what] = (statistics.median(w for w, _ in runs), max(m for _, m in runs))
            rows.append((label, n, fig))
            print(
                f"{label:>20}: fit {fig['fit'][0]:7.1f} s {fig['fit'][1]:6.0f} MB | diagnose "
                f"{fig['diagnose'][0]:6.1f} s {fig['diagnose'][1]:6.0f} MB | fit --effects "
                f"{fig['fit --effects'][0]:6.1f} s {fig['fit --effects'][1]:6.0f} MB",
                flush=True,
            )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print()
    print(
        "| data | poses | fit (s) | fit peak (MB) | diagnose (s) | diagnose peak (MB) | fit --effects (s) | --effects peak (MB) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, n, fig in rows:
        print(f"| {label} | {n:,} | {fig['fit'][0]:.1f} | {fig['fit'][1]:.0f} | {fig['diagnose'][0]:.1f} | "
              f"{fig['diagnose'][1]:.0f} | {fig['fit --effects'][0]:.1f} | {fig['fit --effects'][1]:.0f} |")  # fmt: skip
    if args.real_rows:
        t, r = (
            f"twin {args.real_rows} fit",
            [k for k in CPU if k.startswith("UR10") and "resampled" in k and k.endswith(" fit")],
        )
        if t in CPU and r:
            ct, cr = statistics.median(CPU[t]), statistics.median(CPU[r[0]])
            print(f"real / twin at {args.real_rows:,} rows, identify fit: CPU {cr:.1f} s / {ct:.1f} s = "
                  f"{cr / ct:.2f} x (target: at most 2 x)")  # fmt: skip
    twin = [(n, fig) for label, n, fig in rows if label.startswith("twin") and n >= 1000]
    if len(twin) >= 2:
        x = np.log([n for n, _ in twin])
        for what in ("fit", "diagnose", "fit --effects"):
            y = np.log([fig[what][0] for _, fig in twin])
            print(
                f"growth exponent of {what} from {twin[0][0]:,} to {twin[-1][0]:,} poses: {np.polyfit(x, y, 1)[0]:.2f}"
            )


if __name__ == "__main__":
    main()
