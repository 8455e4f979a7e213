"""Benchmark: a whole ``quickhealth identify fit`` process on 150 full-pose poses.

What a user waits for, start-up (imports) included: the median wall time of several whole
processes, without plots and with ``--plots``.  Targets on the 2-core station PC: ≤ 1.0 s
without plots, ≤ 3 s with.  The data are the digital twin's (``quickhealth twin``, seed 0).

    .venv/bin/python benchmarks/identify_fit_process.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

QH = [sys.executable, "-m", "quickhealth.station.cli"]


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        meas = Path(tmp) / "meas.csv"
        subprocess.run(
            [*QH, "twin", "--n", "150", "--seed", "0", "--out", str(meas)],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        fit = [*QH, "identify", "fit", str(meas), "--robot", "ur5", "--quiet"]
        timed([*fit, "--out", f"{tmp}/warm"])  # file cache warm, .pyc written
        for label, extra, target in (
            ("without plots", [], 1.0),
            ("with --plots", ["--plots"], 3.0),
        ):
            t = [timed([*fit, "--out", f"{tmp}/o{i}", *extra]) for i in range(args.repeats)]
            print(
                f"identify fit, 150 full-pose poses, {label}: median {statistics.median(t):.2f} s "
                f"of {args.repeats} processes (min {min(t):.2f}, max {max(t):.2f}; target ≤ {target} s)"
            )


if __name__ == "__main__":
    main()
