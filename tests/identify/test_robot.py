"""Robot kinematics against known values and independent implementations."""

import numpy as np
import pinocchio as pin
from hypothesis import given, settings
from hypothesis import strategies as st

from quickhealth.identify.errormodel import ErrorModelSpec, chebyshev_basis
from quickhealth.identify.linearize import loop_pose
from quickhealth.identify.robot import chain, from_dh, gravity_torques, ur5
from quickhealth.identify.transforms import (
    R_to_rpy,
    exp_so3,
    inv_T,
    log_so3,
    rpy_to_R,
    small_error_transform,
)

angles = st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6)


def _dh_reference(q):
    """Textbook standard-DH product, written independently of robot.chain."""
    a = [0, -0.425, -0.39225, 0, 0, 0]
    d = [0.089159, 0, 0, 0.10915, 0.09465, 0.0823]
    al = [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0]
    T = np.eye(4)
    for i in range(6):
        ct, st_, ca, sa = np.cos(q[i]), np.sin(q[i]), np.cos(al[i]), np.sin(al[i])
        A = np.array(
            [
                [ct, -st_ * ca, st_ * sa, a[i] * ct],
                [st_, ct * ca, -ct * sa, a[i] * st_],
                [0, sa, ca, d[i]],
                [0, 0, 0, 1],
            ]
        )
        T = T @ A
    return T


def test_ur5_zero_pose_matches_published_geometry() -> None:
    T = ur5().fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [-0.81725, -0.19145, -0.005491], atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(angles)
def test_ur5_fk_matches_textbook_dh(q) -> None:
    np.testing.assert_allclose(ur5().fk(np.array(q)), _dh_reference(q), atol=1e-12)


def test_modified_dh_equals_standard_dh_rewritten() -> None:
    # A 2-link planar arm: standard (a=[1, 1]) equals modified (a_{i-1}=[0, 1]) plus a tool of 1 m.
    std = from_dh("p", a=[1.0, 1.0], d=[0, 0], alpha=[0, 0])
    mdh = from_dh("p", a=[0.0, 1.0], d=[0, 0], alpha=[0, 0], modified=True)
    q = np.random.default_rng(0).uniform(-2, 2, (20, 2))
    tool = np.eye(4)
    tool[0, 3] = 1.0
    np.testing.assert_allclose(std.fk(q), mdh.fk(q) @ tool, atol=1e-12)


def test_gravity_torques_match_pinocchio_rnea() -> None:
    robot = ur5()
    model = pin.Model()
    parent = 0
    for i in range(6):
        placement = pin.SE3(robot.links[i][:3, :3], robot.links[i][:3, 3])
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{i}")
        # inertia about the CoM given in the frame after Rz·C_i; pinocchio's body frame is after Rz
        com_body = robot.links[i + 1][:3, :3] @ robot.coms[i] + robot.links[i + 1][:3, 3]
        model.appendBodyToJoint(
            jid, pin.Inertia(robot.masses[i], com_body, np.eye(3) * 1e-3), pin.SE3.Identity()
        )
        parent = jid
    model.gravity = pin.Motion(np.array([0, 0, -9.80665]), np.zeros(3))
    data = model.createData()
    q = np.random.default_rng(1).uniform(-3, 3, (10, 6))
    ours = gravity_torques(robot, q)
    for k in range(10):
        # pinocchio's g(q) is the torque the motors must supply: the negative of gravity's torque.
        np.testing.assert_allclose(
            ours[k], -pin.computeGeneralizedGravity(model, data, q[k]), atol=1e-9
        )


@settings(max_examples=50, deadline=None)
@given(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_rpy_round_trip(p, y, r) -> None:
    np.testing.assert_allclose(R_to_rpy(rpy_to_R(p, y, r)), [p, y, r], atol=1e-9)


def test_so3_log_exp_round_trip_including_near_pi() -> None:
    rng = np.random.default_rng(2)
    w = rng.normal(size=(200, 3))
    w *= (rng.uniform(0, np.pi - 1e-6, 200) / np.linalg.norm(w, axis=1))[:, None]
    w[:3] *= (np.pi - 1e-5) / np.linalg.norm(w[:3], axis=1)[:, None]
    R = exp_so3(w)
    np.testing.assert_allclose(exp_so3(log_so3(R)), R, atol=1e-7)


def test_chebyshev_basis_matches_numpy() -> None:
    u = np.linspace(-1, 1, 101)
    B = chebyshev_basis(u, 8)
    for k in range(9):
        np.testing.assert_allclose(
            B[:, k], np.polynomial.chebyshev.chebval(u, np.eye(9)[k]), atol=1e-12
        )


def test_zero_error_model_is_nominal_kinematics_with_base_and_tool() -> None:
    robot = ur5()
    q = np.random.default_rng(3).uniform(-3, 3, (30, 6))
    spec = ErrorModelSpec.uniform(6, 3, robot.q_min, robot.q_max)
    base = small_error_transform([1.0, -2.0, 0.5], [0.1, 0.2, 3.0])
    tool = small_error_transform([0.0, 0.0, 0.1], [0, 0, 0])
    T = loop_pose(robot, spec, np.zeros(spec.n_params), base, tool, q)
    np.testing.assert_allclose(T, base @ robot.fk(q) @ tool, atol=1e-12)
    np.testing.assert_allclose(inv_T(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


def test_joint_error_ez_is_a_joint_offset() -> None:
    """A constant εz on joint 2 equals turning joint 2 by that angle."""
    robot = ur5()
    q = np.random.default_rng(4).uniform(-3, 3, (10, 6))
    E = np.broadcast_to(np.eye(4), (10, 6, 4, 4)).copy()
    E[:, 1] = small_error_transform([0, 0, 0], [0, 0, 1e-3])
    dq = np.zeros_like(q)
    dq[:, 1] = 1e-3
    np.testing.assert_allclose(chain(robot, q, E_joint=E), chain(robot, q, dq=dq), atol=1e-12)
