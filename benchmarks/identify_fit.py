"""Benchmark: one implicit-loop ML fit on the paper's use case (150 full-pose UR5 poses).

Prints the wall time of a single fit (median of repeats) for
- the true orders of the synthetic case,
- every joint motion at order 6 with base and tool (all 8 E matrices, 246 identifiable of
  264 coefficients): the largest model the order search considers,
and the held-out accuracy of each.  Target on the 2-core machine: ≤ 0.5 s per fit.

    .venv/bin/python benchmarks/identify_fit.py [--repeats 5] [--blas-threads=N]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# BLAS threads must be set before numpy loads OpenBLAS.  Default 1: on two cores shared with
# other work, OpenBLAS threading makes these small products (~900 x 250) about 10x slower.
_BLAS = next((a.split("=", 1)[1] for a in sys.argv if a.startswith("--blas-threads=")), "1")
if _BLAS != "0":
    os.environ["OPENBLAS_NUM_THREADS"] = _BLAS
    os.environ["OMP_NUM_THREADS"] = _BLAS

import numpy as np  # noqa: E402

from quickhealth.identify.errormodel import ErrorModelSpec  # noqa: E402
from quickhealth.identify.fit import fit_model  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def synth():
    """The synthetic-data helper of the tests (tests/helpers/qh_synth.py)."""
    sys.path.insert(0, str(ROOT / "tests" / "helpers"))
    import qh_synth

    return qh_synth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--blas-threads=N",
        dest="blas",
        default="1",
        help="OpenBLAS threads (default 1; 0 keeps the library default)",
    )
    args = ap.parse_args()
    print(f"OpenBLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS', 'library default')}")
    S = synth()
    truth = S.paper_truth(0)
    train = S.measure(truth, S.random_q(150, 1), 2)
    test = S.measure(truth, S.random_q(300, 3), 4)
    floor = np.sqrt(3) * 3e-5
    cases = [
        ("true orders, full pose", truth.spec, train),
        ("order 6 everywhere, full pose", ErrorModelSpec.uniform(6, 6, S.Q_LO, S.Q_HI), train),
        ("true orders, position only", truth.spec, train.position_only()),
        (
            "order 6 everywhere, position only",
            ErrorModelSpec.uniform(6, 6, S.Q_LO, S.Q_HI),
            train.position_only(),
        ),
    ]
    print(f"single ML fit, 150 poses, median of {args.repeats} (target <= 0.5 s)")
    for name, spec, meas in cases:
        fit_model(truth.robot, meas, spec)  # warm-up (imports, caches)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fm = fit_model(truth.robot, meas, spec)
            times.append(time.perf_counter() - t0)
        T = fm.predict(test.q)
        rms = np.sqrt(np.mean(np.sum((test.pos - T[:, :3, 3]) ** 2, axis=1)))
        print(
            f"  {name:36s} {np.median(times):6.3f} s  ({fm.n_free} parameters, {fm.n_iter} "
            f"iterations)  held-out rms {rms * 1e3:.4f} mm = {rms / floor:.3f} x noise floor"
        )


if __name__ == "__main__":
    main()
