"""The simulated controller drives the cell's arm (issue 24, part B): its model and version,
its joint limits and joint speed limits, its kinematics, and effects hidden in its twin.
No sockets, no real time: the controller's pure parts and the world."""

from __future__ import annotations

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.robot import builtin_robot, gravity_torques
from quickhealth.station.sim.arm import (
    Motion,
    controller_arm,
    joint_path,
    linear_path,
    speed_cap,
)
from quickhealth.station.sim.controller import CMD_MOVEJ, CMD_MOVEL, PlanJob, plan_command
from quickhealth.station.sim.fake_robot import FakeRobot
from quickhealth.station.sim.kinematics import JointLimits
from quickhealth.station.sim.process import build_controller
from quickhealth.station.sim.servers import robot_facts
from quickhealth.station.sim.wire import dashboard_model, max_stream_hz
from quickhealth.station.sim.world import build_world


def test_dashboard_names_the_arm_as_ur_does():
    assert [dashboard_model(n) for n in ("ur3", "ur5", "ur10")] == ["UR3", "UR5", "UR10"]
    assert [dashboard_model(n) for n in ("ur3e", "ur10e", "ur16e", "ur20", "ur30")] == [
        "UR3",
        "UR10",
        "UR16",
        "UR20",
        "UR30",
    ]


@pytest.mark.parametrize(
    "cell, name, model, major, hz",
    [("reference", "ur5", "UR5", 3, 125.0), ("ur10e", "ur10e", "UR10", 5, 500.0)],
)
def test_the_controller_is_the_cells_arm(cell, name, model, major, hz):
    ctrl = build_controller(cell=cell)
    try:
        r = ctrl.arm.ik_model  # its nominal kinematics (ctrl.arm.robot: under its calibration)
        assert r is not None and ctrl.arm.robot.name == name
        assert r.name == name and ctrl.version[0] == major and ctrl.stream_hz == hz
        assert max_stream_hz(ctrl.version) == hz
        own = builtin_robot(name)  # the arm's own limits, not the cell's planning limits
        np.testing.assert_array_equal([r.q_min, r.q_max], [own.q_min, own.q_max])
        np.testing.assert_allclose(r.links, own.links)
        facts = robot_facts(r)
        assert facts["model"] == model and facts["q_max_deg"] == [360.0] * 6
        np.testing.assert_allclose(facts["qd_max_deg_s"], np.degrees(own.qd_max))
    finally:
        ctrl.close()
    explicit = build_controller(cell="ur10e", version=(3, 15, 7, 0))  # what the user says wins
    try:
        assert explicit.stream_hz == 125.0
    finally:
        explicit.close()


def test_a_move_is_slowed_until_no_joint_overspeeds():
    r = builtin_robot("ur10e")  # base and shoulder 120°/s, the others 180°/s
    q0 = np.zeros(6)
    q1 = np.array([1.5, 0.0, 0.0, 0.0, 0.0, 1.0])  # the base leads, the wrist follows
    path = joint_path(q0, q1)
    # 3 rad/s asked of the leading joint: the base may turn at 120°/s only
    v = np.radians(120)
    assert speed_cap(path, r.qd_max) == pytest.approx(v)
    fast = Motion.timed(path, 3.0, 40.0, 0.0, r.qd_max)
    assert fast.duration == pytest.approx(1.5 / v + v / 40.0)
    assert Motion.timed(path, 3.0, 40.0, 0.0).duration == pytest.approx(1.5 / 3.0 + 3.0 / 40.0)
    assert Motion.timed(path, 1.0, 40.0, 0.0, r.qd_max).duration == pytest.approx(1.5 + 1 / 40)
    # a straight line: the limit holds on every path segment
    T = r.fk(np.array([0.2, -1.2, 1.4, -1.8, -1.5, 0.3]))
    q_start = np.array([-0.6, -1.3, 1.5, -1.7, -1.6, 0.1])
    lp = linear_path(r, np.eye(4), q_start, T)
    cap = speed_cap(lp, r.qd_max)
    seg = lp.distance / (lp.q.shape[0] - 1)
    rates = np.abs(np.diff(lp.q, axis=0)) / seg * cap  # rad/s at the capped path speed
    assert np.all(rates <= r.qd_max + 1e-9) and np.any(np.isclose(rates, r.qd_max).any(0))


def test_a_path_leaving_the_arms_joint_limits_is_refused():
    class _Arm:
        robot = controller_arm(builtin_robot("ur10e"))
        tcp = np.eye(4)
        ik_model = None

    lim = JointLimits.of(_Arm.robot)  # the UR10e's own: ±360°, not a cell's planning limits
    q0 = (0.0, -1.5, 1.5, -1.5, -1.5, 0.0)
    far = PlanJob(0, CMD_MOVEJ, (0.0, -1.5, 1.5, -1.5, -1.5, 7.0), 1.0, 1.0, False, q0, lim)
    why = plan_command(_Arm(), far)  # type: ignore[arg-type]
    assert isinstance(why, str) and why.startswith("joint position limit: joint 6 target 401.1")
    near = PlanJob(0, CMD_MOVEJ, (0.0, -1.5, 1.5, -1.5, -1.5, 6.0), 1.0, 1.0, False, q0, lim)
    assert not isinstance(plan_command(_Arm(), near), str)  # inside ±360°
    T = _Arm.robot.fk(np.array(q0))
    from quickhealth.station.sim.arm import pose_from_T

    line = PlanJob(0, CMD_MOVEL, tuple(pose_from_T(T)), 0.1, 1.0, False, q0, lim)
    assert not isinstance(plan_command(_Arm(), line), str)


def test_a_hidden_compliance_bends_the_twin_under_arm_and_target():
    """--sim-degrade compliance:j2=SIZE: the twin's joint 2 turns by c·τ2, τ2 the gravity
    torque of the UR10e's links plus the cell's 1 kg target."""
    healthy = build_world("ur10e", twin_seed=3)
    worn = build_world("ur10e", twin_seed=3, degrade={"compliance:j2": 1e-5})
    assert worn.twin.truth.effects == {"compliance:j2": [1e-5]}
    assert worn.twin.robot.masses[-1] == pytest.approx(0.615 + 1.0)
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (20, 6))
    tau = gravity_torques(worn.twin.robot, q)[:, 1]
    bent = healthy.twin.true_pose(q + np.outer(1e-5 * tau, [0, 1, 0, 0, 0, 0]))
    moved = worn.twin.true_pose(q) - healthy.twin.true_pose(q)
    assert np.abs(moved[:, :3, 3]).max() > 1e-4  # a tenth of a millimetre and more
    # equal up to the joint-2 error terms evaluated at q + dq instead of the reading q
    assert np.abs(worn.twin.true_pose(q) - bent).max() < 1e-3 * np.abs(moved).max()
    with pytest.raises(InputError, match="no clock or temperature"):
        build_world("ur10e", degrade={"thermal": 1e-5})
    with pytest.raises(InputError):
        build_world("ur10e", degrade={"compliance:j9": 1e-5})


def test_the_fake_robot_streams_at_its_controllers_rate():
    assert FakeRobot(model=builtin_robot("ur10e"), time_scale=2.0).sample_period == pytest.approx(
        1 / 500 / 2
    )
    assert FakeRobot().sample_period == pytest.approx(0.008)  # the UR5: 125 Hz


def test_the_tuis_simulated_sensor_keeps_the_farthest_marker_detectable():
    from quickhealth.station.planning.cell import load_cell
    from quickhealth.station.planning.planfile import plan_from_dict, plan_to_dict
    from quickhealth.station.planning.planner import plan_loop
    from quickhealth.station.tui.simulated import sensor_scale

    def scale(name: str) -> float:
        cell = load_cell(name)
        return sensor_scale(cell, plan_from_dict(plan_to_dict(plan_loop(cell, 30, 1)), "p"))

    assert scale("reference") == 0.3  # the paper's cell: as fast as before
    assert 0.35 <= scale("ur10e") <= 0.5  # targets 3 m and more away need a larger sensor
