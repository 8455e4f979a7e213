"""Digital twin: reproducible, honest noise, effects where they belong, truth round trip."""

import json

import numpy as np
import pytest

from quickhealth.identify.diagnose import pose_residuals
from quickhealth.identify.effects import Perturbation
from quickhealth.identify.linearize import loop_pose
from quickhealth.identify.measurements import approach_from_order
from quickhealth.identify.twin import (
    TwinTruth,
    camera_pose,
    make_twin,
    random_joints,
    schedules,
    twin_from_truth,
)


def test_same_seed_same_data_other_seed_other_data() -> None:
    a = make_twin(seed=5, effects={"backlash:j2": 3e-4})
    b = make_twin(seed=5, effects={"backlash:j2": 3e-4})
    c = make_twin(seed=6, effects={"backlash:j2": 3e-4})
    q = random_joints(a.robot, 30, seed=1)
    ma, mb, mc = a.measure(q), b.measure(q), c.measure(q)
    np.testing.assert_array_equal(ma.pos, mb.pos)
    np.testing.assert_array_equal(ma.rpy, mb.rpy)
    assert np.abs(ma.pos - mc.pos).max() > 1e-4
    np.testing.assert_array_equal(random_joints(a.robot, 30, seed=1), q)


def test_noise_has_the_stated_size_and_nothing_else_is_random() -> None:
    twin = make_twin(seed=2, sigma_pos=3e-5, sigma_rot=1e-4)
    q = random_joints(twin.robot, 2000, seed=3)
    meas = twin.measure(q, seed=4)
    res = pose_residuals(meas, twin.true_pose(q))
    np.testing.assert_allclose(res[:, :3].std(axis=0), 3e-5, rtol=0.08)
    np.testing.assert_allclose(res[:, 3:].std(axis=0), 1e-4, rtol=0.08)
    assert np.abs(res.mean(axis=0)[:3]).max() < 4 * 3e-5 / np.sqrt(2000)
    # encoder noise goes on the readings, not on the pose
    twin_q = make_twin(seed=2, sigma_pos=0.0, sigma_rot=0.0, sigma_q=1e-4)
    mq = twin_q.measure(q, seed=4)
    np.testing.assert_allclose((mq.q - q).std(), 1e-4, rtol=0.08)
    np.testing.assert_allclose(mq.pos, twin_q.true_pose(q)[:, :3, 3], atol=1e-15)


def test_geometry_is_the_same_with_and_without_effects_and_backlash_shifts_the_joint() -> None:
    b = 5e-4
    plain = make_twin(seed=9)
    lash = make_twin(seed=9, effects={"backlash:j3": b})
    q = random_joints(plain.robot, 50, seed=2)
    app = approach_from_order(q)
    shifted = q.copy()
    shifted[:, 2] += 0.5 * b * app[:, 2]
    t = plain.truth
    expect = loop_pose(
        plain.robot,
        t.spec,
        t.coeffs,
        t.T_instr_base,
        t.T_flange_target,
        q,
        Perturbation(dq=shifted - q),
    )
    np.testing.assert_allclose(lash.true_pose(q), expect, atol=1e-14)
    assert np.abs(lash.true_pose(q) - plain.true_pose(q))[:, :3, 3].max() > 1e-4


def test_effects_that_need_schedules_ask_for_them() -> None:
    twin = make_twin(seed=1, effects={"thermal": 2e-5, "drift": 1e-7})
    q = random_joints(twin.robot, 20, seed=1)
    with pytest.raises(ValueError, match="temp"):
        twin.true_pose(q, time=np.arange(20.0))
    t, temp = schedules(20, duration=600.0, temp_rise=5.0)
    assert t[0] == 0 and t[-1] == 600.0 and temp[0] == 21.0 and 25.5 < temp[-1] < 26.0
    m = twin.measure(q, t, temp)
    assert m.time is not None and m.temp is not None
    # thermal growth with a rising temperature lengthens the arm: points move away from base
    cold = twin.true_pose(q, t, np.full(20, 20.0))
    warm = twin.true_pose(q, t, np.full(20, 30.0))
    assert np.abs(warm - cold)[:, :3, 3].max() > 1e-5


def test_truth_round_trips_through_json() -> None:
    twin = make_twin(seed=3, effects={"cyclic:j1:h9": 2e-4, "drift": 1e-7, "depthscale": 1e-4})
    doc = json.loads(json.dumps(twin.truth.to_dict()))
    assert doc["effects"]["cyclic:j1:h9"] and len(doc["effects"]["drift"]) == 6
    again = twin_from_truth(TwinTruth.from_dict(doc))
    q = random_joints(twin.robot, 10, seed=1)
    t, temp = schedules(10)
    np.testing.assert_allclose(again.true_pose(q, t, temp), twin.true_pose(q, t, temp), atol=0)
    amp = np.hypot(*twin.truth.effects["cyclic:j1:h9"])
    assert amp == pytest.approx(2e-4)


def test_random_joints_are_in_view_above_the_table_and_spread() -> None:
    twin = make_twin(seed=0)
    T_ib = twin.truth.T_instr_base
    q = random_joints(twin.robot, 300, seed=4, T_instr_base=T_ib)
    assert q.shape == (300, 6)
    T = twin.true_pose(q)
    p_cam = T[:, :3, 3]
    assert np.all(p_cam[:, 2] > 1.0) and np.all(p_cam[:, 2] < 3.0)  # ~2 m in front
    ang = np.degrees(np.arctan2(np.linalg.norm(p_cam[:, :2], axis=1), p_cam[:, 2]))
    assert ang.max() < 30.5
    p_base = twin.robot.fk(q)[:, :3, 3]
    assert np.all(p_base[:, 2] > -0.1)
    assert np.all(np.ptp(q, axis=0)[[0, 3, 4, 5]] > 5.0)  # wide joint coverage (rad)
    # the camera looks at the base from 2 m
    np.testing.assert_allclose(np.linalg.norm(np.linalg.inv(camera_pose())[:3, 3][:2]), 2.0)
