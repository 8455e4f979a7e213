"""UrRobot on the real ur-rtde client against the controller simulator: moves and every
fault ending a move within a fraction of a second with the right error (never a hang)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from quickhealth.station.hardware.robot import (
    ConnectionLost,
    Leg,
    MoveStopped,
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
    r = UrRobot(sim.host)
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


def _no_client_threads() -> bool:
    import threading

    return not [t for t in threading.enumerate() if t.name.startswith("ur-rtde")]


def test_abort_during_a_move_stops_the_arm_within_a_second(sim, robot):
    """stop() from another thread (the TUI's abort) jumps the queue and ends the move."""
    import threading

    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    far = np.radians([-40.0, -100.0, 110.0, -70.0, -90.0, -60.0])
    box: dict[str, object] = {}

    def run() -> None:
        try:
            robot.move(far, Leg.JOINT, speed=0.3, accel=1.0)
        except Exception as exc:  # noqa: BLE001 - the test inspects it
            box["error"] = exc
        box["t_end"] = time.monotonic()

    th = threading.Thread(target=run)
    th.start()
    deadline = time.monotonic() + 5.0
    while not sim.state()["moving"]:
        assert time.monotonic() < deadline, "the arm never started moving"
        time.sleep(0.01)
    t0 = time.monotonic()
    robot.stop()
    t_stop = time.monotonic() - t0
    th.join(5.0)
    assert not th.is_alive()
    assert isinstance(box.get("error"), MoveStopped), box
    assert t_stop < 1.0 and float(box["t_end"]) - t0 < 1.0, (t_stop, box["t_end"])
    # The simulator confirms the arm stands still, well short of its target.
    assert not sim.state()["moving"]
    time.sleep(0.5)  # the post-stop ringing (tau 60 ms) dies out
    q_a = np.asarray(sim.state()["q"])
    time.sleep(0.3)
    q_b = np.asarray(sim.state()["q"])
    assert np.max(np.abs(q_b - q_a)) < 1e-5  # encoder noise only: zero joint velocity
    assert np.max(np.abs(q_b - far)) > 0.05
    # Stopped means stopped: no move goes out until the next run clears the stop.
    with pytest.raises(MoveStopped):
        robot.move(Q1, Leg.JOINT)
    assert np.max(np.abs(np.asarray(sim.state()["q"]) - q_b)) < 1e-5
    robot.clear_stop()
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q1, atol=3e-4)


def test_frozen_stream_during_movej_kills_the_client_then_reconnect_works(sim, robot):
    """A frozen stream leaves the C++ client waiting for a handshake that never comes: the
    error is the clear one, the client process is killed (no thread of ours was ever inside
    it), and reconnecting gives a working robot without restarting anything else."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    child = robot._child
    sim.fault("freeze_stream")
    t0 = time.monotonic()
    with pytest.raises(StreamFrozen) as err:
        robot.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
    assert time.monotonic() - t0 < 2.0
    assert "stream froze" in str(err.value) and "\n" not in str(err.value)
    assert child.proc.poll() is not None  # the client process is gone
    assert robot.status().connected is False
    robot.close()
    assert _no_client_threads()
    sim.fault("clear")
    robot.reconnect()
    robot.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q2, atol=3e-4)


def test_link_drop_then_reconnect_without_a_new_robot_object(sim, robot):
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    sim.fault("drop_connection")
    with pytest.raises(ConnectionLost):
        for _ in range(200):
            robot.joints()
            time.sleep(0.01)
    assert not robot.status().connected
    with pytest.raises(ConnectionLost):
        robot.reconnect()  # still refused: the controller is away
    sim.fault("clear")
    robot.reconnect()
    assert robot.status().ready
    robot.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q2, atol=3e-4)


def test_two_simulators_at_once_each_on_its_own_loopback_address(sim, robot):
    """The UR ports are fixed; a second simulator (another test run, a demo) takes another
    127.x address, and each client drives its own arm."""
    other = start_sim_controller(control_port=30099, speed_factor=3.0, wait_s=5.0)
    try:
        assert other.host != sim.host and other.host.startswith("127.")
        with UrRobot(other.host) as r2:
            q_before = np.asarray(sim.state()["q"])
            r2.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
            assert np.allclose(r2.joints(), Q2, atol=3e-4)
            assert np.allclose(np.asarray(other.state()["q"]), Q2, atol=3e-4)
            assert np.max(np.abs(np.asarray(sim.state()["q"]) - q_before)) < 1e-3
    finally:
        other.stop()
