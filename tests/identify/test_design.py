"""Optimal designs: the greedy selection's criterion, groups, and what it predicts (the
held-out errors against random poses are benchmarks/optimal_plan.py's, docs/plan.md)."""

import numpy as np
import pytest

from quickhealth.identify import design as D
from quickhealth.identify.errors import InputError
from quickhealth.identify.robot import ur5
from quickhealth.identify.twin import random_joints


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
