"""Workspace error, joint curves and command prediction from an identified model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import qh_synth as S

from quickhealth.identify.errormodel import chebyshev_basis, chebyshev_u
from quickhealth.identify.fit import fit_model
from quickhealth.identify.workspace import (
    all_joint_curves,
    joint_curves,
    predict_commands,
    workspace_error,
)


@pytest.fixture(scope="module")
def fitted():
    truth = S.paper_truth(0)
    meas = S.measure(truth, S.random_q(120, 1), 2)
    return truth, fit_model(truth.robot, meas, truth.spec)


def test_workspace_error_of_a_perfect_robot_is_zero(fitted):
    _, fm = fitted
    zero = replace(fm, coeffs=np.where(_setup_mask(fm), fm.coeffs, 0.0))
    ws = workspace_error(zero, n_samples=300)
    assert ws.max < 1e-12 and ws.mean < 1e-12


def _setup_mask(fm):
    idx = fm.spec.index()
    return (idx[:, 0] == 0) | (idx[:, 0] == fm.spec.n_joints + 1)


def test_workspace_error_statistics_match_direct_evaluation(fitted):
    _, fm = fitted
    ws = workspace_error(fm, n_samples=2000, seed=4, bins=25)
    rng = np.random.default_rng(4)
    q = rng.uniform(fm.spec.q_lo, fm.spec.q_hi, (2000, 6))
    err = fm.tcp_error(q, approach=np.ones_like(q))
    assert ws.mean == pytest.approx(err.mean())
    assert ws.std == pytest.approx(err.std())
    assert ws.max == pytest.approx(err.max())
    assert ws.hist_counts.sum() == 2000 and len(ws.hist_edges) == 26
    d = ws.as_dict()
    assert d["mean_mm"] == pytest.approx(err.mean() * 1e3)
    # robot errors of ~0.1 mm and 0.3 mrad give sub-millimetre TCP errors, not zero
    assert 1e-5 < ws.mean < 2e-3


def test_joint_curves_evaluate_the_chebyshev_series(fitted):
    _, fm = fitted
    c = joint_curves(fm, 1, n_points=50)
    lab = fm.labels
    u = chebyshev_u(c.theta, fm.spec.q_lo[0], fm.spec.q_hi[0])
    B = chebyshev_basis(u, 3)
    ez = fm.coeffs[[lab.index(f"j1.ez.c{k}") for k in range(4)]]
    np.testing.assert_allclose(c.values[5], B @ ez)
    assert np.all(c.half_width >= c.pointwise_half_width - 1e-15)
    assert np.all(c.sigma[5] > 0)
    assert len(all_joint_curves(fm, n_points=10)) == 6
    d = c.as_dict()
    assert set(d["motions"]) == {"dx", "dy", "dz", "ex", "ey", "ez"}
    with pytest.raises(ValueError):
        joint_curves(fm, 7)


def test_predict_commands_flags_threshold_and_extrapolation(fitted):
    truth, fm = fitted
    q = S.random_q(40, 7)
    q[3, 2] = fm.spec.q_hi[2] + 0.1  # outside the identified range of joint 3
    pred = predict_commands(fm, q, threshold=float(np.median(fm.tcp_error(q))))
    assert pred.over_threshold.sum() in (19, 20, 21)
    assert pred.extrapolated[3] and pred.extrapolated.sum() == 1
    assert np.all(pred.err_sigma > 0) and np.all(pred.err_sigma < 0.2 * pred.err.max())
    # against the truth's TCP error in the model's gauge (the same fit on exact data: errors
    # that are a base or tool placement are not TCP errors of the robot)
    qd = S.random_q(500, 8)
    T = S.truth_pose(truth, qd)
    exact = S.measure(truth, qd, 9, sigma_pos=0.0, sigma_rot=0.0)
    assert np.allclose(exact.pos, T[:, :3, 3])
    true_fm = fit_model(truth.robot, exact, fm.spec)
    ok = ~pred.extrapolated
    diff = np.abs(pred.err[ok] - true_fm.tcp_error(q[ok]))
    assert np.median(diff) < 3 * np.median(pred.err_sigma[ok]) + 2e-5
