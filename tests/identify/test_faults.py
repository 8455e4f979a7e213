"""The fault dictionary and the change test along each fault (identify/faults.py, fault_test.py)."""

import re
from dataclasses import replace

import numpy as np
import pytest

from quickhealth.identify import fault_test as FT
from quickhealth.identify import faults as F
from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.robot import builtin_robot
from quickhealth.identify.twin import make_twin, random_joints

NOISE = InstrumentNoise(sigma_pos=3e-5, sigma_rot=1e-4)


@pytest.fixture(scope="module")
def ur5_pair():
    """A UR5 twin measured twice on the same 150 poses, the baseline fitted at order 1."""
    rob = builtin_robot("ur5")
    tw = make_twin(rob, seed=3)
    q = random_joints(rob, 150, seed=4, T_instr_base=tw.truth.T_instr_base)
    ma, mb = tw.measure(q, seed=10), tw.measure(q, seed=11)
    spec = ErrorModelSpec.uniform(6, 1, q.min(0) - 0.01, q.max(0) + 0.01)
    fa = fit_model(rob, ma, spec, noise=NOISE)
    img = F.fault_images(fa, F.fault_dictionary(rob, setup=True), ma)
    return rob, fa, mb, img


def _named(rob, fa, mb, img, joint=None, shift=3e-4):
    if joint is not None:
        q = mb.q.copy()
        q[:, joint - 1] += shift  # the reading raised: true angle − reading falls by `shift`
        mb = replace(mb, q=q)
    fb = fit_model(rob, mb, fa.spec, noise=NOISE)
    return FT.name_run_change(FT.run_change(fa, fb, img), img, floors={"m": 1e-5, "rad": 2e-5})


@pytest.mark.parametrize("joint", [2, 3, 5])
def test_a_zero_shift_is_named_by_its_joint_with_its_size(ur5_pair, joint):
    """The issue's case: q2 (q3, q5) raised by 0.3 mrad was flagged as 'joint 1 tilt about y'
    plus radial motions (the gauge's coordinates); it is one change, the joint's zero."""
    t = _named(*ur5_pair, joint=joint)
    (c,) = t.robot
    assert c.fault == f"j{joint}.zero" and c.unit == "rad" and c.display_unit == "mrad"
    assert abs(c.size + 3e-4) < 2 * c.sigma and c.sigma < 2e-5
    assert c.words == f"joint {joint} zero offset" and "re-zero" in c.action
    # z, σ and p are one set of numbers, and the line says them
    assert c.z == pytest.approx(c.size / c.sigma) and c.p_value == FT.two_sided_p(c.z)
    assert re.match(
        rf"joint {joint} zero offset changed by -0\.(29|30)\d* ± 0\.0\d+ mrad", c.line()
    )
    assert not t.setup


def test_faults_geometry_cannot_tell_apart_are_ranked_by_the_prior(ur5_pair):
    """On a UR, joint 6's axis tilted about y is joint 5's zero offset (the axes meet): the
    change is named by the more common fault, the other is its alternative."""
    t = _named(*ur5_pair, joint=5)
    c = t.robot[0]
    alt = {a.fault: a for a in c.alternatives}
    assert "j6.tilt_y" in alt
    ratio = c.probability / alt["j6.tilt_y"].probability
    assert ratio == pytest.approx(F.PRIOR[F.FaultKind.ZERO] / F.PRIOR[F.FaultKind.TILT_Y], rel=0.05)


def test_a_healthy_repeat_names_nothing(ur5_pair):
    t = _named(*ur5_pair)
    assert not t.significant and t.named and not t.named[0].significant


def test_set_up_faults_are_recognised_not_tested(ur5_pair):
    """Joint 1's zero offset and a tilt of joint 2 about y (the same rotation about joint 1's
    axis) are a base rotation; joint 6's zero, the target turning on the flange: the data
    cannot see them, and they are never tested."""
    *_, img = ur5_pair
    seen = {img.faults[k].key for k in img.testable()}
    for key in ("j1.zero", "j2.tilt_y", "j1.offset", "j6.zero", "j6.offset"):
        assert key not in seen
    for key in ("j2.zero", "j3.zero", "j3.tilt_x", "j2.length", "j4.offset", "tool.dx"):
        assert key in seen


def test_a_moved_target_is_a_set_up_change_not_a_fault(ur5_pair):
    rob, fa, mb, img = ur5_pair
    tw = make_twin(rob, seed=3)
    T_ft = tw.truth.T_flange_target.copy()
    T_ft[:3, 3] += T_ft[:3, 0] * 2e-4  # re-mounted 0.2 mm along the target's own x
    tw2 = replace(tw, truth=replace(tw.truth, T_flange_target=T_ft))
    mb2 = tw2.measure(mb.q, seed=11)
    t = _named(rob, fa, mb2, img)
    assert not t.robot
    assert t.setup and t.setup[0].fault == "tool.dx" and abs(t.setup[0].size - 2e-4) < 1e-5


def test_a_fault_injected_into_the_truth_matches_its_definition():
    """``raw_vector`` puts a fault into an error model's coefficients: a zero offset of joint 3
    in the truth is the same robot as joint 3's readings shifted the other way."""
    rob = builtin_robot("ur10e")
    tw = make_twin(rob, seed=2)
    f = next(f for f in F.geometric_faults(rob) if f.key == "j3.zero")
    c = tw.truth.coeffs + 2e-4 * f.raw_vector(tw.truth.spec)
    tw2 = replace(tw, truth=replace(tw.truth, coeffs=c))
    q = random_joints(rob, 20, seed=1, T_instr_base=tw.truth.T_instr_base)
    q2 = q.copy()
    q2[:, 2] += 2e-4
    # (the error motions are evaluated at the reading: their slope over 0.2 mrad, < 1 µm)
    np.testing.assert_allclose(tw2.true_pose(q), tw.true_pose(q2), atol=1e-6)


def test_a_joint_scale_counts_by_how_far_it_moves_the_tcp():
    """A joint scale (gear ratio) is dimensionless: it counts when its TCP displacement passes
    the length floor (the demo's healthy repeat named 'joint 1 scale changed by -0.95 ppm',
    z = -5.1, a micrometre at the TCP, with no floor for its unit)."""
    rob = builtin_robot("ur5")
    faults = [f for f in F.geometric_faults(rob) if f.key in ("j2.scale", "j3.zero")]
    g = np.eye(4)[:, :2]  # each fault's image: one coordinate of its own
    blocks = [g[:, [k]] for k in range(2)]
    S = np.eye(4) * 1e-20  # measured far more sharply than the sizes below
    tcp = [0.8, 0.9]  # m of TCP per unit of each fault
    floors = {"m": 1e-5, "rad": 2e-5}
    for size, counts in ((1e-6, False), (1e-4, True)):  # 0.8 µm and 80 µm at the TCP
        t = FT.name_changes(g[:, 0] * size, S, blocks, faults, floors=floors, tcp=tcp)
        c = t.named[0]
        assert c.fault == "j2.scale" and abs(c.z) > 100
        assert c.significant is counts, (size, c.tcp)
