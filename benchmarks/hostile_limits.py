"""Issue 32's loaders and limits under attack: wall time and peak memory of each refusal.

Builds, in a temporary folder, the inputs issue 32's probe used and runs the installed
``quickhealth`` on each under ``/usr/bin/time -v`` (memory capped at 3 GB, as the probe did):

- a 940-byte calibration YAML of nested aliases (a "billion laughs"), in a segment's value and
  in ``hash:`` (``identify fit --calibration``);
- a 57 MiB model.json (inside the 64 MiB limit) whose unknown key holds 20 M empty objects
  (``identify predict`` and ``trend`` of an archive holding it);
- an archived run of 200 004 rows (``reprocess``; ``identify fit`` of the same file beside it);
- the costliest JSON shapes just inside the value budget (3 M values), parsed by the one JSON
  loader: what the budget allows at most.

Prints one line per case: exit status, wall time, max RSS.  Run:
``nice -n 10 .venv/bin/python benchmarks/hostile_limits.py`` (about two minutes).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats

EXE = str(Path(sys.executable).with_name("quickhealth"))
SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
SEG = "{x: 0, y: 0, z: 0.1625, roll: 0, pitch: 0, yaw: 0}"


def timed(label: str, argv: list[str], cwd: Path) -> None:
    """Run ``argv`` under /usr/bin/time -v with a 3 GB address-space cap; print one line."""
    cmd = ["bash", "-c", 'ulimit -v 3000000; exec /usr/bin/time -v "$@"', "_", *argv]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", r.stderr).group(1)
    said = [x for x in r.stderr.splitlines() if x.startswith("quickhealth")][:1]
    said += [x for x in r.stdout.splitlines() if "FAILED" in x][:1]
    print(f"{label}: exit {r.returncode}, wall {wall}, max RSS {rss / 1024:.0f} MiB")
    if said:
        print(f"    {said[0][:160]}")


def alias_bomb(where: str) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    kin = dict.fromkeys(SEGMENTS, SEG)
    if where == "hash":
        kin["hash"] = "*a8"
    else:
        kin["shoulder"] = SEG.replace("x: 0", "x: *a8")
    return "\n".join(lines) + "\nkinematics:\n" + "".join(f"  {k}: {v}\n" for k, v in kin.items())


def main() -> None:
    d = Path(tempfile.mkdtemp(prefix="qh-hostile-limits-"))
    twin = make_twin(seed=2)
    q = random_joints(twin.robot, 60, seed=3, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=4)
    spec = ErrorModelSpec.uniform(6, 1, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, meas, spec, noise=InstrumentNoise(3e-5, 1e-4))
    formats.write_model(d / "model.json", fm)
    formats.write_measurements(d / "meas.csv", meas)

    for where in ("value", "hash"):
        (d / f"bomb_{where}.yaml").write_text(alias_bomb(where))
        size = (d / f"bomb_{where}.yaml").stat().st_size
        timed(
            f"identify fit --calibration ({size}-byte alias bomb in {where})",
            [EXE, "identify", "fit", "meas.csv", "--robot", "ur5", "--calibration",
             f"bomb_{where}.yaml", "--out", f"out_{where}", "--quiet"], d,
        )  # fmt: skip

    text = (d / "model.json").read_text().rstrip()
    with open(d / "big_model.json", "w") as fh:
        fh.write(text[:-1] + ', "padding": [' + "{}," * (20_000_000 - 1) + "{}]}\n")
    mib = (d / "big_model.json").stat().st_size / 2**20
    timed(f"identify predict ({mib:.0f} MiB model.json, 20 M empty objects)",
          [EXE, "identify", "predict", "big_model.json", "meas.csv", "--out", "p.csv"], d)  # fmt: skip

    subprocess.run([EXE, "identify", "fit", "meas.csv", "--robot", "ur5", "--out", "r1",
                    "--quiet"], cwd=d, check=True, capture_output=True)  # fmt: skip
    big = d / "r2"
    subprocess.run(["cp", "-r", str(d / "r1"), str(big)], check=True)
    lines = (d / "meas.csv").read_text().splitlines()
    body = [x for x in lines if not x.startswith("#")]
    rows = body[1:]
    (big / "measurements.csv").write_text(
        "\n".join([body[0]] + [rows[i % len(rows)] for i in range(200_004)]) + "\n"
    )
    (d / "r1" / "measurements.csv").write_text((d / "meas.csv").read_text())
    for run, robot in (("r1", "cell3"), ("r2", "big")):
        subprocess.run([EXE, "archive", "add", run, "--robot", robot, "--archive", "arch",
                        "--time", "2026-01-01T00:00:00Z"], cwd=d, check=True,
                       capture_output=True)  # fmt: skip
    timed("reprocess (an archived run of 200 004 rows)",
          [EXE, "reprocess", "big", "--archive", "arch", "--workers", "1"], d)  # fmt: skip
    timed("identify fit (the same 200 004 rows)",
          [EXE, "identify", "fit", "r2/measurements.csv", "--robot", "ur5", "--out", "r3",
           "--quiet"], d)  # fmt: skip
    archived = d / "arch" / "robots" / "cell3" / "r1" / "model.json"
    archived.write_bytes((d / "big_model.json").read_bytes())
    timed("trend (the archived model.json is the 57 MiB one)",
          [EXE, "trend", "cell3", "--archive", "arch"], d)  # fmt: skip

    n = 2_999_990
    shapes = {
        "empty objects": lambda: "[" + "{}," * (n // 2 - 1) + "{}]",
        "distinct keys": lambda: "{" + ",".join(f'"k{i:07d}":0' for i in range(n)) + "}",
        "floats": lambda: "[" + ",".join(f"{i * 1.0000001:.17g}" for i in range(n)) + "]",
    }
    for name, make in shapes.items():
        p = d / f"budget_{name.replace(' ', '_')}.json"
        p.write_text(make())
        code = f"from quickhealth.station.formats import load_json_limited; load_json_limited({str(p)!r}, 'model')"  # noqa: E501
        timed(f"load_json_limited, 3 M {name} ({p.stat().st_size / 2**20:.0f} MiB)",
              [sys.executable, "-c", code], d)  # fmt: skip
    shutil.rmtree(d)


if __name__ == "__main__":
    main()
