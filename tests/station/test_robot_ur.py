"""UrRobot on the real ur-rtde client against the controller simulator: moves and every
fault ending a move within a fraction of a second with the right error (never a hang), and
stops that are only reported done when the simulator confirms the arm is still."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from quickhealth.identify.errors import HardwareError, InputError
from quickhealth.station.hardware.robot import (
    REST_TOL_RAD,
    ConnectionLost,
    Leg,
    MoveStopped,
    ProgramStopped,
    ProtectiveStop,
    SafetyMode,
    StreamFrozen,
    UrRobot,
)
from quickhealth.station.sim.process import start_sim_controller

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
    T = robot.tcp_pose()  # through the controller's factory calibration, not nominal DH
    dev = np.linalg.norm(T[:3, 3] - robot.model.fk(robot.joints())[:3, 3])
    assert 1e-5 < dev < 5e-3
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


FAR = np.radians([-40.0, -100.0, 110.0, -70.0, -90.0, -60.0])


def _gone(pid: int) -> bool:
    """True when no process ``pid`` exists any more (ended and reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def _move_in_thread(robot, q, speed: float) -> tuple[threading.Thread, dict]:  # type: ignore[no-untyped-def]
    box: dict[str, object] = {}

    def run() -> None:
        try:
            robot.move(q, Leg.JOINT, speed=speed, accel=1.0)
        except Exception as exc:  # noqa: BLE001 - the test inspects it
            box["error"] = exc
        box["t_end"] = time.monotonic()

    th = threading.Thread(target=run)
    th.start()
    return th, box


def _wait_moving(sim, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not sim.state()["moving"]:
        assert time.monotonic() < deadline, "the arm never started moving"
        time.sleep(0.01)


def _stands_still(sim) -> np.ndarray:
    """The simulator's own word: no motion, and (after the post-stop ringing) the joints
    stay put to encoder noise: zero joint velocity.  Returns where the arm stands."""
    assert not sim.state()["moving"]
    time.sleep(0.5)  # the post-stop ringing (tau 60 ms) dies out
    q_a = np.asarray(sim.state()["q"])
    time.sleep(0.3)
    q_b = np.asarray(sim.state()["q"])
    assert np.max(np.abs(q_b - q_a)) < 1e-5
    return q_b


def _stops_since(sim, t0: float) -> list[tuple[float, str]]:
    """Stop commands the simulator received after ``t0`` (s after it, how)."""
    return [
        (s["at_monotonic"] - t0, s["via"]) for s in sim.state()["stops"] if s["at_monotonic"] >= t0
    ]


def test_abort_during_a_move_stops_the_arm_within_a_second(sim, robot):
    """stop() from another thread (the TUI's abort) jumps the queue and ends the move."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    far = FAR
    th, box = _move_in_thread(robot, far, 0.3)
    _wait_moving(sim)
    t0 = time.monotonic()
    robot.stop()
    t_stop = time.monotonic() - t0
    th.join(5.0)
    assert not th.is_alive()
    assert isinstance(box.get("error"), MoveStopped), box
    assert t_stop < 1.0 and float(box["t_end"]) - t0 < 1.0, (t_stop, box["t_end"])
    # The stop went over RTDE (stopJ), and the simulator confirms the arm stands still,
    # well short of its target.
    assert [how for _, how in _stops_since(sim, t0)] == ["stopj"]  # no dashboard needed
    q_b = _stands_still(sim)
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
    # The client process was killed with every thread in it (one was inside moveJ, waiting
    # for a handshake the frozen stream never shows): nothing of it is left.
    assert child.proc.returncode == -signal.SIGKILL
    assert _gone(child.proc.pid)
    assert robot.status().connected is False
    robot.close()
    sim.fault("clear")
    robot.reconnect()
    robot.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q2, atol=3e-4)
    # A clean close: the client's receiver and commander threads ended (the client says so
    # as its last words), then its process exited on its own.
    child = robot._child
    robot.close()
    assert child.farewell == {"threads": []}, child.farewell
    assert child.proc.returncode == 0 and _gone(child.proc.pid)


def test_stop_after_a_frozen_stream_mid_move_stops_the_arm_through_the_dashboard(sim, robot):
    """A frozen stream mid-move: the run's move ends with the clear error and its client is
    killed, while the controller (no watchdog) keeps the motion going.  stop() then stops it
    through the dashboard server, and only then reports success."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    th, box = _move_in_thread(robot, FAR, 0.1)
    _wait_moving(sim)
    sim.fault("freeze_stream")
    th.join(5.0)
    assert isinstance(box.get("error"), StreamFrozen), box
    assert sim.state()["moving"]  # the client is gone; the controller still moves the arm
    t0 = time.monotonic()
    robot.stop()
    assert time.monotonic() - t0 < 1.0
    assert [how for _, how in _stops_since(sim, t0)] == ["dashboard"]
    _stands_still(sim)
    assert sim.state()["runtime_state"] != 2  # the dashboard's stop ends the program
    sim.fault("clear")
    robot.reconnect()  # the new client uploads the program again
    robot.clear_stop()
    robot.move(Q2, Leg.JOINT, speed=1.0, accel=1.4)
    assert np.allclose(robot.joints(), Q2, atol=3e-4)


def test_stop_while_the_stream_is_frozen_but_not_yet_detected(sim, robot):
    """The stream froze 0.2 s ago (the move has not noticed yet): RTDE cannot confirm a stop
    then, so the client says so at once and the dashboard stops the arm."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    th, box = _move_in_thread(robot, FAR, 0.1)
    _wait_moving(sim)
    sim.fault("freeze_stream")
    time.sleep(0.2)
    t0 = time.monotonic()
    robot.stop()
    assert time.monotonic() - t0 < 1.0
    th.join(5.0)
    assert isinstance(box.get("error"), HardwareError), box
    assert "dashboard" in [how for _, how in _stops_since(sim, t0)]
    sim.fault("clear")  # the stream again: the simulator reports the arm as it is
    _stands_still(sim)


def test_a_real_freeze_is_detected_with_a_busy_core(sim, robot):
    """Time the client process was not running does not count towards the 0.5 s freeze check
    (it could see nothing then), but a real freeze is still caught after 0.5 s of watched
    time while another process keeps a core busy: the move ends with the clear error soon
    after, never before the stream stood still 0.5 s."""
    import re

    burner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
        th, box = _move_in_thread(robot, FAR, 0.1)
        _wait_moving(sim)
        t_freeze = time.monotonic()
        sim.fault("freeze_stream")
        th.join(10.0)
        err = box.get("error")
        assert isinstance(err, StreamFrozen), box
        detected = float(box["t_end"]) - t_freeze
        still = float(re.search(r"unchanged for ([0-9.]+) s", str(err)).group(1))
        assert still >= 0.5 and 0.5 <= detected < 2.0, (still, detected)
    finally:
        burner.kill()
        burner.wait()
    robot.stop()
    assert sim.state()["stops"][-1]["via"] == "dashboard"
    sim.fault("clear")
    _stands_still(sim)


def test_stop_after_a_link_drop_mid_move_goes_through_the_dashboard(sim, robot):
    """Every connection drops mid-move and the link stays away until the client is gone (a
    client whose link comes back at once reconnects by itself, and ur-rtde's reconnect stops
    the program): the controller keeps moving the arm; stop() stops it by the dashboard."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    th, box = _move_in_thread(robot, FAR, 0.1)
    _wait_moving(sim)
    sim.fault("drop_connection")
    th.join(5.0)
    assert isinstance(box.get("error"), ConnectionLost), box  # and the client was killed
    sim.fault("clear")  # the link is back
    assert sim.state()["moving"]
    t0 = time.monotonic()
    robot.stop()
    assert time.monotonic() - t0 < 1.0
    assert [how for _, how in _stops_since(sim, t0)] == ["dashboard"]
    _stands_still(sim)


def test_a_stop_nobody_can_confirm_raises_and_says_the_arm_may_move(sim, robot):
    """The link is down and the controller refuses every connection: neither the client nor
    the dashboard can confirm the stop, so stop() says so instead of reporting success."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    th, box = _move_in_thread(robot, FAR, 0.1)
    _wait_moving(sim)
    sim.fault("drop_connection")
    th.join(5.0)
    assert isinstance(box.get("error"), ConnectionLost), box
    t0 = time.monotonic()
    with pytest.raises(HardwareError) as err:
        robot.stop()
    assert time.monotonic() - t0 < 3.0
    msg = str(err.value)
    assert "could not be confirmed" in msg and "emergency stop" in msg and "\n" not in msg
    assert sim.state()["moving"]  # honest: the arm is indeed still moving
    assert not _stops_since(sim, t0)
    sim.fault("clear")
    robot.stop()  # the dashboard answers again: now confirmed
    _stands_still(sim)


def test_stop_while_the_client_waits_for_a_restarted_program(sim, robot):
    """A stop arriving while the client re-uploads the control program and waits (up to 5 s)
    for it to run is acted on within one wait cycle: the move never goes out."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    sim.fault("program_stop")
    sim.fault("slow_program_start", delay_s=2.0)
    deadline = time.monotonic() + 2.0
    while robot.status().program_running:  # the client has seen the program stop
        assert time.monotonic() < deadline
        time.sleep(0.01)
    n_moves = sim.state()["n_moves"]
    q0 = np.asarray(sim.state()["q"])
    t_sim = sim.state()["t"]  # the simulator's log lines start with its controller time
    th, box = _move_in_thread(robot, FAR, 0.5)
    deadline = time.monotonic() + 5.0
    while not any(
        "script received" in ln and float(ln.split()[0]) > t_sim for ln in sim.request("log")["log"]
    ):
        assert time.monotonic() < deadline, "the client never re-uploaded the program"
        time.sleep(0.01)
    t0 = time.monotonic()
    robot.stop()
    t_stop = time.monotonic() - t0
    th.join(5.0)
    assert isinstance(box.get("error"), MoveStopped), box
    assert t_stop < 1.0 and float(box["t_end"]) - t0 < 1.0, (t_stop, box["t_end"])
    time.sleep(2.5)  # the program is running by now: still no move was sent
    st = sim.state()
    assert st["runtime_state"] == 2 and st["n_moves"] == n_moves and not st["moving"]
    assert np.max(np.abs(np.asarray(st["q"]) - q0)) < 1e-4
    sim.fault("clear")


def test_stop_while_the_client_is_stuck_inside_a_call_goes_through_the_dashboard(sim, robot):
    """The stream freezes just as a move is sent: the commander is then inside moveJ waiting
    for a handshake that never shows.  The stop does not wait for it: the client answers
    within 50 ms that it cannot act, and the dashboard stops the arm."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    sim.fault("freeze_stream")
    th, box = _move_in_thread(robot, FAR, 0.1)
    deadline = time.monotonic() + 2.0
    while not sim.state()["moving"]:  # the controller took the move (its stream is frozen)
        assert time.monotonic() < deadline, "the move was never sent"
        time.sleep(0.005)
    t0 = time.monotonic()
    robot.stop()
    t_stop = time.monotonic() - t0
    assert t_stop < 0.5, t_stop
    assert [how for _, how in _stops_since(sim, t0)] == ["dashboard"]
    th.join(5.0)
    assert isinstance(box.get("error"), HardwareError), box
    sim.fault("clear")
    _stands_still(sim)


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


def test_a_trigger_pulse_goes_out_only_with_the_arm_at_rest(sim, robot):
    """The cameras' line trigger: ``setStandardDigitalOut`` from the client's io thread.
    While a move is under way the pulse is refused in one line and the output never moves;
    at rest it rises and falls, each edge confirmed on the stream at a controller cycle, no
    shorter than asked, and the output is left low."""
    robot.move(Q1, Leg.JOINT, speed=1.0, accel=1.4)
    changes = sim.state()["digital_out_changes"]
    th, box = _move_in_thread(robot, Q2, 0.3)
    _wait_moving(sim)
    with pytest.raises(HardwareError) as err:
        robot.pulse_digital_out(3, 0.02)
    th.join(30.0)
    assert "move is under way" in str(err.value) and "\n" not in str(err.value)
    assert "error" not in box and sim.state()["digital_out_changes"] == changes  # nothing set
    p = robot.pulse_digital_out(3, 0.02)
    assert p.output == 3 and p.width_s >= 0.02 - 1e-9 and p.rest_p2p_rad <= REST_TOL_RAD
    assert p.rise_after_t < p.rise_t and p.fall_after_t < p.fall_t  # each edge bracketed
    k = np.array([p.rise_t, p.rise_after_t, p.fall_t]) / robot.sample_period
    assert np.allclose(k, np.round(k), atol=1e-3)
    st = sim.state()
    assert st["digital_out"] == 0 and st["digital_out_changes"] == changes + 2
    for bad in ((8, 0.02), (3, 0.01)):  # no output 8; 10 ms is under two 8 ms cycles
        with pytest.raises(InputError):
            robot.pulse_digital_out(*bad)
