"""UrRobot on the real ur-rtde client against the controller simulator: moves and every
fault ending a move within a fraction of a second with the right error (never a hang)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from quickhealth.station.hardware.robot import (
    ConnectionLost,
    Leg,
    ProgramStopped,
    ProtectiveStop,
    SafetyMode,
    StreamFrozen,
    UrRobot,
)
from quickhealth.station.hardware.simcontroller import start_sim_controller

# The timeout includes waiting for the UR ports (one simulator per host).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(200)]

Q1 = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])
Q2 = np.radians([25.0, -70.0, 70.0, -95.0, -85.0, 20.0])


@pytest.fixture(scope="module")
def sim():
    h = start_sim_controller(control_port=30093, speed_factor=3.0)
    try:
        yield h
    finally:
        h.stop()


@pytest.fixture
def robot(sim):
    sim.fault("clear")
    r = UrRobot("127.0.0.1")
    try:
        yield r
    finally:
        r.close()


def test_joint_and_linear_legs_end_at_their_targets(robot):
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q1, atol=3e-4)
    robot.move(Q2, Leg.LINEAR, speed=0.25, accel=1.0)
    time.sleep(0.3)
    assert np.allclose(robot.joints(), Q2, atol=3e-5)
    T = robot.tcp_pose()
    assert np.allclose(T, robot.model.fk(robot.joints()), atol=1e-4)
    st = robot.status()
    assert st.ready and st.program_running and st.safety_mode is SafetyMode.NORMAL


@pytest.mark.parametrize(
    "kind, exc, words",
    [
        ("protective_stop", ProtectiveStop, "protective stop"),
        ("program_stop", ProgramStopped, "control program stopped"),
        ("freeze_stream", StreamFrozen, "stream froze"),
        ("drop_connection", ConnectionLost, "lost the"),
    ],
)
def test_fault_mid_move_ends_it_quickly_with_advice(sim, robot, kind, exc, words):
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    sim.fault(kind, after_s=0.15)
    t0 = time.monotonic()
    with pytest.raises(exc) as err:
        robot.move(np.radians([-20.0, -100.0, 100.0, -80.0, -90.0, -30.0]), speed=0.5, accel=1.0)
    dt = time.monotonic() - t0
    assert dt < 1.5, dt
    msg = str(err.value)
    assert words in msg and "--resume" in msg and "\n" not in msg
    if kind == "protective_stop":
        assert sim.state()["safety_mode"] == 3
    sim.fault("clear")
