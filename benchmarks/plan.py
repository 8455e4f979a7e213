"""Time `quickhealth plan` on the reference cell (issue 4, acceptance 5; target ≤ 20 s for N = 150).

    .venv/bin/python benchmarks/plan.py [--n 150] [--seed 0] [--repeat 1]

Prints the wall time of the planner itself (steps 1–5), of writing plan.json + loop.script,
and of the Fig. 6 plots, plus the plan summary and the machine's load average.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from quickhealth.station.planning.cell import load_cell
from quickhealth.station.planning.figures import write_figures
from quickhealth.station.planning.planfile import dumps, plan_from_dict, plan_to_dict
from quickhealth.station.planning.planner import plan_loop
from quickhealth.station.planning.urscript import render_urscript


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--n", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    cell = load_cell("reference")
    for r in range(args.repeat):
        t0 = time.perf_counter()
        res = plan_loop(cell, args.n, args.seed + r)
        t1 = time.perf_counter()
        doc = plan_to_dict(res)
        script = render_urscript(plan_from_dict(doc))
        with tempfile.TemporaryDirectory() as d:
            Path(d, "plan.json").write_text(dumps(doc))
            Path(d, "loop.script").write_text(script)
            t2 = time.perf_counter()
            write_figures(res, Path(d))
            t3 = time.perf_counter()
        print(f"plan N={args.n} seed={args.seed + r} on the reference cell:")
        for line in res.summary():
            print(f"  {line}")
        print(
            f"  time: planner {t1 - t0:.2f} s (target <= 20 s), files {t2 - t1:.2f} s, plots {t3 - t2:.2f} s"
        )
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
