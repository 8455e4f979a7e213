"""A joint's warm-up (``thermal:jK``): its physics, and a twin whose shoulder warms during a long
run found by diagnose and fitted to the noise floor, where the ambient ``thermal`` is not."""

import numpy as np
import pytest

from quickhealth.identify.diagnose import diagnose, pose_residuals, rms_pos_mm, state_from_fitted
from quickhealth.identify.effects import parse_effect, parse_effects
from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.linearize import loop_pose
from quickhealth.identify.robot import ur5
from quickhealth.identify.select import select_orders
from quickhealth.identify.twin import (
    camera_pose,
    make_twin,
    random_joints,
    warm_run,
)


def test_a_warm_joint_grows_along_its_axis_and_turns_about_it():
    """At joint temperature T, ``thermal:j3`` with (a, e) is joint 3's order-0 error motions
    δz and εz raised by a·(T − 20) and e·(T − 20); other joints' temperatures do nothing."""
    robot = ur5()
    q = random_joints(robot, 10, seed=1)
    spec = ErrorModelSpec.uniform(6, 1, q.min(0) - 0.01, q.max(0) + 0.01)
    c = np.random.default_rng(2).normal(0, 1e-4, spec.n_params)
    T_ft = np.eye(4)
    T_ft[:3, 3] = [0.04, 0.0, 0.06]
    e = parse_effect("thermal:j3", robot)
    assert e.requires() == ("joint_temp",) and e.joint == 2
    temps = np.full((10, 6), 31.0)
    temps[:, 0] = 55.0  # joint 1 is hot: thermal:j3 does not care
    ctx = make_twin(robot).context(q, joint_temp=temps)
    T1 = loop_pose(
        robot, spec, c, camera_pose(), T_ft, q, e.perturbation(ctx, np.array([2e-5, 3e-5]))
    )
    c2 = c.copy()
    labels = spec.labels()
    c2[labels.index("j3.dz.c0")] += 2e-5 * 11.0
    c2[labels.index("j3.ez.c0")] += 3e-5 * 11.0
    np.testing.assert_allclose(T1, loop_pose(robot, spec, c2, camera_pose(), T_ft, q), atol=1e-15)
    with pytest.raises(ValueError, match="needs a 'joint_temp' schedule"):
        make_twin(robot, effects={"thermal:j3": 1e-5}).true_pose(q)


@pytest.mark.slow
def test_a_warming_shoulder_is_named_and_fitted_to_the_noise_floor():
    """An hour's run, 300 poses in view (7D), 300 held-out poses of another such run: the air
    warms 1 K, the joints by their duty (shoulder ~10 K).  A hidden thermal:j2 is named first
    and suggested alone; with it the held-out RMS is within 1.05× the floor, the ambient
    thermal alone is not."""
    seed = 100
    twin = make_twin(seed=seed, effects={"thermal:j2": 1.5e-5})
    q = random_joints(twin.robot, 600, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    train, held = warm_run(twin, q[:300], seed + 2), warm_run(twin, q[300:], seed + 3)
    assert np.ptp(train.joint_temp[:, 1]) > 8.0 and np.ptp(train.temp) < 1.01
    true = twin.true_pose(held.q, held.time, held.temp, joint_temp=held.joint_temp)
    floor = rms_pos_mm(pose_residuals(held, true))

    def held_rms(fitted) -> float:
        return rms_pos_mm(pose_residuals(held, fitted.predict(held.q, **held.conditions())))

    plain = select_orders(twin.robot, train).fitted
    diag = diagnose(state_from_fitted(plain), train)
    assert diag.candidates[0].effect == "thermal:j2" and diag.suggested == ("thermal:j2",)
    fitted = select_orders(twin.robot, train, parse_effects("thermal:j2", twin.robot)).fitted
    ambient = select_orders(twin.robot, train, parse_effects("thermal", twin.robot)).fitted
    before, after, amb = (
        held_rms(plain) / floor,
        held_rms(fitted) / floor,
        held_rms(ambient) / floor,
    )
    print(f"thermal:j2 held-out / floor: {before:.3f} without, {after:.3f} with, {amb:.3f} ambient")
    assert after <= 1.05 < amb and before > 1.15
    a, e = fitted.effect_params[0]
    np.testing.assert_allclose([a, e], twin.truth.effects["thermal:j2"], rtol=0.15)
    assert "grows" in "\n".join(fitted.summary())
