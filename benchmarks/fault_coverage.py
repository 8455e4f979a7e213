"""Benchmark: is the trend's change test honest on a real robot?  Coverage over repeated sessions.

The shared UR10 series' fitting part (tests/helpers/qh_real.py; the held-out rows are never
used) is split at random by goal pose into two sessions of one robot, ``--splits`` times.
Each pair goes through the trend's own code (:func:`quickhealth.identify.trend.assess_trend`
on the two fits, the first fitted by the BIC search as ``identify fit`` does, the second at
its orders as the archive refits it), unchanged and with session B's ``q2``, ``q3``, ``q5``
readings raised by 0.3 mrad.

Printed:

- coverage of the faults' z under no change: the share beyond 1.96, 2.58 and 3.29 (5 %, 1 %,
  0.1 % if honest) and the mean z², with the scale λ as a trend of two runs estimates it and
  as a long history pools it (median over all comparisons); the fits' own covariances
  (``--plain``) for comparison;
- false alarms: unchanged pairs flagged (a named fault or a curve change);
- the injected zero shifts: flagged and named as that joint's zero offset, and the share
  whose size lies within 2σ of the truth (−0.3 mrad).

    .venv/bin/python benchmarks/fault_coverage.py [--splits 30] [--plain]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

import qh_real as R  # noqa: E402

from quickhealth.identify import fault_test as FT  # noqa: E402
from quickhealth.identify.fit import fit_model  # noqa: E402
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.identify.trend import RunState, assess_trend  # noqa: E402
from quickhealth.station import formats  # noqa: E402
from quickhealth.station.formats.tracker import PRESETS, read_tracker  # noqa: E402

SHIFT = 3e-4
CHI2_1 = FT.CHI2_1_MEDIAN


def _state(name, fitted, meas, t, plain):  # type: ignore[no-untyped-def]
    n = fitted.spec.n_params
    return RunState(name, t, spec=fitted.spec, coeffs=fitted.coeffs, cov=fitted.cov[:n, :n],
                    model=fitted, poses=None if plain else meas)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--splits", type=int, default=30)
    ap.add_argument("--plain", action="store_true", help="the fits' own covariances")
    args = ap.parse_args()
    robot = formats.load_robot(str(R.UR10_ROBOT))
    meas = read_tracker(R.UR10_FILE, PRESETS["ipa-ur10"])
    goals = R.ur10_goal_groups()
    fit_rows = goals % R.HELD_EVERY != R.HELD_EVERY - 1
    fit_goals = np.unique(goals[fit_rows])
    null_raw, lams, alarms, shifted = [], [], 0, {2: [], 3: [], 5: []}
    resid_p: list[float] = []
    t0 = time.perf_counter()
    for s in range(args.splits):
        rng = np.random.default_rng(100 + s)
        side = dict(zip(fit_goals, rng.permutation(np.arange(fit_goals.size) % 2), strict=True))
        sess = np.array([side[g] if f else -1 for g, f in zip(goals, fit_rows, strict=True)])
        a = meas.subset(np.flatnonzero(sess == 0))
        b = meas.subset(np.flatnonzero(sess == 1))
        sel = select_orders(robot, a)
        fa = sel.fitted
        for joint in (0, 2, 3, 5):
            bq = b
            if joint:
                q = b.q.copy()
                q[:, joint - 1] += SHIFT
                bq = replace(b, q=q)
            fb = fit_model(robot, bq, fa.spec, fa.effects, sel.noise, fa.prior)
            res = assess_trend(
                [_state("A", fa, a, 0.0, args.plain), _state("B", fb, bq, 86400.0, args.plain)]
            )
            test = res.fault_tests[1]
            if joint == 0:
                lam = test.scale
                lams.append(lam)
                null_raw.append(np.array(test.null_z2) * lam)  # z² at λ = 1
                resid_p.append(test.residual_p)
                alarms += bool(res.flags())
                if res.flags():
                    print(f"  split {s}: false alarm: {res.flags()[0][:120]}")
            else:
                top = test.significant[0] if test.significant else None
                named = top is not None and top.fault == f"j{joint}.zero"
                within = named and abs(top.size + SHIFT) < 2 * top.sigma
                shifted[joint].append((named, within))
        print(f"split {s + 1}/{args.splits}: λ {lams[-1]:.2f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip

    def cover(z2: np.ndarray, label: str) -> None:
        z = np.sqrt(z2)
        print(f"  {label:<44} mean z² {np.mean(z2):.2f}; |z| > 1.96: {np.mean(z > 1.96):.1%}, "
              f"> 2.58: {np.mean(z > 2.58):.1%}, > 3.29: {np.mean(z > 3.29):.2%}; "
              f"max {z.max():.2f}")  # fmt: skip

    raw = np.concatenate(null_raw)
    pooled = max(1.0, float(np.median(raw)) / CHI2_1)
    print(f"\n{args.splits} splits, {raw.size} fault statistics under no change "
          f"({'fits own covariances' if args.plain else 'robust covariances'})")  # fmt: skip
    cover(raw, "λ = 1")
    cover(np.concatenate([z / lam for z, lam in zip(null_raw, lams, strict=True)]),
          f"λ of each comparison (median {np.median(lams):.2f})")  # fmt: skip
    cover(raw / pooled, f"λ pooled over the {args.splits} comparisons ({pooled:.2f})")
    print(f"  false alarms (unchanged pairs flagged): {alarms} of {args.splits}")
    rp = np.array(resid_p)
    print(
        f"  what no fault explains (residual χ², p): below 0.05 in {np.mean(rp < 0.05):.0%}, "
        f"below 1e-4 in {np.mean(rp < 1e-4):.0%} of the unchanged pairs"
    )
    for j, rows in shifted.items():
        named = sum(n for n, _ in rows)
        within = sum(w for _, w in rows)
        print(f"  q{j} +0.3 mrad: flagged and named j{j}.zero in {named} of {len(rows)}, "
              f"size within 2σ in {within} of {len(rows)}")  # fmt: skip


if __name__ == "__main__":
    main()
