"""Benchmark: does the trend (and ``check --replay``) name each single fault right, on the twin?

For the UR5 and the UR10e twin (150 poses, camera 2 m away, 0.03 mm / 0.1 mrad): a baseline
run fitted as ``identify fit`` does (BIC orders), then a later run of the same plan with one
physical fault put into the twin's truth (:meth:`~quickhealth.identify.faults.Fault.raw_vector`),
at a size that moves the TCP by ``--tcp-mm`` (0.3 mm: the largest displacement over the
baseline's poses, set-up registered out), fitted at the baseline's orders as the archive
refits it.  Every fault the arm has is tried: each joint's zero offset, both tilts of its
axis, and the link length (a) and offset (d) where the arm has one, ``--repeats`` times each
with fresh noise, a fresh twin and a random sign.  Faults a self-referenced measurement cannot
see (joint 1's zero and tilts, d1, joint 6's zero and d6: the base's and the target's) are
listed and skipped.

The trend path is :func:`~quickhealth.identify.trend.assess_trend` on the two fits (what
``quickhealth trend`` runs on archived runs); the check path is
:func:`~quickhealth.station.services.replay.replay_check` on run folders (what ``quickhealth
check --replay`` runs).  Printed per robot and fault: flagged, named first right, and the size
within 2σ of the truth; "right" counts the fault itself, and separately a fault geometry
cannot tell from it (the same change, named by the prior: e.g. joint 6's tilt about y is joint
5's zero offset on a UR), listed as the named change's alternative.  Then ``--healthy``
repeats without a fault: false alarms of each path.

    .venv/bin/python benchmarks/fault_naming.py [--robots ur5,ur10e] [--repeats 4] [--healthy 200]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from quickhealth.identify import faults as F
from quickhealth.identify.fit import fit_model
from quickhealth.identify.robot import builtin_robot
from quickhealth.identify.select import select_orders
from quickhealth.identify.trend import RunState, assess_trend
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats
from quickhealth.station.services.checking import load_baseline
from quickhealth.station.services.replay import replay_check

KINDS = (F.FaultKind.ZERO, F.FaultKind.TILT_X, F.FaultKind.TILT_Y, F.FaultKind.LENGTH,
         F.FaultKind.OFFSET)  # fmt: skip


def _state(name, fitted, meas, t):  # type: ignore[no-untyped-def]
    n = fitted.spec.n_params
    return RunState(name, t, spec=fitted.spec, coeffs=fitted.coeffs, cov=fitted.cov[:n, :n],
                    model=fitted, poses=meas)  # fmt: skip


class Case:
    """One baseline of one twin: its fit, its folder and the faults' unit TCP sizes."""

    def __init__(self, robot, seed: int, d: Path) -> None:  # type: ignore[no-untyped-def]
        self.robot = robot
        self.twin = make_twin(robot, seed=seed)
        self.q = random_joints(robot, 150, seed=seed + 1, T_instr_base=self.twin.truth.T_instr_base)
        self.base_meas = self.twin.measure(self.q, seed=seed + 2)
        sel = select_orders(robot, self.base_meas)
        self.fitted, self.noise = sel.fitted, sel.noise
        self.folder = d / f"base-{robot.name}-{seed}"
        self.folder.mkdir(parents=True)
        formats.write_measurements(self.folder / "measurements.csv", self.base_meas)
        formats.write_model(self.folder / "model.json", self.fitted)
        self.images = F.fault_images(self.fitted, F.geometric_faults(robot), self.base_meas)
        self.seed = seed

    def run(self, fault: F.Fault | None, size: float, k: int, d: Path):  # type: ignore[no-untyped-def]
        """A later run (fault of ``size`` in the truth): trend's and replay's top change."""
        twin = self.twin
        if fault is not None:
            c = twin.truth.coeffs + size * fault.raw_vector(twin.truth.spec)
            twin = replace(twin, truth=replace(twin.truth, coeffs=c))
        meas = twin.measure(self.q, seed=self.seed * 1000 + 17 + k)
        fb = fit_model(self.robot, meas, self.fitted.spec, self.fitted.effects, self.noise,
                       self.fitted.prior)  # fmt: skip
        res = assess_trend([_state("A", self.fitted, self.base_meas, 0.0),
                            _state("B", fb, meas, 86400.0)])  # fmt: skip
        rec = d / f"rec-{self.robot.name}-{self.seed}-{k}-{fault.key if fault else 'none'}"
        rec.mkdir(parents=True)
        formats.write_measurements(rec / "measurements.csv", meas)
        chk = replay_check(rec, load_baseline(self.folder), rec / "check")
        trend_top = res.named_changes()[0] if res.named_changes() else None
        check_top = chk.status.named_changes()[0] if chk.changed and chk.status else None
        return bool(res.flags()), trend_top, chk.changed, check_top


def _judge(top, fault: F.Fault, size: float, images: F.FaultImages) -> tuple[bool, bool, bool]:  # type: ignore[no-untyped-def]
    """(named right, named right or as its geometric twin, size within 2σ: a twin's size is
    the true size carried over to it through the two faults' images)."""
    if top is None:
        return False, False, False
    right = top.fault == fault.key
    twin = right or any(
        a.fault == fault.key
        and abs(a.probability * top.prior - top.probability * a.prior)
        < 0.05 * top.probability * a.prior
        for a in top.alternatives
    )  # the same evidence: only the prior told them apart
    expect = size
    if twin and not right:
        keys = [f.key for f in images.faults]
        if top.fault in keys:
            g_true = images.G[:, images.columns[keys.index(fault.key)]][:, 0]
            g_top = images.G[:, images.columns[keys.index(top.fault)]][:, 0]
            expect = size * float(g_true @ g_top) / float(g_top @ g_top)
    within = (right or twin) and abs(top.size - expect) < 2 * top.sigma
    return right, twin, within


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="ur5,ur10e")
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--healthy", type=int, default=200, help="healthy repeats in all")
    ap.add_argument("--tcp-mm", type=float, default=0.3)
    args = ap.parse_args()
    t0 = time.perf_counter()
    robots = [builtin_robot(n) for n in args.robots.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        totals = {"trend": [0, 0, 0, 0, 0], "check": [0, 0, 0, 0, 0]}  # n, flagged, right, twin, 2σ
        for robot in robots:
            cases = [Case(robot, 11 + 7 * r, d) for r in range(args.repeats)]
            img = cases[0].images
            seen = {img.faults[k].key for k in img.testable()}
            faults = [f for f in img.faults if f.kind in KINDS and f.key in seen]
            blind = [f.key for f in img.faults if f.kind in KINDS and f.key not in seen]
            print(f"\n{robot.name}: {len(faults)} faults tried; not visible (set-up): "
                  f"{', '.join(blind)}")  # fmt: skip
            print(
                f"  {'fault':<11} {'size':>14}  trend: flag right twin 2σ   check: flag right "
                "twin 2σ"
            )
            for f in faults:
                row = {"trend": [0, 0, 0, 0], "check": [0, 0, 0, 0]}
                sizes = []
                for r, case in enumerate(cases):
                    k = case.images.faults.index(f)
                    unit = float(case.images.tcp[k])
                    sign = 1.0 if (r + zlib.crc32(f.key.encode())) % 2 else -1.0  # reproducible
                    size = sign * args.tcp_mm * 1e-3 / unit
                    sizes.append(abs(size))
                    flag, ttop, cflag, ctop = case.run(f, size, r, d)
                    for path, fl, top in (("trend", flag, ttop), ("check", cflag, ctop)):
                        right, twin, within = _judge(top, f, size, case.images)
                        row[path][0] += fl
                        row[path][1] += right
                        row[path][2] += twin
                        row[path][3] += within
                n = len(cases)
                unit, k = f.display
                print(
                    f"  {f.key:<11} {np.mean(sizes) * k:9.3f} {unit:<4}  "
                    + "   ".join(" ".join(f"{v}/{n}" for v in row[p]) for p in ("trend", "check"))
                )
                for p in ("trend", "check"):
                    totals[p][0] += n
                    for i in range(4):
                        totals[p][i + 1] += row[p][i]
        for p, (n, fl, right, twin, within) in totals.items():
            print(f"{p}: {n} faulted runs: flagged {fl} ({fl / n:.1%}), named right first "
                  f"{right} ({right / n:.1%}), right or its geometric twin {twin} ({twin / n:.1%}), "
                  f"size within 2σ {within} ({within / n:.1%})")  # fmt: skip
        # healthy repeats: fresh noise on baselines of every robot
        n_base = max(1, args.healthy // 20)
        fa_t = fa_c = done = 0
        for b in range(n_base):
            robot = robots[b % len(robots)]
            case = Case(robot, 500 + b, d)
            for k in range(args.healthy // n_base):
                flag, _, cflag, _ = case.run(None, 0.0, 100 + k, d)
                fa_t += flag
                fa_c += cflag
                done += 1
        print(
            f"healthy: {done} repeats over {n_base} baselines: trend flagged {fa_t}, "
            f"check --replay changed {fa_c} ({time.perf_counter() - t0:.0f} s in all)"
        )


if __name__ == "__main__":
    main()
