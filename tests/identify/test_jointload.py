"""What a controller reports about each joint: drive torques and temperatures warmed by duty."""

import numpy as np
import pytest

from quickhealth.identify.jointload import (
    IDLE_W,
    THERMAL_RESISTANCE,
    THERMAL_TAU_S,
    TORQUE_CONSTANT,
    WINDING_OHM,
    drive_torques,
    warm_up,
)
from quickhealth.identify.robot import gravity_torques, ur5, with_payload
from quickhealth.identify.twin import joint_schedules, make_twin, payloads, random_joints


def test_drive_torques_hold_arm_and_payload_against_gravity():
    robot = ur5()
    q = random_joints(robot, 30, seed=1)
    m = payloads(30, 2.0, seed=2)
    tau = drive_torques(robot, q, m)
    for i in (0, 7, 19):
        expect = -gravity_torques(with_payload(robot, m[i], (0.0, 0.0, 0.05)), q[i : i + 1])[0]
        np.testing.assert_allclose(tau[i], expect, atol=1e-9)
    assert np.any(m == 0.0) and np.any(m > 0.4)  # empty and carrying, both
    np.testing.assert_allclose(drive_torques(robot, q), -gravity_torques(robot, q))
    with pytest.raises(ValueError, match="payload"):
        drive_torques(robot, q, -1.0)


def test_warm_up_is_the_first_order_response_to_constant_duty():
    """A joint holding a constant torque at rest heats by R·I² + idle towards
    T_amb + R_th·P with its own time constant; a moving joint heats more; cooling follows."""
    n = 400
    t = np.linspace(0.0, 4000.0, n)
    q = np.zeros((n, 6))
    tau = np.tile([0.0, 40.0, 15.0, 2.0, 1.0, 0.1], (n, 1))
    temps = warm_up(t, q, tau, 22.0)
    P = WINDING_OHM * (tau[0] / TORQUE_CONSTANT) ** 2 + IDLE_W
    expect = 22.0 + THERMAL_RESISTANCE * P * (1.0 - np.exp(-t[:, None] / THERMAL_TAU_S))
    np.testing.assert_allclose(temps, expect, atol=1e-9)
    assert temps[-1, 1] > temps[-1, 3] > 22.0  # the loaded shoulder is the warmest
    moving = q.copy()
    moving[:, 1] = np.where(np.arange(n) % 2, 0.5, -0.5)  # the shoulder swings every leg
    assert warm_up(t, moving, tau, 22.0)[-1, 1] > temps[-1, 1] + 5.0
    hot = warm_up(t, q, np.zeros_like(tau), 22.0, start=np.full(6, 40.0))
    assert np.all(np.diff(hot[:, 0]) < 0) and hot[-1, 0] < 30.0  # cools towards the ambient


def test_the_twin_records_the_joint_conditions_it_measured_at():
    twin = make_twin(seed=3)
    q = random_joints(twin.robot, 20, seed=4, T_instr_base=twin.truth.T_instr_base)
    t = np.linspace(0.0, 900.0, 20)
    temp = np.full(20, 22.0)
    jt, tau = joint_schedules(twin.robot, q, t, temp, payloads(20, 1.5, seed=5))
    assert jt.shape == tau.shape == (20, 6)
    assert np.all(np.diff(jt[:, 1]) > 0)  # the shoulder warms during the run
    m = twin.measure(q, t, temp, joint_temp=jt, joint_torque=tau)
    np.testing.assert_array_equal(m.joint_temp, jt)
    np.testing.assert_array_equal(m.joint_torque, tau)
    sub = m.subset(np.arange(5, 12))
    np.testing.assert_array_equal(sub.joint_temp, jt[5:12])
