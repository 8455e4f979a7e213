"""The effect loop on real data nobody on the team made: the Barrett WAM laser-tracker set.

Fit on grid.csv (216 poses) exactly as ``identify fit --sigma-pos-mm 1`` does (BIC order
search, the arm's ~2 mm repeatability as the per-axis uncertainty), then repeat what a user
does: ``diagnose`` on grid.csv, add the effects it suggests, fit again, diagnose again, until
it finds nothing more (at most ``--rounds``).  Every decision is taken on grid.csv alone;
random.csv (20 poses) is only predicted, never fitted, selected or tuned on.  Printed per
round: the effects in the model, the mean and RMS of |measured − model| on random.csv (mm),
and what diagnose suggests next (with the lumped compliance candidates' rank: the WAM's
description has no link masses, so compliance is tested in its lumped form).

The WAM's figures: uncalibrated 17.77 mm, the thesis' best (geometric calibration plus a
learned residual) 2.92 mm on random.csv.

    .venv/bin/python benchmarks/wam_effects.py [--data DIR] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from quickhealth.identify.diagnose import diagnose, state_from_fitted  # noqa: E402
from quickhealth.identify.effects import parse_effects  # noqa: E402
from quickhealth.identify.fit import FittedModel, InstrumentNoise  # noqa: E402
from quickhealth.identify.measurements import Measurements  # noqa: E402
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.station import formats  # noqa: E402
from quickhealth.station.services.wam import wam_sign  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NOISE = InstrumentNoise(sigma_pos=1e-3)  # --sigma-pos-mm 1: the arm's repeatability


def held_out_errors(fitted: FittedModel, held: Measurements) -> np.ndarray:
    """|measured − model| (mm) of every held-out pose (``identify predict``'s column)."""
    T = fitted.predict(held.q)
    return np.linalg.norm(held.pos - T[:, :3, 3], axis=1) * 1e3


def effect_loop(data: Path, rounds: int = 3, say=print) -> list[dict[str, object]]:  # type: ignore[no-untyped-def]
    """The rounds of fit → predict → diagnose; one dict per round."""
    robot = formats.load_robot(str(ROOT / "fixtures" / "robots" / "wam.toml"))
    sign, _ = wam_sign(robot, data / "grid.csv")  # decided on the fitting file
    grid = formats.read_wam_csv(data / "grid.csv", sign)
    held = formats.read_wam_csv(data / "random.csv", sign)
    names: list[str] = []
    out = []
    for r in range(rounds + 1):
        t0 = time.perf_counter()
        fitted = select_orders(robot, grid, parse_effects(names, robot), noise=NOISE).fitted
        err = held_out_errors(fitted, held)
        diag = diagnose(state_from_fitted(fitted), grid)
        ranks = {
            c.effect: (i + 1, c.significant)
            for i, c in enumerate(diag.candidates)
            if c.effect.startswith("compliance:")
        }
        row = {
            "effects": tuple(e.name for e in fitted.effects),
            "mean_mm": float(err.mean()),
            "rms_mm": float(np.sqrt(np.mean(err**2))),
            "fit_rms_mm": fitted.rms_pos * 1e3,
            "verdict": diag.verdict.value,
            "suggested": diag.suggested,
            "compliance_ranks": ranks,
            "seconds": time.perf_counter() - t0,
        }
        out.append(row)
        say(
            f"round {r}: effects {', '.join(row['effects']) or '(none)'}; held-out mean "  # type: ignore[arg-type]
            f"{row['mean_mm']:.2f} mm, rms {row['rms_mm']:.2f} mm (fit rms "
            f"{row['fit_rms_mm']:.2f} mm); diagnose: {diag.verdict.value}"
            + (f", suggests {', '.join(diag.suggested)}" if diag.suggested else "")
            + f"; compliance ranks {ranks} ({row['seconds']:.1f} s)"
        )
        new = [s for s in diag.suggested if s not in names]
        if not new:
            break
        names += new
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", type=Path, default=ROOT / "fixtures" / "wam")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    effect_loop(args.data, args.rounds)
    print("published: uncalibrated 17.77 mm, best 2.92 mm (random.csv, mean)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
