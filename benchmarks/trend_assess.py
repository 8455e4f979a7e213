"""The trend's detection figures through ``assess_trend`` (the path the command line takes).

Synthetic histories (the generator of tests/identify/test_trend.py): per robot a true error
model, each run's coefficients drawn from a realistic correlated covariance (5 µm, 10 µrad),
workspace figures with noise.  Printed:

- false alarms: runs flagged among 20 robots × 30 healthy runs (600 runs), and which part
  raised them (curve test or EWMA chart);
- detection: first flagged run when joint 2's tilt about x drifts 10 µrad per run
  (10 robots);
- EWMA chart: first alarm when the workspace max rises 0.3σ per run (20 robots), and whether
  the chart's EWMA is a smoothed series (it must differ from the data).

Run: ``.venv/bin/python benchmarks/trend_assess.py`` (about a minute on one core).
"""

from __future__ import annotations

import time

import numpy as np

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.trend import RunState, assess_trend

DAY = 86400.0
FIG_MEAN = {"mean": 0.30, "std": 0.10, "max": 0.80}
FIG_SD = {"mean": 0.010, "std": 0.005, "max": 0.030}


def _spec(order: int = 2) -> ErrorModelSpec:
    return ErrorModelSpec.uniform(6, order, np.full(6, -np.pi), np.full(6, np.pi))


def _cov(spec: ErrorModelSpec, rng: np.random.Generator) -> np.ndarray:
    n = spec.n_params
    sd = np.where(spec.index()[:, 1] < 3, 5e-6, 10e-6)
    A = rng.normal(size=(n, n))
    corr = A @ A.T / n + np.eye(n)
    d = np.sqrt(np.diag(corr))
    corr = corr / np.outer(d, d)
    return corr * np.outer(sd, sd)


def history(rng, n_runs, drift_per_run=0.0, fig_drift_per_run=0.0):  # type: ignore[no-untyped-def]
    spec = _spec()
    truth = rng.normal(scale=50e-6, size=spec.n_params)
    k = spec.labels().index("j2.ex.c0")
    truth[k] = abs(truth[k])
    cov = _cov(spec, rng)
    Lc = np.linalg.cholesky(cov)
    runs = []
    for i in range(n_runs):
        c = truth + Lc @ rng.normal(size=spec.n_params)
        c[k] += drift_per_run * i
        figs = {
            f: FIG_MEAN[f] + FIG_SD[f] * rng.normal() + fig_drift_per_run * FIG_SD[f] * i
            for f in FIG_MEAN
        }
        runs.append(
            RunState(
                run_id=f"r{i:03d}",
                t_s=1.7e9 + 7 * DAY * i,
                figures_mm=figs,
                spec=spec,
                coeffs=c,
                cov=cov,
                meta={"plan_hash": "abc", "cell": "reference"},
            )
        )
    return runs


def main() -> None:
    t0 = time.perf_counter()
    flagged = curve = chart = 0
    for seed in range(20):
        res = assess_trend(history(np.random.default_rng(seed), 30), 0, threshold_mm=1.2)
        for i in range(30):
            if res.flags(i):
                flagged += 1
                curve += bool(res.significant_changes(i))
                chart += any(c.alarms[i] for c in res.charts.values())
    print(
        f"healthy: {flagged} of 600 runs flagged (curve test {curve}, EWMA chart {chart}) "
        f"[20 robots x 30 runs]"
    )
    firsts = []
    for seed in range(10):
        res = assess_trend(history(np.random.default_rng(100 + seed), 30, drift_per_run=10e-6), 0)
        firsts.append(next((i for i in range(30) if res.flags(i)), None))
    got = [f for f in firsts if f is not None]
    print(
        f"joint 2 tilt drifting 10 urad/run: first flagged run {firsts} "
        f"(median {np.median(got) if got else float('nan'):.0f}, max {max(got) if got else None}, "
        f"missed {firsts.count(None)} of 10)"
    )
    chart_firsts, same = [], 0
    for seed in range(20):
        runs = history(np.random.default_rng(300 + seed), 40, fig_drift_per_run=0.3)
        res = assess_trend(runs, 0)
        ch = res.charts["max"]
        chart_firsts.append(ch.first_alarm)
        same += bool(np.allclose(ch.ewma_mm[1:], ch.values_mm[1:]))
    got = [f for f in chart_firsts if f is not None]
    print(
        f"workspace max rising 0.3 sigma/run: EWMA chart first alarm {chart_firsts} "
        f"(median {np.median(got) if got else float('nan'):.0f}); "
        f"EWMA identical to the data in {same} of 20 histories"
    )
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
