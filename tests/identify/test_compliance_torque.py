"""Compliance driven by the measured joint torque (``compliance:jK:torque``): the mass form's
physics without masses, following a payload that changes between poses."""

import numpy as np
import pytest

from quickhealth.identify.diagnose import diagnose, pose_residuals, rms_pos_mm, state_from_fitted
from quickhealth.identify.effects import parse_effect, parse_effects
from quickhealth.identify.errors import InputError
from quickhealth.identify.jointload import drive_torques
from quickhealth.identify.robot import ur5
from quickhealth.identify.select import select_orders
from quickhealth.identify.twin import (
    make_twin,
    payloads,
    random_joints,
    warm_run,
)


def test_the_measured_torque_of_an_unloaded_arm_gives_the_mass_form():
    """Without a payload the drive holds the arm's own weight: the torque form with c deflects
    the joint exactly as the mass form with c; a payload deflects it further, as the torque
    the drive then measures says."""
    robot = ur5()
    twin = make_twin(robot)
    q = random_joints(robot, 25, seed=3)
    torque = parse_effect("compliance:j2:torque", robot)
    mass = parse_effect("compliance:j2", robot)
    assert torque.physical == mass.physical == "compliance:j2" and torque.form == "torque"
    c = np.array([2.5e-5])
    empty = twin.context(q, joint_torque=drive_torques(robot, q))
    np.testing.assert_allclose(
        torque.perturbation(empty, c).dq, mass.perturbation(empty, c).dq, atol=1e-15
    )
    m = payloads(25, 2.0, seed=4)
    loaded = twin.context(q, joint_torque=drive_torques(robot, q, m))
    extra = torque.perturbation(loaded, c).dq[:, 1] - mass.perturbation(loaded, c).dq[:, 1]
    assert np.all(np.abs(extra[m == 0]) < 1e-15) and np.all(np.abs(extra[m > 0]) > 1e-6)
    with pytest.raises(InputError, match="two forms of compliance:j2"):
        parse_effects("compliance:j2,compliance:j2:torque", robot)


@pytest.mark.slow
def test_a_payload_that_changes_between_poses_is_followed_by_the_torque_form():
    """An hour's pick-and-place run (each pose empty or carrying up to 2 kg), 300 poses (7D),
    300 held-out poses of another such run: a hidden compliance:j2:torque is named first and
    suggested alone; with it the held-out RMS is within 1.05× the floor, the mass form (which
    knows the links, not the payload) is not."""
    seed = 100
    twin = make_twin(seed=seed, effects={"compliance:j2:torque": 2.5e-5})
    q = random_joints(twin.robot, 600, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    train, held = warm_run(twin, q[:300], seed + 2), warm_run(twin, q[300:], seed + 3)
    true = twin.true_pose(held.q, held.time, held.temp, joint_torque=held.joint_torque)
    floor = rms_pos_mm(pose_residuals(held, true))

    def held_rms(fitted) -> float:
        return rms_pos_mm(pose_residuals(held, fitted.predict(held.q, **held.conditions())))

    plain = select_orders(twin.robot, train).fitted
    diag = diagnose(state_from_fitted(plain), train)
    assert diag.candidates[0].effect == "compliance:j2:torque"
    assert diag.suggested == ("compliance:j2:torque",)
    fitted = select_orders(twin.robot, train, parse_effects("compliance:j2:torque", twin.robot))
    masses = select_orders(twin.robot, train, parse_effects("compliance:j2", twin.robot)).fitted
    before, after = held_rms(plain) / floor, held_rms(fitted.fitted) / floor
    mass = held_rms(masses) / floor
    print(f"compliance:j2:torque held-out / floor: {before:.3f} without, {after:.3f} with, "
          f"{mass:.3f} mass form")  # fmt: skip
    assert after <= 1.05 < mass and before > 1.5
    assert fitted.fitted.effect_params[0][0] == pytest.approx(2.5e-5, rel=0.05)
    assert "torque form" in "\n".join(fitted.fitted.summary())
