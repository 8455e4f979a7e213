"""Compensation with every effect: the twin runs a compensated reference program (issue 15).

For the geometric case and each effect family, :func:`quickhealth.identify.compensate_trial.
run_trial`: a twin UR5 (random geometric and position-dependent joint errors, camera 2 m away,
noise 0.03 mm and 0.1 mrad per axis) hides the effect and is measured at the reference cell's
measurement plan (``plan --cell reference``, seed 0: the poses ``quickhealth run`` would
visit), in plan order, over 900 s warming from 21 to 27 °C; ``select_orders`` (what
``identify fit`` runs) fits the joint model and the model with the effect; a second
reference plan (seed 1) is the program, compensated and run by the twin at 30 °C and 900 s.

Columns (remaining TCP position error, mean / max over the program's targets, mm):
``none`` the program as written; ``joint model`` compensated by the fit without the effect;
``left out`` by the fit with the effect, the effect left out of the compensation; ``with
effect`` by the fit with the effect; ``allowance`` what the instrument noise allows: the
same trial on the paired twin without the effect (same errors, poses, noise draws),
compensated by its joint model, widened by the TCP uncertainty the effect's own parameters
add (propagated from the fit's covariance; ``effect σ``); ``ratio`` with effect / allowance
(acceptance: ≤ 1.3 for the mean and the max); ``σ fit`` the RMS TCP uncertainty of the
model with the effect propagated from its covariance (parameter noise alone; the paired
result adds the sub-noise joint terms the BIC search leaves out).  A second table gives the
rotation errors (mrad; the allowance column there is the paired result).  With several
seeds the last lines count the ratios above 1.3 per family.

Run: ``.venv/bin/python benchmarks/compensate_effects.py [--seeds 11,12,13] [--program-n 120]``
"""

from __future__ import annotations

import argparse
import os
import time
from importlib import resources

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from quickhealth.identify.compensate_trial import (  # noqa: E402
    FAMILIES,
    TRIAL_TEMP_C,
    TRIAL_TIME_S,
    TcpErrors,
    TrialRow,
    run_trial,
)


def reference_plans(n_train: int = 300, n_program: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Joint targets (rad) of the reference cell's measurement plan (seed 0) and of a second
    plan used as the program (seed 1), each in plan order."""
    from quickhealth.station.planning import load_cell, plan_loop

    cell = load_cell(str(resources.files("quickhealth.station.data") / "reference_cell.toml"))
    q_train = np.array([p.q for p in plan_loop(cell, n_train, seed=0).poses])
    q_prog = np.array([p.q for p in plan_loop(cell, n_program, seed=1).poses])
    return q_train, q_prog


def _cell(e: TcpErrors | None, rot: bool = False) -> str:
    if e is None:
        return f"{'-':>15}"
    a, b = (e.mean_rot, e.max_rot) if rot else (e.mean_pos, e.max_pos)
    return f"{a * 1e3:7.4f}/{b * 1e3:7.4f}"


def table(rows: list[TrialRow]) -> list[str]:
    """The two tables (position mm, rotation mrad) as lines."""
    head = (
        f"{'effect':<21}{'none':>16}{'joint model':>16}{'left out':>16}{'with effect':>16}"
        f"{'allowance':>16}{'ratio':>11}{'effect σ':>9}{'σ fit':>8}"
    )
    out = ["remaining TCP position error, mean/max (mm)", head]
    for r in rows:
        ratio = "-" if r.ratio is None else f"{r.ratio[0]:.2f}/{r.ratio[1]:.2f}"
        cells = [_cell(x) for x in (r.uncompensated, r.joint_model, r.left_out, r.with_effect)]
        allow = f"{r.allowance_mean_pos * 1e3:7.4f}/{r.allowance_max_pos * 1e3:7.4f}"
        out.append(
            f"{r.effect or 'geometric':<21} "
            + " ".join(cells)
            + f" {allow}{ratio:>11}{r.effect_sigma * 1e3:9.4f}{r.sigma_fit * 1e3:8.4f}"
        )
    out += [
        "",
        "remaining TCP rotation error, mean/max (mrad)",
        head[:101].replace("allowance", "   paired"),
    ]
    for r in rows:
        cells = [
            _cell(x, rot=True)
            for x in (r.uncompensated, r.joint_model, r.left_out, r.with_effect, r.paired)
        ]
        out.append(f"{r.effect or 'geometric':<21} " + " ".join(cells))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="11", help="twin seeds, comma-separated (11)")
    ap.add_argument("--train-n", type=int, default=300, help="targets drawn for the plan (300)")
    ap.add_argument("--program-n", type=int, default=120, help="targets drawn for the program")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    q_train, q_prog = reference_plans(args.train_n, args.program_n)
    print(
        f"measurement plan: {len(q_train)} poses; program: {len(q_prog)} targets; run at "
        f"{TRIAL_TEMP_C:g} °C, {TRIAL_TIME_S:g} s ({time.perf_counter() - t0:.1f} s to plan)"
    )
    over: dict[str, list[str]] = {}
    worst = 0.0
    for seed in (int(s) for s in args.seeds.split(",")):
        t1 = time.perf_counter()
        rows = [
            run_trial(e, s, q_train, q_prog, seed=seed, withhold_masses=w) for e, s, w in FAMILIES
        ]
        n = sorted({r.n_targets for r in rows})
        print(
            f"\nseed {seed}: {n[0]}–{n[-1]} targets compensated (the others refused by "
            f"'compensate' with one of the models), {time.perf_counter() - t1:.1f} s"
        )
        print("\n".join(table(rows)))
        for r in rows:
            if r.ratio is not None:
                worst = max(worst, *r.ratio)
                for what, v in zip(("mean", "max"), r.ratio, strict=True):
                    if v > 1.3:
                        over.setdefault(str(r.effect), []).append(f"seed {seed} {what} {v:.2f}")
    print(f"\nworst ratio with effect / allowance (mean or max): {worst:.2f} (acceptance ≤ 1.3)")
    for eff, items in over.items():
        print(f"  above 1.3: {eff}: {', '.join(items)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
