"""Compliance without inertial data: the lumped form against the fit that knows the masses.

The digital twin (a UR5 with random geometric and position-dependent joint errors, camera 2 m
away, noise 0.03 mm and 0.1 mrad) hides ``compliance:j2`` or ``compliance:j3`` (mass form, the
UR5's published masses); 150 training poses (7D), 300 held-out.  Orders are selected by BIC
(``select_orders``, as ``identify fit`` does) three times: with the masses and
``compliance:jK`` (mass form); with the masses withheld and ``compliance:jK`` (which falls back
to ``compliance:jK:lumped``); with the masses withheld and no effect, followed by ``diagnose``.
Printed per case: the held-out 3D position RMS of each, the noise floor (held-out RMS of the
measurements against the twin's noise-free poses), and what diagnose suggests.  ``--controls
N`` adds noise-only sets on the mass-less robot and counts false alarms.

Run: ``.venv/bin/python benchmarks/lumped_compliance.py [--random N] [--controls N]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from quickhealth.identify.diagnose import (  # noqa: E402
    diagnose,
    pose_residuals,
    rms_pos_mm,
    state_from_fitted,
)
from quickhealth.identify.effects import parse_effects  # noqa: E402
from quickhealth.identify.robot import ur5  # noqa: E402
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.identify.twin import make_twin, random_joints, schedules  # noqa: E402

FIXED = [("compliance:j2", 2.5e-5, 100), ("compliance:j3", 2.5e-5, 107)]


def run_case(effect: str | None, size: float, seed: int) -> dict[str, object]:
    """One data set: mass form, lumped form (masses withheld), and diagnose without masses."""
    twin = make_twin(seed=seed, effects={effect: size} if effect else {})
    q = random_joints(twin.robot, 450, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    train = twin.measure(q[:150], *schedules(150), seed=seed + 2)
    held = twin.measure(q[150:], *schedules(300), seed=seed + 3)
    floor = rms_pos_mm(pose_residuals(held, twin.true_pose(held.q, held.time, held.temp)))

    def held_rms(fitted) -> float:  # type: ignore[no-untyped-def]
        return rms_pos_mm(pose_residuals(held, fitted.predict(held.q)))

    bare = dataclasses.replace(ur5(), masses=None, coms=None)
    out: dict[str, object] = {"floor": floor}
    t0 = time.perf_counter()
    if effect:
        fm = select_orders(twin.robot, train, parse_effects(effect, twin.robot)).fitted
        t1 = time.perf_counter()
        fl = select_orders(bare, train, parse_effects(effect, bare)).fitted
        t2 = time.perf_counter()
        out.update(masses=held_rms(fm), lumped=held_rms(fl), t_masses=t1 - t0, t_lumped=t2 - t1)
    plain = select_orders(bare, train).fitted
    diag = diagnose(state_from_fitted(plain), train)
    out.update(
        none=held_rms(plain),
        verdict=diag.verdict.value,
        top=diag.candidates[0].effect if diag.candidates else "-",
        suggested=",".join(diag.suggested) or "-",
    )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--random", type=int, default=0, help="also N random joints and sizes")
    ap.add_argument("--controls", type=int, default=0, help="also N noise-only sets")
    ap.add_argument("--seed", type=int, default=31)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    cases: list[tuple[str | None, float, int]] = list(FIXED)
    cases += [
        (f"compliance:j{rng.choice([2, 3])}", float(rng.uniform(2e-5, 4e-5)), 500 + 7 * i)
        for i in range(args.random)
    ]
    cases += [(None, 0.0, 900 + 7 * i) for i in range(args.controls)]  # apart from the draws
    print(
        f"{'effect':<15}{'size':>9}{'seed':>6}{'masses':>9}{'lumped':>9}{'none':>9}{'floor':>9}"
        f"{'l/m':>7}{'l/fl':>7}{'t_m s':>7}{'t_l s':>7}  diagnose (masses withheld, no effect)"
    )
    ok = True
    for eff, size, seed in cases:
        r = run_case(eff, size, seed)
        fl = float(r["floor"])  # type: ignore[arg-type]
        if eff:
            m, lu = float(r["masses"]), float(r["lumped"])  # type: ignore[arg-type]
            nums = (
                f"{m:>9.4f}{lu:>9.4f}{float(r['none']):>9.4f}{fl:>9.4f}{lu / m:>7.3f}"  # type: ignore[arg-type]
                f"{lu / fl:>7.3f}{float(r['t_masses']):>7.1f}{float(r['t_lumped']):>7.1f}"  # type: ignore[arg-type]
            )
            ok &= lu <= 1.05 * m and lu <= 1.3 * fl and r["suggested"] == f"{eff}:lumped"
        else:
            nums = f"{'-':>9}{'-':>9}{float(r['none']):>9.4f}{fl:>9.4f}{'-':>7}{'-':>7}{'-':>7}{'-':>7}"  # type: ignore[arg-type]
            ok &= r["verdict"] == "adequate"
        print(
            f"{eff or '(control)':<15}{size:>9.3g}{seed:>6}{nums}  {r['verdict']}, "
            f"top {r['top']}, suggests {r['suggested']}",
            flush=True,
        )
    print("all within 5 % of the mass form and 1.3x the floor, controls adequate:", ok)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
