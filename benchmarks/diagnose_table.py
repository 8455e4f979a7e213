"""Acceptance table of the diagnosis: one hidden effect per effect name, plus a control.

For each case the digital twin (a UR5 with random geometric and position-dependent joint
errors, camera 2 m away, noise 0.03 mm and 0.1 mrad) gives 150 training poses (7D) and 300
held-out poses.  The paper's model is selected by BIC (``select_orders``, as ``identify fit``
does), ``diagnose`` ranks every candidate effect, then the model is selected again with the
true effect added (``identify fit --effects``).  Printed per case: the rank of the true effect
(family and joint, and harmonic for cyclic), the held-out position RMS before and after, and
the noise floor (held-out RMS of the measurements against the twin's true, noise-free poses).

Run: ``.venv/bin/python benchmarks/diagnose_table.py [--random N]`` (``--random`` adds N
cases with effect, joint and size drawn at random).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

# One BLAS thread (set before numpy loads OpenBLAS): on two shared cores, threading these
# small products is much slower.
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
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.identify.twin import make_twin, random_joints, schedules  # noqa: E402

# effect name -> size (SI): each 1.5–5× the noise floor in held-out RMS
CASES: list[tuple[str | None, float]] = [
    ("compliance:j2", 2.5e-5),
    ("backlash:j3", 4.0e-4),
    ("cyclic:j1:h9", 2.0e-4),
    ("thermal", 5.0e-5),
    ("drift", 2.0e-7),
    ("depthscale", 4.0e-4),
    (None, 0.0),
]


def run_case(effect: str | None, size: float, seed: int) -> dict[str, object]:
    """One hidden-effect data set through select → diagnose → select with the effect."""
    twin = make_twin(seed=seed, effects={effect: size} if effect else {})
    q = random_joints(twin.robot, 450, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    train = twin.measure(q[:150], *schedules(150), seed=seed + 2)
    held = twin.measure(q[150:], *schedules(300), seed=seed + 3)
    floor = rms_pos_mm(pose_residuals(held, twin.true_pose(held.q, held.time, held.temp)))

    def held_rms(fitted) -> float:  # type: ignore[no-untyped-def]
        T = fitted.predict(held.q, time=held.time, temp=held.temp)
        return rms_pos_mm(pose_residuals(held, T))

    t0 = time.perf_counter()
    before = select_orders(twin.robot, train).fitted
    diag = diagnose(state_from_fitted(before), train)
    names = [c.effect for c in diag.candidates]
    rank = names.index(effect) + 1 if effect in names else None
    after_rms = None
    if effect:
        after = select_orders(twin.robot, train, parse_effects(effect, twin.robot)).fitted
        after_rms = held_rms(after)
    return {
        "effect": effect or "(none: control)",
        "size": size,
        "verdict": diag.verdict.value,
        "rank": rank,
        "top": names[0] if names else "-",
        "top_significant": bool(diag.candidates and diag.candidates[0].significant),
        "before": held_rms(before),
        "after": after_rms,
        "floor": floor,
        "seconds": time.perf_counter() - t0,
    }


def random_case(rng: np.random.Generator) -> tuple[str, float]:
    """An effect, joint and size drawn at random (sizes in the 1.5–5× floor band)."""
    fam = rng.choice(["compliance", "backlash", "cyclic", "thermal", "drift", "depthscale"])
    if fam == "compliance":
        return f"compliance:j{rng.choice([2, 3])}", float(rng.uniform(2e-5, 4e-5))
    if fam == "backlash":
        return f"backlash:j{rng.integers(1, 4)}", float(rng.uniform(3.5e-4, 8e-4))
    if fam == "cyclic":
        return f"cyclic:j{rng.integers(1, 4)}:h{rng.integers(5, 21)}", float(
            rng.uniform(1.8e-4, 4e-4)
        )
    if fam == "thermal":
        return "thermal", float(rng.uniform(5e-5, 9e-5))
    if fam == "drift":
        return "drift", float(rng.uniform(2e-7, 4e-7))
    return "depthscale", float(rng.uniform(4e-4, 8e-4))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--random", type=int, default=0, help="also N random cases")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--skip-fixed", action="store_true", help="only the random cases")
    ap.add_argument(
        "--controls", type=int, default=0, help="also N noise-only sets: the false-alarm rate"
    )
    args = ap.parse_args(argv)
    cases = [] if args.skip_fixed else list(CASES)
    rng = np.random.default_rng(args.seed)
    cases += [random_case(rng) for _ in range(args.random)]
    hdr = (
        f"{'effect':<16}{'size (SI)':>11}{'verdict':>16}{'rank':>6}{'before mm':>11}"
        f"{'after mm':>10}{'floor mm':>10}{'bef/fl':>8}{'aft/fl':>8}{'s':>6}"
    )
    print(hdr)
    print("-" * len(hdr))
    ok = True
    for i, (eff, size) in enumerate(cases):
        r = run_case(eff, size, seed=100 + 7 * (i + (len(CASES) if args.skip_fixed else 0)))
        fl = float(r["floor"])  # type: ignore[arg-type]
        bef = float(r["before"])  # type: ignore[arg-type]
        aft = r["after"]
        rank = r["rank"] if eff else "-"
        print(
            f"{r['effect']:<16}{size:>11.3g}{r['verdict']:>16}{rank!s:>6}{bef:>11.4f}"
            f"{(f'{aft:.4f}' if aft is not None else '-'):>10}{fl:>10.4f}{bef / fl:>8.2f}"
            f"{(f'{aft / fl:.2f}' if aft is not None else '-'):>8}{r['seconds']:>6.1f}",
            flush=True,
        )
        if eff:
            ok &= r["rank"] == 1 and aft is not None and aft <= 1.3 * fl
        else:
            ok &= r["verdict"] == "adequate"
    if args.controls:
        alarms = []
        for k in range(args.controls):
            r = run_case(None, 0.0, seed=5000 + 7 * k)
            if r["verdict"] != "adequate":
                alarms.append(f"seed {5000 + 7 * k}: {r['top']}")
        print(
            f"noise-only sets: {len(alarms)} false alarms in {args.controls}"
            + (f" ({'; '.join(alarms)})" if alarms else "")
        )
        ok &= len(alarms) <= max(1, round(0.05 * args.controls))
    print("all acceptance checks pass" if ok else "SOME ACCEPTANCE CHECKS FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
