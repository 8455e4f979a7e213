"""Compliance without inertial data: a UR5 twin with hidden gravity compliance, fitted with the
robot's link masses withheld (the lumped form), against the fit that knows them."""

import dataclasses

import numpy as np
import pytest

from quickhealth.identify.diagnose import diagnose, pose_residuals, rms_pos_mm, state_from_fitted
from quickhealth.identify.effects import parse_effects
from quickhealth.identify.robot import ur5
from quickhealth.identify.select import select_orders
from quickhealth.identify.twin import make_twin, random_joints, schedules


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed"), [("compliance:j2", 100), ("compliance:j3", 107)])
def test_lumped_compliance_predicts_as_well_as_known_masses(effect, seed) -> None:
    """150 training poses (7D), 300 held-out; orders chosen by BIC as ``identify fit`` does.

    Without masses ``compliance:jK`` falls back to the lumped form: its held-out RMS is within
    5 % of the mass form's and at most 1.3× the noise floor; diagnose on the mass-less model
    without the effect ranks the lumped compliance of that joint first and suggests it."""
    twin = make_twin(seed=seed, effects={effect: 2.5e-5})
    q = random_joints(twin.robot, 450, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    train = twin.measure(q[:150], *schedules(150), seed=seed + 2)
    held = twin.measure(q[150:], *schedules(300), seed=seed + 3)
    floor = rms_pos_mm(pose_residuals(held, twin.true_pose(held.q, held.time, held.temp)))

    def held_rms(fitted) -> float:
        return rms_pos_mm(pose_residuals(held, fitted.predict(held.q)))

    bare = dataclasses.replace(ur5(), masses=None, coms=None)
    with_masses = select_orders(twin.robot, train, parse_effects(effect, twin.robot)).fitted
    lumped = select_orders(bare, train, parse_effects(effect, bare)).fitted
    assert with_masses.effects[0].form == "masses"
    assert lumped.effects[0].name == f"{effect}:lumped"
    summary = "\n".join(lumped.summary())
    assert (
        "lumped form, no link masses used" in summary and "identifiable from this data" in summary
    )
    rms_m, rms_l = held_rms(with_masses), held_rms(lumped)
    print(f"{effect}: held-out {rms_m:.4f} (masses) {rms_l:.4f} (lumped) floor {floor:.4f} mm")
    assert rms_l <= 1.05 * rms_m
    assert rms_l <= 1.3 * floor
    # the deflection the lumped fit found is the true one (the twin's c·τ at the held-out poses)
    k = lumped.effects[0].joint
    ctx = lumped.context(held.q)
    found = lumped.effects[0].perturbation(ctx, lumped.effect_params[0]).dq[:, k]
    true = 2.5e-5 * with_masses.context(held.q).gravity_torque[:, k]
    assert np.sqrt(np.mean((found - true) ** 2)) < 0.1 * np.sqrt(np.mean(true**2))

    plain = select_orders(bare, train).fitted
    diag = diagnose(state_from_fitted(plain), train)
    assert diag.candidates[0].effect == f"{effect}:lumped"
    assert diag.suggested[:1] == (f"{effect}:lumped",)
    assert held_rms(plain) > 1.4 * floor  # the effect mattered
