"""Trend statistics on synthetic histories: no false alarms when healthy, drift caught early."""

import math

import numpy as np
import pytest

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.trend import (
    RunState,
    assess_trend,
    compare_curves,
    control_chart,
    joint_curves,
    prognosis,
)

DAY = 86400.0
FIG_MEAN = {"mean": 0.30, "std": 0.10, "max": 0.80}
FIG_SD = {"mean": 0.010, "std": 0.005, "max": 0.030}


def _spec(order=2):
    return ErrorModelSpec.uniform(6, order, np.full(6, -np.pi), np.full(6, np.pi))


def _cov(spec, rng):
    """A correlated covariance: 5 µm on lengths, 10 µrad on angles, like a 150-pose 7D fit."""
    n = spec.n_params
    sd = np.where(spec.index()[:, 1] < 3, 5e-6, 10e-6)
    A = rng.normal(size=(n, n))
    corr = A @ A.T / n + np.eye(n)
    d = np.sqrt(np.diag(corr))
    corr = corr / np.outer(d, d)
    return corr * np.outer(sd, sd)


def _history(rng, n_runs, drift_per_run=0.0, fig_drift_per_run=0.0, spec=None):
    """Runs of one robot: truth + fit noise drawn from each run's covariance."""
    spec = spec or _spec()
    truth = rng.normal(scale=50e-6, size=spec.n_params)
    labels = spec.labels()
    k = labels.index("j2.ex.c0")
    truth[k] = abs(truth[k])  # the drift makes the tilt grow
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


@pytest.mark.slow
def test_no_false_alarm_over_30_healthy_runs():
    """30 healthy runs with fit noise and figure noise: not one run is flagged, 20 robots."""
    flagged = 0
    for seed in range(20):
        runs = _history(np.random.default_rng(seed), 30)
        res = assess_trend(runs, 0, threshold_mm=1.2)  # every verdict is causal
        flagged += sum(bool(res.flags(i)) for i in range(30))
        assert not res.warnings
    assert flagged == 0


def test_slow_drift_is_flagged_within_stated_runs():
    """Joint 2 tilt about x grows 10 µrad per run (1σ of one fit; combined σ of a change 14 µrad).

    Stated detection: within 10 runs after the drift starts; the hint names joint and motion.
    """
    firsts = []
    for seed in range(10):
        runs = _history(np.random.default_rng(100 + seed), 30, drift_per_run=10e-6)
        res = assess_trend(runs, 0)
        first = next((i for i in range(30) if res.flags(i)), None)
        firsts.append(first)
        if first is not None:
            changes = res.significant_changes(first)
            assert changes and all((c.joint, c.motion) == (2, "ex") for c in changes)
            assert changes[0].hint().startswith("joint 2 tilt about x grew by")
    print("first flagged runs:", firsts)
    assert all(f is not None and f <= 10 for f in firsts), firsts


def test_ewma_flags_slow_rise_of_max_error():
    rng = np.random.default_rng(7)
    firsts = []
    for _ in range(20):
        x = (
            FIG_MEAN["max"]
            + FIG_SD["max"] * rng.normal(size=40)
            + 0.3 * FIG_SD["max"] * np.arange(40)
        )
        c = control_chart(x, figure="max")
        firsts.append(c.first_alarm)
    assert all(f is not None and f <= 25 for f in firsts), firsts


def test_change_inside_combined_uncertainty_is_not_degradation():
    """A 2σ shift of one coefficient is not significant; a 10σ one is, with the right words."""
    spec = _spec(1)
    k = spec.labels().index("j3.ez.c1")
    cov = np.diag(np.full(spec.n_params, (10e-6) ** 2))
    c0 = np.zeros(spec.n_params)
    base = RunState("b", 0.0, spec=spec, coeffs=c0, cov=cov)
    small = c0.copy()
    small[k] = 2 * math.sqrt(2) * 10e-6
    big = c0.copy()
    big[k] = 10 * math.sqrt(2) * 10e-6
    ch_small = compare_curves(base, RunState("s", 1.0, spec=spec, coeffs=small, cov=cov))
    ch_big = compare_curves(base, RunState("b2", 1.0, spec=spec, coeffs=big, cov=cov))
    assert not any(c.significant for c in ch_small)
    sig = [c for c in ch_big if c.significant]
    assert [(c.joint, c.motion) for c in sig] == [(3, "ez")]
    assert sig[0].max_change == pytest.approx(big[k], rel=1e-9)  # |c1 · u| peaks at u = ±1
    assert sig[0].hint().startswith("joint 3 angular positioning error grew by 0.14 mrad")


def test_compare_curves_across_different_orders():
    """Runs with different selected orders compare on the curve, not the coefficient vector."""
    sa, sb = _spec(1), _spec(3)
    ca, cb = np.zeros(sa.n_params), np.zeros(sb.n_params)
    cb[sb.labels().index("j5.dz.c3")] = 200e-6
    cova = np.diag(np.full(sa.n_params, 1e-12))
    covb = np.diag(np.full(sb.n_params, 1e-12))
    ch = compare_curves(
        RunState("a", 0, spec=sa, coeffs=ca, cov=cova),
        RunState("b", 1, spec=sb, coeffs=cb, cov=covb),
    )
    sig = [(c.joint, c.motion) for c in ch if c.significant]
    assert sig == [(5, "dz")]


def test_joint_curves_band_matches_monte_carlo():
    rng = np.random.default_rng(3)
    spec = _spec(3)
    cov = _cov(spec, rng)
    c = rng.normal(scale=1e-5, size=spec.n_params)
    jc = joint_curves(spec, c, cov, n_grid=11)
    draws = rng.multivariate_normal(c, cov, size=4000)
    vals = np.stack([joint_curves(spec, d, None, n_grid=11).value for d in draws[:400]])
    np.testing.assert_allclose(vals.std(0), jc.std, rtol=0.15)


def test_prognosis_crossing_and_no_trend():
    t = 1.7e9 + DAY * 7 * np.arange(12)
    rng = np.random.default_rng(1)
    y = 0.5 + 0.01 * np.arange(12) + 0.002 * rng.normal(size=12)  # +0.01 mm per week
    p = prognosis(t, y, 0.8, figure="max")
    assert p.trend
    days = (p.crossing_t_s - t[0]) / DAY
    assert days == pytest.approx(30 * 7, rel=0.05)  # 0.5 + 0.01 k = 0.8 at k = 30 weeks
    assert p.crossing_early_t_s < p.crossing_t_s < p.crossing_late_t_s
    assert "reaching 0.8 mm in about" in p.words()
    flat = prognosis(t, 0.5 + 0.002 * rng.normal(size=12), 0.8, figure="max")
    assert not flat.trend and "no trend" in flat.words()


def test_threshold_breach_and_comparability_warning():
    runs = _history(np.random.default_rng(5), 3)
    r = runs[2]
    runs[2] = RunState(
        r.run_id,
        r.t_s,
        {**r.figures_mm, "max": 2.0},
        r.spec,
        r.coeffs,
        r.cov,
        meta={"plan_hash": "zzz", "cell": "reference"},
    )
    res = assess_trend(runs, 0, threshold_mm=1.0)
    assert res.breaches == (False, False, True)
    assert res.flagged and "above the threshold 1 mm" in res.flags()[0]
    assert any("plan hash zzz differs" in w for w in res.warnings)


def test_verdicts_are_causal():
    """A run's verdict uses only the runs up to it: later runs never change it."""
    runs = _history(np.random.default_rng(11), 20, drift_per_run=10e-6)
    full = assess_trend(runs, 0)
    for i in (3, 9, 15):
        part = assess_trend(runs[: i + 1], 0)
        assert part.flags(i) == full.flags(i)


def test_covariances_that_understate_the_scatter_raise_no_false_alarm():
    """Fits whose real scatter is twice the reported σ (4× variance): the genomic-control
    factor, pooled over the history, absorbs it; without it the same history would alarm."""
    spec = _spec()
    rng = np.random.default_rng(21)
    cov = _cov(spec, rng)
    L2 = 2.0 * np.linalg.cholesky(cov)
    truth = rng.normal(scale=50e-6, size=spec.n_params)
    runs = [
        RunState(
            f"r{i}",
            float(i),
            spec=spec,
            coeffs=truth + L2 @ rng.normal(size=spec.n_params),
            cov=cov,
        )
        for i in range(30)
    ]
    res = assess_trend(runs, 0)
    assert not any(res.flags(i) for i in range(30))
    assert 3.0 < res.curve_changes[-1][0].inflation < 5.5  # pooled over 29 comparisons
    raw = [compare_curves(runs[0], r, inflate=1.0) for r in runs[1:]]
    assert sum(any(c.significant for c in ch) for ch in raw) >= 10


def test_curves_compared_only_where_both_runs_measured():
    """A difference outside the measured range (an extrapolation) is not a change."""
    spec = _spec(3)
    lab = spec.labels()
    c0 = np.zeros(spec.n_params)
    c1 = c0.copy()
    # j2.dz = 1e-4 (T3(u) - T1(u)... ) : a cubic that is ~0 on |u| < 0.3, large near ±1
    c1[lab.index("j2.dz.c3")] = 4e-4
    c1[lab.index("j2.dz.c1")] = 3e-4
    cov = np.diag(np.full(spec.n_params, (1e-6) ** 2))
    near = (np.full(6, -0.3 * np.pi), np.full(6, 0.3 * np.pi))
    a = RunState("a", 0, spec=spec, coeffs=c0, cov=cov, q_measured=near)
    b = RunState("b", 1, spec=spec, coeffs=c1, cov=cov, q_measured=near)
    ch = {(c.joint, c.motion): c for c in compare_curves(a, b)}
    full = {
        (c.joint, c.motion): c
        for c in compare_curves(
            RunState("a", 0, spec=spec, coeffs=c0, cov=cov),
            RunState("b", 1, spec=spec, coeffs=c1, cov=cov),
        )
    }
    # 4 T3(u) + 3 T1(u) = 16u³ - 9u: at |u| ≤ 0.3 at most |16·0.027 - 2.7| → 2.27e-4·... smaller
    assert ch[(2, "dz")].max_change < full[(2, "dz")].max_change / 2


def test_assess_trend_charts_use_the_ewma_weight_not_the_inflation_factor():
    """The charts smooth with λ (0.2 by default), whatever the curve test's inflation factor.

    The fits here scatter 2x their reported σ, so the genomic-control factor is well above 1;
    it once overwrote λ and the plotted EWMA equalled the data.
    """
    rng = np.random.default_rng(11)
    runs = _history(rng, 20)
    runs = [
        RunState(
            r.run_id,
            r.t_s,
            figures_mm=r.figures_mm,
            spec=r.spec,
            coeffs=runs[0].coeffs + 2.0 * (r.coeffs - runs[0].coeffs),
            cov=r.cov,
            meta=r.meta,
        )
        for r in runs
    ]
    res = assess_trend(runs, 0)
    assert res.curve_changes[-1] and res.curve_changes[-1][0].inflation > 1.5
    for lam in (0.2, 0.5):
        res = assess_trend(runs, 0, lam=lam)
        for f, ch in res.charts.items():
            vals = [r.figures_mm[f] for r in runs]
            x = np.asarray(vals)
            z = np.empty_like(x)
            mu0 = x[:8].mean()
            for i in range(len(x)):  # EWMA restarted from the in-control mean (n_phase1 = 8)
                m0 = x[: min(i + 1, 8)].mean()
                zz = m0
                for v in x[1 : i + 1]:
                    zz = lam * v + (1 - lam) * zz
                z[i] = zz
            assert np.allclose(ch.ewma_mm, z), f
            assert not np.allclose(ch.ewma_mm[1:], vals[1:]), f
            assert ch.mu0_mm == pytest.approx(mu0)
