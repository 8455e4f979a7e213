"""Benchmark: is ``FittedModel.cov`` honest?  Monte Carlo over refits of one twin truth.

In the style of mrcal's test-projection-uncertainty: one digital-twin truth (UR5, camera 2 m
away, 0.03 mm / 0.1 mrad noise), the same joint commands measured again and again with fresh
noise, each set fitted at *fixed* orders.  Printed per case, as ratios empirical / reported:
the per-coefficient variance (median, p90, max), the mean eigenvalue of the whitened
empirical covariance ``C_rep^-1/2 C_emp C_rep^-1/2`` (1 when honest), the variance of the
predicted TCP error at 40 new commands (``predict_commands(...).err_sigma``) and χ²/dof.
``--select`` adds the case where the orders are chosen by BIC on every refit (what
``identify fit`` does): the covariance is conditional on the orders and does not cover that.

    .venv/bin/python benchmarks/identify_covariance.py [--refits 100] [--select 40]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from quickhealth.identify.errormodel import ErrorModelSpec  # noqa: E402
from quickhealth.identify.fit import FittedModel, InstrumentNoise, fit_model  # noqa: E402
from quickhealth.identify.select import select_orders  # noqa: E402
from quickhealth.identify.twin import make_twin, random_joints, schedules  # noqa: E402
from quickhealth.identify.workspace import predict_commands  # noqa: E402


def _tcp_ratio(fits: list[FittedModel], q_new: np.ndarray) -> np.ndarray:
    pred = [predict_commands(f, q_new) for f in fits]
    var_emp = np.var([p.err for p in pred], axis=0, ddof=1)
    var_rep = np.mean([p.err_sigma**2 for p in pred], axis=0)
    return var_emp / var_rep


def case(
    n: int, order: int | None, refits: int, orientation: bool = True, sigma_q: float = 0.0
) -> str:
    """One Monte-Carlo case; ``order=None``: the twin's own (position-dependent) orders."""
    twin = make_twin(seed=1, position_dependent=order is None, sigma_q=sigma_q)
    q = random_joints(twin.robot, n, seed=2, T_instr_base=twin.truth.T_instr_base)
    q_new = random_joints(twin.robot, 40, seed=100, T_instr_base=twin.truth.T_instr_base)
    if order is None:
        orders = twin.truth.orders.copy()
        orders[[0, -1]] = 0
    else:
        orders = np.zeros((8, 6), np.int64)
        orders[1:-1] = order
    spec = ErrorModelSpec(orders, q.min(0) - 0.02, q.max(0) + 0.02)
    noise = InstrumentNoise(twin.truth.sigma_pos, twin.truth.sigma_rot, sigma_q)
    t0 = time.perf_counter()
    fits = [
        fit_model(
            twin.robot,
            twin.measure(q, *schedules(n), seed=1000 + r, orientation=orientation),
            spec,
            noise=noise,
        )
        for r in range(refits)
    ]
    fits = [f for f in fits if f.unidentifiable == fits[0].unidentifiable]
    joint = np.array(
        [lb.startswith("j") and lb not in fits[0].unidentifiable for lb in fits[0].labels]
    )
    P = np.array([f.params[joint] for f in fits])
    C_rep = np.mean([f.cov[np.ix_(joint, joint)] for f in fits], axis=0)
    C_emp = np.cov(P.T)
    ratio = np.diag(C_emp) / np.diag(C_rep)
    Li = np.linalg.inv(np.linalg.cholesky(C_rep))
    white = np.trace(Li @ C_emp @ Li.T) / joint.sum()
    tcp = _tcp_ratio(fits, q_new)
    chi2 = np.mean([f.chi2_data / f.dof for f in fits])
    name = (
        f"{n} poses, {'true orders' if order is None else f'order {order}'}, "
        f"{'7D' if orientation else 'position only'}"
        + (f", encoder {sigma_q * 1e3:.2f} mrad" if sigma_q else "")
    )
    return (
        f"{name:44s} {len(fits):4d}  {np.median(ratio):5.2f} {np.percentile(ratio, 90):5.2f} "
        f"{ratio.max():5.2f}   {white:5.2f}   {np.median(tcp):5.2f} {tcp.max():5.2f}   "
        f"{chi2:5.3f}  {time.perf_counter() - t0:5.1f}"
    )


def selected(n: int, refits: int) -> str:
    """Orders chosen by BIC on every refit: TCP error scatter against the reported one."""
    twin = make_twin(seed=1)
    q = random_joints(twin.robot, n, seed=2, T_instr_base=twin.truth.T_instr_base)
    q_new = random_joints(twin.robot, 40, seed=100, T_instr_base=twin.truth.T_instr_base)
    true_orders = twin.truth.orders.copy()
    true_orders[[0, -1]] = 0
    fits = [
        select_orders(twin.robot, twin.measure(q, *schedules(n), seed=1000 + r)).fitted
        for r in range(refits)
    ]
    found = sum(np.array_equal(f.spec.orders, true_orders) for f in fits)
    tcp = _tcp_ratio(fits, q_new)
    chi2 = np.mean([f.chi2_data / f.dof for f in fits])
    return (
        f"{n} poses, orders selected by BIC, 7D: TCP error variance ratio median "
        f"{np.median(tcp):.2f}, mean {tcp.mean():.2f}, max {tcp.max():.2f}; chi2/dof {chi2:.3f}; "
        f"true orders found in {found}/{refits}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--refits", type=int, default=100)
    ap.add_argument("--select", type=int, default=0, help="refits of the selected-orders case")
    args = ap.parse_args()
    print("ratios empirical / reported (1 = honest)")
    print(
        f"{'case':44s} {'fits':>4s}  {'coefficient var':17s}   {'white':5s}   "
        f"{'TCP var':11s}   {'chi2/':5s}  {'s':>5s}"
    )
    print(
        f"{'':44s} {'':4s}  {'med':>5s} {'p90':>5s} {'max':>5s}   {'':5s}   {'med':>5s} {'max':>5s}   dof"
    )
    for kw in (
        dict(n=30, order=1),
        dict(n=60, order=1),
        dict(n=80, order=2),
        dict(n=80, order=2, sigma_q=2e-5),
        dict(n=150, order=None),
        dict(n=80, order=2, orientation=False),
    ):
        print(case(refits=args.refits, **kw), flush=True)  # type: ignore[arg-type]
    if args.select:
        print(selected(150, args.select))


if __name__ == "__main__":
    main()
