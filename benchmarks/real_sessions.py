"""Benchmark: monitoring a real robot across two sessions, through the command line.

The shared UR10 series split by goal pose into two sessions of 600 rows each (only the
fitting part of the held-out split; tests/helpers/qh_real.py ``ur10_sessions``): the same
robot measured twice on different poses.  As a user runs it:

1. ``identify fit`` each session in its own run folder (measurements.csv beside model.json);
2. ``archive add`` session A (the baseline), then session B; ``trend``: must be healthy;
3. ``check --replay B --baseline A``: must be unchanged;
4. session B again with the ``q2`` (then ``q3``, ``q5``) column raised by 0.3 mrad
   (0.0171887°, a zero shift of −0.3 mrad: true angle − reading): ``trend`` and
   ``check --replay`` must flag it and name that joint's zero offset, size within 2σ.

Printed: each command's verdict, its named changes (fault, size ± σ, z, p) and the figures.

    .venv/bin/python benchmarks/real_sessions.py [--shifts 2,3,5]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

import qh_real as R  # noqa: E402

from quickhealth.station import formats  # noqa: E402

QH = [sys.executable, "-m", "quickhealth.station.cli"]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
SHIFT = 3e-4  # rad


def qh(*args: str, ok: tuple[int, ...] = (0,)) -> tuple[int, str, float]:
    """Run one command: exit status, stdout, wall time."""
    t0 = time.perf_counter()
    p = subprocess.run([*QH, *args], capture_output=True, text=True, env=ENV)
    if p.returncode not in ok:
        raise SystemExit(f"quickhealth {' '.join(args)}: exit {p.returncode}: {p.stderr[-800:]}")
    return p.returncode, p.stdout, time.perf_counter() - t0


def session(d: Path, name: str, meas, time_utc: str) -> Path:  # type: ignore[no-untyped-def]
    run = d / name
    run.mkdir(parents=True)
    formats.write_measurements(run / "measurements.csv", meas)
    _, _, t = qh("identify", "fit", str(run / "measurements.csv"), "--robot", str(R.UR10_ROBOT),
                 "--out", str(run), "--quiet")  # fmt: skip
    print(f"  fit {name}: {t:.1f} s")
    return run


def trend(d: Path, base: Path, run: Path, robot: str) -> tuple[int, dict, str]:  # type: ignore[type-arg]
    arch = str(d / "arch")
    qh("archive", "add", str(base), "--robot", robot, "--archive", arch,
       "--time", "2020-11-01T00:00:00Z")  # fmt: skip
    qh("archive", "add", str(run), "--robot", robot, "--archive", arch,
       "--time", "2020-11-02T00:00:00Z")  # fmt: skip
    js = d / f"{robot}.json"
    code, out, _ = qh("trend", robot, "--archive", arch, "--json", str(js), ok=(0, 1))
    return code, json.loads(js.read_text()), out


def replay(d: Path, base: Path, run: Path, name: str) -> tuple[int, dict]:  # type: ignore[type-arg]
    out = d / f"check-{name}"
    code, _, t = qh("check", "--replay", str(run), "--baseline", str(base), "--out", str(out),
                    ok=(0, 1))  # fmt: skip
    return code, json.loads((out / "check.json").read_text())


def show(label: str, code: int, changes: list, truth: float | None, key: str | None) -> bool:  # type: ignore[type-arg]
    top = changes[0] if changes else None
    if top is None:
        words = "no change named"
    elif top.get("fault") is None:  # the check's omnibus: a change no single fault describes
        words = f"{top['words']} ({top['probability']:.0%} of the evidence)"
    else:
        words = (f"{top['fault']}: {top['size']:+.3f} ± {top['sigma']:.3f} {top['size_unit']} "
                 f"(z = {top['z']:+.1f}, p = {top['p_value']:.1e})")  # fmt: skip
    if key is None:
        ok = code == 0 and not changes
    else:
        ok = (code == 1 and top is not None and top["fault"] == key
              and abs(top["size"] - truth) < 2 * top["sigma"])  # fmt: skip
    print(f"  {label:<34} exit {code}  {words}  {'OK' if ok else 'NOT AS REQUIRED'}")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shifts", default="2,3,5", help="joints whose reading is raised")
    args = ap.parse_args()
    a, b = R.ur10_sessions()
    print(f"sessions: A {a.n_poses} rows, B {b.n_poses} rows (shared UR10 series, by goal pose)")
    good = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        ra = session(d, "A", a, "2020-11-01")
        rb = session(d, "B", b, "2020-11-02")
        code, doc, out = trend(d, ra, rb, "ur10-same")
        for line in out.splitlines():
            if "figures are over" in line or line.startswith("  A ") or line.startswith("  B "):
                print("   ", line.strip())
        good.append(show("trend, unchanged", code, doc["changes"], None, None))
        code, cj = replay(d, ra, rb, "same")
        good.append(show("check --replay, unchanged", code, cj["changes"], None, None))
        print(f"    check: {cj['poses']} poses, {cj['robot_time_s']:.0f} s of robot time")
        for j in [int(x) for x in args.shifts.split(",") if x]:
            q = b.q.copy()
            q[:, j - 1] += SHIFT
            rj = session(d, f"B_q{j}", replace(b, q=q), "2020-11-02")
            code, doc, _ = trend(d, ra, rj, f"ur10-q{j}")
            good.append(show(f"trend, q{j} +0.3 mrad", code, doc["changes"], -0.3, f"j{j}.zero"))
            code, cj = replay(d, ra, rj, f"q{j}")
            good.append(show(f"check --replay, q{j} +0.3 mrad", code, cj["changes"], -0.3,
                             f"j{j}.zero"))  # fmt: skip
            print(f"    check: {cj['poses']} poses, {cj['robot_time_s']:.0f} s of robot time")
    print(f"{sum(good)} of {len(good)} as required")


if __name__ == "__main__":
    main()
