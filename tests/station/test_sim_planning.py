"""The simulated controller plans motions outside its lock, with the analytic UR IK.

In-process tests of :mod:`quickhealth.station.sim` (no sockets, no ur-rtde): the register
protocol is driven through ``Controller.set_inputs`` exactly as the RTDE server does with
a client's input packets.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import qh_station_plan as _station_plan

from quickhealth.identify.robot import ur5
from quickhealth.station.hardware.legs import Leg
from quickhealth.station.hardware.urtypes import RuntimeState, SafetyMode
from quickhealth.station.planning.planfile import load_plan
from quickhealth.station.sim.arm import (
    HOME_Q_DEG,
    Arm,
    linear_path,
    linear_path_dls,
    pose_from_T,
)
from quickhealth.station.sim.controller import (
    CMD_MOVEJ,
    CMD_MOVEL,
    CMD_MOVEL_FK,
    CMD_NONE,
    CMD_STOPJ,
    Controller,
    plan_command,
)

RUNNING_BIT = 1 << 15


@pytest.fixture
def ctrl():
    c = Controller(Arm(ur5(), np.radians(HOME_Q_DEG)))
    c.start_program()
    yield c
    c.close()


def _command(ctrl: Controller, cmd: int, target, speed: float, accel: float, *, sync: bool):
    regs = {f"input_double_register_{i}": float(v) for i, v in enumerate(target)}
    regs.update(
        input_int_register_0=cmd,
        input_double_register_6=speed,
        input_double_register_7=accel,
        input_int_register_1=0 if sync else 1,
    )
    ctrl.set_inputs(regs)


def _snapshot_within(ctrl: Controller, timeout: float = 1.0) -> dict:
    """A snapshot taken by another thread, which must return within ``timeout`` seconds."""
    out: list[dict] = []
    t = threading.Thread(target=lambda: out.append(ctrl.snapshot()), daemon=True)
    t.start()
    t.join(timeout)
    assert out, f"snapshot() blocked for more than {timeout} s"
    return out[0]


def _wait(pred, timeout: float = 10.0) -> None:
    t0 = time.monotonic()
    while not pred():
        assert time.monotonic() - t0 < timeout, "timed out"
        time.sleep(0.005)


def _held_planner(ctrl: Controller):
    """Make the planner wait for a go (a planner as slow as we like); returns (started, go)."""
    started, go = threading.Event(), threading.Event()

    def slow(arm, job):
        started.set()
        go.wait(20)
        return plan_command(arm, job)

    ctrl.plan_fn = slow
    return started, go


def test_snapshot_keeps_streaming_while_a_sync_move_l_is_planned(ctrl):
    started, go = _held_planner(ctrl)
    q0 = ctrl.arm.q_cmd.copy()
    goal = pose_from_T(ctrl.arm.robot.fk(q0))
    goal[0] += 0.15
    goal[2] -= 0.25
    _command(ctrl, CMD_MOVEL, goal, 0.5, 4.0, sync=True)  # within every joint speed limit
    assert started.wait(5)
    stamps = []
    for _ in range(5):  # the planner is held: the stream goes on, the move is not done
        s = _snapshot_within(ctrl)
        stamps.append(s["timestamp"])
        assert s["output_int_register_0"] != 2
        assert np.allclose(s["target_q"], q0)
        time.sleep(0.01)
    assert np.all(np.diff(stamps) > 0)
    assert ctrl.planning is not None and not ctrl.arm.moving(ctrl.now())
    go.set()
    _wait(lambda: ctrl.snapshot()["output_int_register_0"] == 2)  # done only when it arrived
    s = ctrl.snapshot()
    assert np.allclose(s["target_TCP_pose"][:3], goal[:3], atol=1e-9)
    _command(ctrl, CMD_NONE, [0.0] * 6, 0.0, 0.0, sync=True)
    assert ctrl.snapshot()["output_int_register_0"] == 1


def test_async_move_reports_running_at_zero_progress_while_planned(ctrl):
    started, go = _held_planner(ctrl)
    q1 = ctrl.arm.q_cmd + np.radians([10.0, 5.0, -5.0, 0.0, 0.0, 0.0])
    _command(ctrl, CMD_MOVEL_FK, q1, 0.5, 4.0, sync=False)
    assert started.wait(5)
    s = _snapshot_within(ctrl)
    assert s["output_int_register_0"] == 2  # async: acknowledged at once
    reg2 = s["output_int_register_2"]
    assert reg2 & RUNNING_BIT and reg2 & 0x7FFF == 0
    go.set()
    _wait(lambda: (ctrl.snapshot()["output_int_register_2"] & RUNNING_BIT) == 0)
    assert np.allclose(ctrl.snapshot()["target_q"], q1, atol=1e-12)  # moveL_FK ends at q1


def test_stop_during_planning_cancels_the_move(ctrl):
    started, go = _held_planner(ctrl)
    q0 = ctrl.arm.q_cmd.copy()
    _command(ctrl, CMD_MOVEL_FK, q0 + 0.2, 0.5, 4.0, sync=False)
    assert started.wait(5)
    _command(ctrl, CMD_NONE, [0.0] * 6, 0.0, 0.0, sync=False)
    _command(ctrl, CMD_STOPJ, [2.0] * 6, 0.0, 0.0, sync=False)
    go.set()
    _wait(lambda: ctrl.planning is None)
    time.sleep(0.05)  # the planner finished its (stale) job meanwhile
    s = ctrl.snapshot()
    assert not ctrl.arm.moving(ctrl.now()) and np.allclose(s["target_q"], q0)
    assert s["output_int_register_2"] == -1


def test_a_failed_plan_is_a_protective_stop(ctrl):
    ctrl.plan_fn = lambda arm, job: 1 / 0
    q0 = ctrl.arm.q_cmd.copy()
    _command(ctrl, CMD_MOVEL_FK, q0 + 0.1, 0.5, 4.0, sync=True)
    _wait(lambda: ctrl.safety_mode == SafetyMode.PROTECTIVE_STOP)
    assert any("path planning failed: ZeroDivisionError" in line for line in ctrl.log)
    assert np.allclose(ctrl.snapshot()["target_q"], q0)


def test_move_j_needs_no_planner(ctrl):
    ctrl.plan_fn = lambda arm, job: pytest.fail("moveJ must not be planned")
    _command(ctrl, CMD_MOVEJ, ctrl.arm.q_cmd + 0.1, 1.0, 1.4, sync=False)
    assert ctrl.arm.moving(ctrl.now())


def test_restart_drops_everything_and_refuses_connections_for_down_s(ctrl):
    _command(ctrl, CMD_MOVEJ, ctrl.arm.q_cmd + 0.3, 0.5, 1.0, sync=True)
    assert ctrl.arm.moving(ctrl.now())
    ctrl.add_fault({"kind": "restart", "down_s": 0.3})
    s = ctrl.snapshot()
    assert not ctrl.arm.moving(ctrl.now())
    assert s["runtime_state"] == RuntimeState.STOPPED and s["safety_mode"] == SafetyMode.NORMAL
    assert s["robot_mode"] == 7 and s["output_int_register_0"] == 0 and ctrl.inputs == {}
    assert not ctrl.accepting()
    time.sleep(0.35)
    assert ctrl.accepting()
    with pytest.raises(ValueError, match="down_s"):
        ctrl.add_fault({"kind": "restart", "down_s": "soon"})


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return load_plan(_station_plan.plan_file(tmp_path_factory.getbasetemp()))


@pytest.mark.slow
def test_analytic_path_equals_the_dls_path_on_the_reference_plans_linear_legs(plan):
    robot = plan.robot
    legs = []
    prev = plan.home if plan.home is not None else np.radians(HOME_Q_DEG)
    for p in plan.poses:
        if p.leg == Leg.LINEAR:
            length = np.linalg.norm(robot.fk(p.q)[:3, 3] - robot.fk(prev)[:3, 3])
            legs.append((length, prev, p.q))
        prev = p.q
    legs.sort(key=lambda leg: -leg[0])
    assert len(legs) >= 3
    tcp = np.eye(4)
    for _, qa, qb in legs[:4]:  # the longest lines (the most samples)
        fast = linear_path(robot, tcp, qa, robot.fk(qb), q_goal=qb)
        ref = linear_path_dls(robot, tcp, qa, robot.fk(qb), q_goal=qb)
        assert fast.method == "analytic" and ref.method == "dls"
        assert fast.q.shape == ref.q.shape and fast.q.shape[0] > 10
        assert np.max(np.abs(fast.q - ref.q)) < 1e-6
        assert np.array_equal(fast.q[-1], qb) and fast.distance == ref.distance


def test_lines_the_closed_form_cannot_solve_fall_back_to_dls():
    robot = ur5()
    up = np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0])  # stretched straight up: full reach
    T = robot.fk(up)
    T[2, 3] += 0.02  # out of reach: the old controller's DLS did its best, so do we
    path = linear_path(robot, np.eye(4), up, T)
    assert path.method == "dls" and np.all(np.isfinite(path.q))
    generic = replace(robot, convention="generic")  # not a UR DH table: no closed form
    q0 = np.radians(HOME_Q_DEG)
    T = robot.fk(q0)
    T[0, 3] += 0.03
    slow, ref = linear_path(generic, np.eye(4), q0, T), linear_path(robot, np.eye(4), q0, T)
    assert slow.method == "dls" and ref.method == "analytic"
    assert np.max(np.abs(slow.q - ref.q)) < 1e-6
