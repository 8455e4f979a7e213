"""Analytic UR inverse kinematics: all eight solutions, verified by forward kinematics."""

from __future__ import annotations

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.robot import from_dh, ur5
from quickhealth.station.planning.ik_ur import BRANCH_NAMES, ik_ur, within_limits, wrap_near


def test_every_solution_reproduces_the_pose_and_the_original_is_among_them():
    robot = ur5()
    rng = np.random.default_rng(3)
    q = rng.uniform(-np.pi, np.pi, (3000, 6))
    T = robot.fk(q)
    Q, valid = ik_ur(robot, T)
    assert Q.shape == (3000, 8, 6) and valid.shape == (3000, 8)
    # independent FK of every valid solution
    Tq = robot.fk(np.where(valid[..., None], Q, 0.0).reshape(-1, 6)).reshape(3000, 8, 4, 4)
    err = np.linalg.norm(Tq[..., :3, 3] - T[:, None, :3, 3], axis=-1)
    assert np.all(err[valid] < 1e-7)
    d = np.abs((Q - q[:, None] + np.pi) % (2 * np.pi) - np.pi).max(-1)
    assert np.all(np.nanmin(np.where(valid, d, np.nan), axis=1) < 1e-8)
    # generic poses inside the workspace have all eight solutions most of the time
    assert np.mean(valid.sum(1) == 8) > 0.5
    # the eight solutions are distinct configurations
    full = valid.sum(1) == 8
    Qf = Q[full]
    pair = np.abs(Qf[:, :, None] - Qf[:, None, :]).max(-1) + np.eye(8) * 10
    assert pair.min() > 1e-6
    assert len(set(BRANCH_NAMES)) == 8


def test_single_pose_shape_and_unreachable_pose():
    robot = ur5()
    Q, valid = ik_ur(robot, robot.fk(np.array([0.1, -1.2, 1.0, -0.5, 1.2, 0.3])))
    assert Q.shape == (8, 6) and valid.shape == (8,) and valid.sum() == 8
    far = np.eye(4)
    far[:3, 3] = [2.0, 0.0, 0.3]  # 2 m away: beyond the 0.85 m reach
    Q, valid = ik_ur(robot, far)
    assert not valid.any()


def test_wrist_singularity_still_solved():
    robot = ur5()
    q = np.array([0.4, -1.0, 1.2, 0.3, 0.0, 0.7])  # θ5 = 0: joints 4 and 6 aligned
    Q, valid = ik_ur(robot, robot.fk(q))
    assert valid.any()
    Tq = robot.fk(Q[valid])
    assert np.allclose(Tq, robot.fk(q), atol=1e-7)


def test_non_ur_robot_is_refused():
    bad = from_dh("planar", a=[0.3] * 6, d=[0.0] * 6, alpha=[0.0] * 6)
    with pytest.raises(InputError, match="UR"):
        ik_ur(bad, np.eye(4))


def test_wrap_near_and_limits():
    lo, hi = np.full(6, -np.pi), np.full(6, np.pi)
    q = wrap_near(np.full(6, 3.0), np.full(6, -3.0), lo, hi)
    assert np.allclose(q, 3.0)  # -3.0 + 2π ... would be outside; the in-limit equivalent is kept
    q2 = wrap_near(np.full(6, 3.0), np.full(6, -3.0), np.full(6, -2 * np.pi), np.full(6, 2 * np.pi))
    assert np.allclose(q2, 3.0 - 2 * np.pi)
    assert within_limits(np.zeros(6), ur5())
    assert not within_limits(np.full(6, 7.0), ur5())
