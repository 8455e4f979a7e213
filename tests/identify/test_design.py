"""Optimal designs: the greedy selection's criterion, groups, and what it predicts (the
held-out errors against random poses are benchmarks/optimal_plan.py's, docs/plan.md)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from quickhealth.identify import design as D
from quickhealth.identify.effects import parse_effect
from quickhealth.identify.errors import InputError
from quickhealth.identify.fit import fit_model
from quickhealth.identify.robot import ur5
from quickhealth.identify.select import data_spec
from quickhealth.identify.twin import make_twin, random_joints


@pytest.fixture(scope="module")
def pool():
    return random_joints(ur5(), 300, seed=2)


def test_selection_beats_random_choices_by_its_own_criterion(pool):
    for orientation in (True, False):
        s = D.DesignSettings(orientation=orientation, prior=D.DesignPrior(max_order=2))
        res = D.select_poses(ur5(), pool, 30, s)
        assert len(set(res.indices.tolist())) == 30
        assert res.band_mm < 0.9 * res.random_band_mm
        # the greedy's rank-d updates give the criterion computed from scratch
        spec = D.design_spec(ur5(), pool, s.prior)
        J, G = D.pose_information(ur5(), pool, spec, s)
        M = np.einsum("nip,niq->pq", G, G) / len(pool)
        P0 = np.diag(s.prior.sigmas(spec) ** 2)
        direct = D._criterion(J, M, P0, list(res.indices), D.Criterion.I_OPTIMAL)
        assert res.band_mm == pytest.approx(np.sqrt(direct) * 1e3, rel=1e-9)


def test_greedy_step_takes_the_largest_decrease(pool):
    s = D.DesignSettings(prior=D.DesignPrior(max_order=1))
    spec = D.design_spec(ur5(), pool, s.prior)
    J, G = D.pose_information(ur5(), pool, spec, s)
    M = np.einsum("nip,niq->pq", G, G) / len(pool)
    P0 = np.diag(s.prior.sigmas(spec) ** 2)
    for crit in D.Criterion:
        chosen = D._greedy(J, M, P0, 4, np.arange(len(pool)), crit)
        best = min(
            range(len(pool)),
            key=lambda c: D._criterion(J, M, P0, chosen[:3] + [c], crit),
        )
        assert chosen[3] == best


def test_at_most_one_configuration_per_group(pool):
    groups = np.arange(len(pool)) // 3  # three configurations of each target
    res = D.select_poses(ur5(), pool, 20, D.DesignSettings(), allowed_groups=groups)
    assert len(set(groups[res.indices].tolist())) == 20
    with pytest.raises(InputError, match="between 1 and 100"):
        D.select_poses(ur5(), pool, 101, D.DesignSettings(), allowed_groups=groups)


def test_registered_criterion_ignores_base_and_tool(pool):
    """Base and tool columns add nothing to the health figure's band: the registered TCP
    Jacobian is zero for them and orthogonal to what base and tool can take up."""
    s = D.DesignSettings()
    spec = D.design_spec(ur5(), pool, s.prior)
    _, G = D.pose_information(ur5(), pool, spec, s)
    idx = spec.index()
    setup = (idx[:, 0] == 0) | (idx[:, 0] == 7)
    assert np.all(G[:, :, setup] == 0.0)
    # a joint-1 axial constant is a base shift: nothing of it is left after registration
    j1dz = np.flatnonzero((idx[:, 0] == 1) & (idx[:, 1] == 2) & (idx[:, 2] == 0))
    assert np.abs(G[:, :, j1dz]).max() < 1e-12


def _mmd2(q, rows, length):
    """Squared maximum mean discrepancy (Gaussian kernel) between ``rows`` and all of ``q``."""
    z = q / (length * q.std(axis=0))
    k = lambda a, b: np.exp(-0.5 * np.sum((a[:, None] - b[None]) ** 2, axis=2))  # noqa: E731
    return k(z[rows], z[rows]).mean() - 2 * k(z[rows], z).mean() + k(z, z).mean()


def test_first_poses_by_information_the_rest_represent_the_candidates(pool):
    """k = ceil(1.3 r/d/s) poses are the greedy's; the others bring the set closer to the
    candidates' distribution than more information-chosen poses would."""
    s = D.DesignSettings(prior=D.DesignPrior(max_order=1, unexplained=1.0))
    res = D.select_poses(ur5(), pool, 40, s)
    k = math.ceil(1.3 * res.identifiable / 6)
    stated = D.select_poses(ur5(), pool, 40, replace(s, prior=D.DesignPrior(max_order=1)))
    assert stated.n_information == math.ceil(1.3 * res.identifiable / 6 / 0.5)  # assumed 0.5
    assert (res.n_information, res.n_spread) == (k, 40 - k) and 0 < k < 40
    pure = D.select_poses(ur5(), pool, 40, replace(s, spread=False))
    assert (pure.n_information, pure.n_spread) == (40, 0)
    assert res.indices[:k].tolist() == pure.indices[:k].tolist()
    assert len(set(res.indices.tolist())) == 40
    # the information criterion goes to the joints' extremes, the spread part back towards
    # where the candidates are (normalised distance from their mean: 2.71 and 2.32 against 2.41)
    r = np.linalg.norm((pool - pool.mean(0)) / pool.std(0), axis=1)
    assert r[pure.indices].mean() > r.mean() + 0.2
    assert abs(r[res.indices].mean() - r.mean()) < 0.5 * (r[pure.indices].mean() - r.mean())
    assert _mmd2(pool, res.indices, 1.0) < 0.7 * _mmd2(pool, pure.indices, 1.0)
    # a model that explains everything (a baseline with nothing unexplained): all by information
    trusted = replace(s, prior=replace(s.prior, unexplained=0.0))
    assert D.select_poses(ur5(), pool, 40, trusted).indices.tolist() == pure.indices.tolist()
    # position only: 3 numbers per pose, twice the poses to saturate the model
    pos = D.select_poses(ur5(), pool, 60, replace(s, orientation=False))
    assert pos.n_information == math.ceil(1.3 * pos.identifiable / 3)


@pytest.fixture(scope="module")
def baseline():
    """A fitted model of a twin with a compliance and a backlash, j2's angle error at order 5."""
    twin = make_twin(seed=4, effects={"compliance:j2": 3e-6, "backlash:j3": 2e-4})
    q = random_joints(twin.robot, 120, seed=6, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=7)
    spec = data_spec(twin.robot, meas)
    orders = spec.orders.copy()
    orders[2, 5] = 5
    effects = [parse_effect(n, twin.robot) for n in ("compliance:j2", "backlash:j3")]
    return fit_model(twin.robot, meas, spec.with_orders(orders), effects,
                     setup=(twin.truth.T_instr_base, twin.truth.T_flange_target))  # fmt: skip


def test_prior_from_a_baseline(pool, baseline):
    """Its orders raise the series, its sizes the coefficients' priors, its joint-only effects
    join the information, and its unexplained scatter sets how many poses information picks."""
    prior = D.prior_from_baseline(baseline, "base")
    assert prior.source == "base" and prior.unexplained == 0.0  # residuals = the noise
    spec = D.design_spec(ur5(), pool, prior)
    assert spec.orders[2, 5] == 5 and spec.orders[1, 5] == 3  # j2.ez to the baseline's 5
    sig = dict(zip(spec.labels(), prior.sigmas(spec), strict=True))
    i = baseline.spec.labels().index("j2.ez.c5")
    assert sig["j2.ez.c5"] == pytest.approx(np.hypot(baseline.coeffs[i], baseline.sigma[i]))
    assert sig["j1.ez.c1"] == pytest.approx(1.5e-4)  # stated: j1.ez was not fitted above 0
    res = D.select_poses(ur5(), pool, 30, D.DesignSettings(prior=prior))
    assert res.effects == ("compliance:j2",) and res.left_out[0].startswith("backlash:j3")
    assert res.n_information == 30  # nothing unexplained: every pose by information
    assert res.n_params == int(np.sum(prior.sigmas(spec) > 0)) + 1  # + the compliance
    # scatter beyond the instrument's: the share it is of the residual variance
    noisy = replace(baseline, noise=replace(baseline.noise, excess_pos=9e-5))
    share = D.prior_from_baseline(noisy).unexplained
    assert share == pytest.approx(0.09**2 / (0.09**2 + 0.03**2))
    with pytest.raises(InputError, match="7 joints"):
        D.design_spec(ur5(), pool, replace(prior, fitted_orders=((0,) * 6,) * 9))


def test_every_pose_by_information_keeps_each_joint_range_covered(pool):
    """With no representative part (n <= k) and a model expected to miss part of the
    errors, each quarter of every joint's range holds at least coverage/4 of the poses; the
    plain greedy crowds the extremes and leaves quarters nearly empty."""
    s = D.DesignSettings(prior=D.DesignPrior(max_order=1))
    res = D.select_poses(ur5(), pool, 24, s)
    assert res.n_information == 24 and res.n_spread == 0  # k = 29 here
    plain = D.select_poses(ur5(), pool, 24, replace(s, coverage=0.0))

    def fewest(rows):
        b = D._quarters(pool)[rows]
        return min(np.sum(b[:, j] == i) for j in range(pool.shape[1]) for i in range(4))

    assert fewest(res.indices) >= math.floor(0.8 * 24 / 4)
    assert fewest(plain.indices) < math.floor(0.8 * 24 / 4)
    assert res.band_mm < res.random_band_mm  # still better than random by its criterion
    # a model that explains everything needs no guard: the plain greedy
    trusted = replace(s, prior=replace(s.prior, unexplained=0.0))
    assert D.select_poses(ur5(), pool, 24, trusted).indices.tolist() == plain.indices.tolist()
