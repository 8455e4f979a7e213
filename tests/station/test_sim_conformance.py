"""Conformance of the simulated UR controller to UR's documents, item by item.

Each test drives the simulator (a separate process) the way a client of a real controller
would: through ur-rtde, through the protocol-level client of ``tests/helpers/qh_rtde_guide.py`` (written from
UR's RTDE guide, independent of the simulator's own wire module), through raw dashboard and
URScript sockets.  Each cites the document section whose behaviour it asserts:

- RTDE: "Real-Time Data Exchange (RTDE) Guide", Universal Robots (sections named as there);
- dashboard: "Dashboard Server CB-Series" (3.x) and "Dashboard Server e-Series" (5.x);
- URScript: "The URScript Programming Language" manual (the function's own entry) and the
  "Client Interfaces" article (ports 30001/30002/30003, primary-interface robot messages).
"""

from __future__ import annotations

import math
import socket
import struct
import time

import numpy as np
import pytest
from qh_rtde_guide import RtdeGuideClient

from quickhealth.identify.robot import gravity_torques, ur5, with_payload
from quickhealth.station.hardware.urtypes import RobotMode, RuntimeState, SafetyMode
from quickhealth.station.sim import wire
from quickhealth.station.sim.cable import OutputWatch
from quickhealth.station.sim.dynamics import TORQUE_CONSTANT
from quickhealth.station.sim.process import SMART_TARGET_COM, SMART_TARGET_KG, start_sim_controller
from quickhealth.station.sim.states import TESTING

pytestmark = [pytest.mark.slow, pytest.mark.timeout(200)]

HOME = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])
Q1 = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])


@pytest.fixture(scope="module")
def programs(tmp_path_factory):
    d = tmp_path_factory.mktemp("programs")
    (d / "wave.urp").write_bytes(b"\x1f\x8b PolyScope program (not read by the simulator)")
    (d / "wave.script").write_text(
        "def wave():\n"
        "  movej([0.2, -1.4, 1.4, -1.57, -1.57, 0.0], a=1.0, v=0.5)\n"
        "  sleep(2.0)\n"
        "  movej([0.0, -1.5707963, 1.5707963, -1.5707963, -1.5707963, 0.0], a=1.0, v=0.5)\n"
        "end\n"
    )
    (d / "noscript.urp").write_bytes(b"x")
    return d


@pytest.fixture(scope="module")
def sim(programs):
    h = start_sim_controller(
        control_port=30094, speed_factor=4.0, delays=TESTING.spec(), programs=str(programs)
    )
    try:
        yield h
    finally:
        h.stop()


@pytest.fixture
def fresh(sim):
    """The simulator healthy, the program stopped, the arm at home, no unlock delay."""
    sim.fault("clear")
    dash(sim, "stop")
    sim.request("set_q", q=HOME.tolist())
    return sim


def dash(sim, *lines: str) -> list[str]:
    with socket.create_connection((sim.host, wire.DASHBOARD_PORT), timeout=5) as s:
        f = s.makefile("rwb", buffering=0)
        assert f.readline() == b"Connected: Universal Robots Dashboard Server\n"
        out = []
        for line in lines:
            f.write(line.encode() + b"\n")
            out.append(f.readline().decode().rstrip("\n"))
        return out


def wait(pred, timeout: float = 5.0, what: str = "condition") -> None:
    t0 = time.monotonic()
    while not pred():
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what}"
        time.sleep(0.01)


def sample(sim, names: list[str]) -> dict:
    """One fresh data package of ``names`` (a new client: nothing buffered)."""
    with RtdeGuideClient(sim.host) as g:
        assert g.request_protocol_version(2)
        g.setup_outputs(names, 125.0)
        assert g.start()
        g.read()
        return g.read()


def send_program(sim, text: str, port: int = 30002) -> None:
    with socket.create_connection((sim.host, port), timeout=5) as s:
        s.sendall(text.encode())


class Primary:
    """A primary-interface client that decodes robot messages (type 20)."""

    def __init__(self, sim) -> None:
        self.s = socket.create_connection((sim.host, 30001), timeout=3)
        self.buf = b""

    def messages(self, until: float = 1.0) -> list[tuple[int, bytes]]:
        out = []
        end = time.monotonic() + until
        self.s.settimeout(0.05)
        while time.monotonic() < end:
            try:
                chunk = self.s.recv(65536)
                if not chunk:
                    break
                self.buf += chunk
            except TimeoutError:
                pass
            while len(self.buf) >= 5:
                n, mtype = struct.unpack(">iB", self.buf[:5])
                if len(self.buf) < n:
                    break
                body, self.buf = self.buf[5:n], self.buf[n:]
                if mtype == 20:
                    _, _, kind = struct.unpack(">QbB", body[:10])
                    out.append((kind, body[10:]))
        return out

    def close(self) -> None:
        self.s.close()


# ------------------------------------------------------------------------------ RTDE


def test_protocol_versions_1_and_2_only(sim):
    """RTDE guide, "RTDE_REQUEST_PROTOCOL_VERSION": accepted = 1 for a supported version."""
    with RtdeGuideClient(sim.host) as c:
        assert not c.request_protocol_version(3)
        assert not c.request_protocol_version(99)
        assert not c.request_protocol_version(0)
        assert c.request_protocol_version(2)
    with RtdeGuideClient(sim.host) as c:
        assert c.request_protocol_version(1)
        assert c.controller_version()[:3] == (3, 15, 7)  # "RTDE_GET_URCONTROL_VERSION"


def test_version_1_framing_no_frequency_no_recipe_id(sim):
    """RTDE guide, "RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS" (protocol version 1: variable names
    only; the reply is the types only) and "RTDE_DATA_PACKAGE" (no recipe id in version 1)."""
    with RtdeGuideClient(sim.host) as c:
        assert c.request_protocol_version(1)
        _, types = c.setup_outputs(["timestamp", "actual_q", "robot_mode"])
        assert types == ["DOUBLE", "VECTOR6D", "INT32"]
        assert c.start()
        a, b = c.read(), c.read()
        assert 0.0 < a["timestamp"] < b["timestamp"] < a["timestamp"] + 0.1
        assert a["robot_mode"] == RobotMode.RUNNING and len(a["actual_q"]) == 6


def test_version_2_framing_frequency_and_recipe_ids(sim):
    """RTDE guide, "RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS" (version 2: double frequency, then
    names; reply uint8 recipe id, types) and "RTDE_DATA_PACKAGE" (uint8 recipe id first)."""
    with RtdeGuideClient(sim.host) as c:
        assert c.request_protocol_version(2)
        rid, types = c.setup_outputs(["timestamp", "safety_status_bits"], 125.0)
        assert rid == 1 and types == ["DOUBLE", "UINT32"]
        rid2, _ = c.setup_outputs(["runtime_state"], 125.0)
        assert rid2 == 2
        assert c.start()
        seen = {c.read().keys().__iter__().__next__() for _ in range(6)}
        assert seen == {"timestamp", "runtime_state"}  # both recipes stream, told apart by id


def test_names_the_guide_does_not_list_are_not_found_and_its_full_ranges_are(sim):
    """RTDE guide, "Field names and associated types": registers 0..47, bit registers
    64..127 one by one, tcp_offset; NOT_FOUND for any other name."""
    with RtdeGuideClient(sim.host) as c:
        assert c.request_protocol_version(2)
        good = [
            "tcp_offset",
            "output_bit_register_64",
            "output_bit_register_127",
            "input_bit_register_64",
            "input_bit_register_127",
            "output_int_register_47",
            "output_double_register_47",
            "input_int_register_0",
            "input_double_register_47",
            "standard_analog_input0",
            "output_bit_registers32_to_63",
        ]
        rid, types = c.setup_outputs(good, 125.0)
        assert rid > 0 and "NOT_FOUND" not in types, types
        for bad in (
            "standard_analog_input_bogus",
            "output_int_register_48",
            "output_bit_register_3",  # bits 0..63 go by the 32-bit words
            "input_int_register_07",
            "actual_qdd",
            "timestamp2",
        ):
            rid, types = c.setup_outputs(["timestamp", bad], 125.0)
            assert rid == 0 and types == ["DOUBLE", "NOT_FOUND"], bad
        rid, types = c.setup_inputs(["input_int_register_30", "actual_q"])
        assert rid == 0 and types == ["INT32", "NOT_FOUND"]  # an output is not an input


def test_input_registers_read_back_and_in_use_for_another_client(sim):
    """RTDE guide, "RTDE_CONTROL_PACKAGE_SETUP_INPUTS" (IN_USE: another client writes the
    field) and "Field names and associated types" (input registers readable as outputs)."""
    names = ["input_int_register_30", "input_double_register_40", "input_bit_register_70"]
    with RtdeGuideClient(sim.host) as w, RtdeGuideClient(sim.host) as r:
        assert w.request_protocol_version(2) and r.request_protocol_version(2)
        rid, types = w.setup_inputs(names)
        assert rid >= 1 and types == ["INT32", "DOUBLE", "BOOL"]
        rid2, types2 = r.setup_inputs(["input_int_register_31", "input_int_register_30"])
        assert rid2 == 0 and types2 == ["INT32", "IN_USE"]
        r.setup_outputs(["timestamp", *names], 125.0)
        assert w.start() and r.start()
        w.write(rid, {names[0]: 1234, names[1]: -2.5, names[2]: True})
        wait(lambda: r.read()["input_int_register_30"] == 1234, what="the echo")
        out = r.read()
        assert out["input_double_register_40"] == -2.5 and out["input_bit_register_70"] is True
    with RtdeGuideClient(sim.host) as again:  # the writer left: the fields are free
        assert again.request_protocol_version(2)
        assert again.setup_inputs(["input_int_register_30"])[0] >= 1


DIGITAL_INPUTS = [
    "standard_digital_output_mask",
    "standard_digital_output",
    "configurable_digital_output_mask",
    "configurable_digital_output",
    "tool_digital_output_mask",
    "tool_digital_output",
]


def test_digital_outputs_take_the_masked_levels_at_a_controller_cycle(sim):
    """RTDE guide, "Field names and associated types": the inputs
    standard_digital_output_mask / standard_digital_output (UINT8, outputs 0..7),
    configurable_digital_output_mask / _output (8..15), tool_digital_output_mask / _output
    (the tool's 0..1): only the outputs whose mask bit is set take the level;
    actual_digital_output_bits (UINT64) reads them back, bits 0-7 standard, 8-15
    configurable, 16-17 tool.  The controller reads its inputs once a cycle: a change
    appears at a cycle's timestamp (the terminal's watchers get the same time)."""
    changes: list[tuple[float, int]] = []
    watch = OutputWatch(sim.host, sim.control_port, lambda t, bits, at: changes.append((t, bits)))
    try:
        with RtdeGuideClient(sim.host) as w, RtdeGuideClient(sim.host) as r:
            assert w.request_protocol_version(2) and r.request_protocol_version(2)
            rid, types = w.setup_inputs(DIGITAL_INPUTS)
            assert rid >= 1 and types == ["UINT8"] * 6
            r.setup_outputs(["timestamp", "actual_digital_output_bits"], 125.0)
            assert w.start() and r.start()

            def put(bits: int, **v: int) -> dict:
                w.write(rid, {n: v.get(n, 0) for n in DIGITAL_INPUTS})
                t0 = time.monotonic()
                while True:
                    pkt = r.read()
                    if pkt["actual_digital_output_bits"] == bits:
                        return pkt
                    assert time.monotonic() - t0 < 2.0, (bits, pkt)

            sdo, sdo_m = "standard_digital_output", "standard_digital_output_mask"
            first = put(0b100, **{sdo_m: 0b100, sdo: 0b111})  # levels outside the mask: ignored
            put(0b1101, **{sdo_m: 0b1001, sdo: 0b1001})  # output 2 not in the mask: stays high
            put(0b1001, **{sdo_m: 0b100, sdo: 0})
            put(0b1001, **{sdo_m: 0, sdo: 0xFF})  # no mask: nothing changes
            put(
                0b10_0000_0001_0000_1001,
                configurable_digital_output_mask=0b1,
                configurable_digital_output=0b1,
                tool_digital_output_mask=0b10,
                tool_digital_output=0b10,
            )
            put(
                0,
                **{sdo_m: 0xFF, sdo: 0},
                configurable_digital_output_mask=0xFF,
                tool_digital_output_mask=0b11,
            )
    finally:
        watch.close()
    assert changes[0] == (first["timestamp"], 0b100)  # the watchers see the same cycle
    k = np.array([t for t, _ in changes]) / 0.008  # CB3: 8 ms cycles
    assert np.allclose(k, np.round(k), atol=1e-6)
    assert [b for _, b in changes] == [0b100, 0b1101, 0b1001, 0x20109, 0]


@pytest.mark.parametrize("version, step", [("3.15.7", 0.008), ("5.11.1", 0.002)])
def test_timestamps_step_with_the_controller_cycle(version, step, sim):
    """RTDE guide, "Key features" / timestamp: time elapsed since the controller started,
    sampled once per real-time cycle (125 Hz CB3, 500 Hz e-Series)."""
    h = sim
    if version != "3.15.7":
        h = start_sim_controller(control_port=30095, controller_version=version)
    try:
        with RtdeGuideClient(h.host) as c:
            assert c.request_protocol_version(2)
            c.setup_outputs(["timestamp"], 500.0)
            assert c.start()
            ts = np.array([c.read()["timestamp"] for _ in range(50)])
        k = ts / step
        assert np.allclose(k, np.round(k), atol=1e-6)  # whole controller steps
        assert np.min(np.diff(np.round(k))) >= 1
    finally:
        if h is not sim:
            h.stop()


# ------------------------------------------------------------------ computed values


def test_velocities_currents_and_torques_follow_the_motion(fresh):
    """RTDE guide, "Field names": actual_qd, target_qd, actual_TCP_speed, actual_current,
    target_current; URScript manual, get_joint_torques(): torque minus the robot's own
    (gravity, friction) model."""
    sim = fresh
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
    c = rtde_control.RTDEControlInterface(sim.host, 125.0)
    try:
        # At rest: the motors hold the arm and its unannounced payload against gravity.
        time.sleep(0.1)
        q = np.asarray(r.getActualQ())
        tau = -gravity_torques(with_payload(ur5(), SMART_TARGET_KG, SMART_TARGET_COM), q)[0]
        cur = np.asarray(r.getActualCurrent())
        assert np.allclose(cur * TORQUE_CONSTANT, tau, atol=0.6)  # noise 0.01 A
        assert abs(tau[1]) > 5.0  # the shoulder carries several N·m
        # getJointTorques: the payload the controller was not told about.  ur-rtde does not
        # wait for this real-time command: a call reads what the previous one left, so ask
        # twice (the script keeps computing it each cycle while it stands in the register).
        c.getJointTorques()
        time.sleep(0.03)
        tq = np.asarray(c.getJointTorques())
        tau_payload = -gravity_torques(with_payload(ur5(), SMART_TARGET_KG, SMART_TARGET_COM), q)[0]
        tau_payload -= -gravity_torques(ur5(), q)[0]
        assert np.allclose(tq, tau_payload, atol=0.3) and abs(tq[1]) > 1.0
        # ... and nothing once it is told (setPayload: mass, centre of gravity)
        assert c.setPayload(SMART_TARGET_KG, list(SMART_TARGET_COM))
        c.getJointTorques()
        time.sleep(0.03)
        assert np.max(np.abs(c.getJointTorques())) < 0.3
        # Moving: the joint velocities are the motion's, the TCP speed its Jacobian image.
        far = HOME + np.array([1.0, 0.2, -0.2, 0.3, 0.3, 0.5])
        assert c.moveJ(far.tolist(), 0.3, 0.5, True)  # ~1 s at speed factor 4
        time.sleep(0.4)
        qd, qd_t = np.asarray(r.getActualQd()), np.asarray(r.getTargetQd())
        assert np.max(np.abs(qd)) > 0.1 and np.allclose(qd, qd_t, atol=2e-3)
        d = far - HOME
        assert np.allclose(qd_t / np.max(np.abs(qd_t)), d / np.max(np.abs(d)), atol=1e-6)
        p0, t0 = np.asarray(r.getActualTCPPose()), r.getTimestamp()
        v = np.asarray(r.getActualTCPSpeed())
        time.sleep(0.016)
        p1, t1 = np.asarray(r.getActualTCPPose()), r.getTimestamp()
        fd = (p1[:3] - p0[:3]) / (t1 - t0)
        assert np.linalg.norm(v[:3]) > 0.02
        assert np.linalg.norm(fd - v[:3]) < 0.2 * np.linalg.norm(v[:3])
        assert np.any(np.abs(r.getTargetCurrent()) > 0.1)
        wait(lambda: c.getAsyncOperationProgress() < 0, what="the move")
    finally:
        c.disconnect()
        r.disconnect()


def test_kinematics_calls_answer_from_the_controller_model(fresh):
    """URScript manual: get_forward_kin(), get_inverse_kin(), is_within_safety_limits(),
    get_tcp_offset(); ur-rtde's getActualToolFlangePose (the flange, no TCP offset)."""
    sim = fresh
    import rtde_control
    import rtde_receive

    from quickhealth.station.sim.arm import T_from_pose, pose_from_T

    r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
    c = rtde_control.RTDEControlInterface(sim.host, 125.0)
    try:
        assert c.moveJ(Q1.tolist(), 1.0, 1.4)
        time.sleep(0.3)
        pose = np.asarray(r.getActualTCPPose())
        assert np.allclose(c.getForwardKinematics(), pose, atol=1e-5)
        c.getActualToolFlangePose()  # real-time command: the second call reads its result
        time.sleep(0.03)
        assert np.allclose(c.getActualToolFlangePose(), pose, atol=1e-5)  # TCP offset 0
        assert c.isPoseWithinSafetyLimits(pose.tolist())
        assert c.isJointsWithinSafetyLimits(Q1.tolist())
        assert not c.isJointsWithinSafetyLimits([0.0, 0.0, 7.0, 0.0, 0.0, 0.0])
        assert not c.isPoseWithinSafetyLimits([1.5, 0.0, 0.3, 0.0, 3.14, 0.0])
        q = np.asarray(c.getInverseKinematics(pose.tolist(), Q1.tolist()))
        assert np.allclose(q, Q1, atol=1e-4)
        tcp = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]  # FK of given joints with a given TCP offset
        want = pose_from_T(T_from_pose(pose) @ T_from_pose(tcp))
        assert np.allclose(c.getForwardKinematics(q.tolist(), tcp), want, atol=1e-6)
        assert c.setTcp([0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
        time.sleep(0.05)
        assert np.allclose(c.getTCPOffset(), [0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
        c.getActualToolFlangePose()
        time.sleep(0.03)
        flange = np.asarray(c.getActualToolFlangePose())
        tcp = np.asarray(r.getActualTCPPose())
        assert abs(np.linalg.norm(tcp[:3] - flange[:3]) - 0.1) < 1e-5
        assert c.setTcp([0.0] * 6)
    finally:
        c.disconnect()
        r.disconnect()


def test_joint_temperatures_rise_with_work(sim):
    """RTDE guide, "Field names": joint_temperatures (°C)."""
    # A controller of its own, whose joints start at their idle temperature.
    sim = start_sim_controller(control_port=30098, speed_factor=4.0, delays=TESTING.spec())
    try:
        _temperatures(sim)
    finally:
        sim.stop()


def _temperatures(sim) -> None:
    names = ["timestamp", "joint_temperatures"]
    t0 = np.asarray(sample(sim, names)["joint_temperatures"])
    time.sleep(0.5)
    t1 = np.asarray(sample(sim, names)["joint_temperatures"])
    send_program(
        sim,
        "def work():\n  i = 0\n  while i < 3:\n"
        "    movej([1.5, -1.5707963, 1.5707963, -1.5707963, -1.5707963, 0.0], a=8.0, v=3.0)\n"
        "    movej([-1.5, -1.5707963, 1.5707963, -1.5707963, -1.5707963, 0.0], a=8.0, v=3.0)\n"
        "    i = i + 1\n  end\nend\n",
    )
    time.sleep(0.2)
    wait(lambda: sim.state()["runtime_state"] == RuntimeState.STOPPED, 10, "the program")
    assert sim.state()["program_error"] == ""
    t2 = np.asarray(sample(sim, names)["joint_temperatures"])
    assert np.all(t0 > 25.0) and np.all(t0 < 40.0)
    rest, work = t1[0] - t0[0], t2[0] - t1[0]  # the base joint: no gravity load at rest
    assert work > 0 and work > 20 * max(rest, 0.0), (rest, work)


# ------------------------------------------------------------------------------ faults


def test_unreachable_move_l_is_a_protective_stop_not_a_wound_arm(fresh):
    """URScript manual, movel(): the target must be reachable; the controller stops the arm
    (protective stop) rather than wind the joints.  ur-rtde's moveL then returns False."""
    sim = fresh
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
    c = rtde_control.RTDEControlInterface(sim.host, 125.0)
    try:
        t0 = time.monotonic()
        assert not c.moveL([1.5, 0.0, 0.3, 0.0, 3.14, 0.0], 0.25, 1.0)
        assert time.monotonic() - t0 < 2.0
        time.sleep(max(0.05, TESTING.unlock_after_s))
        assert r.getSafetyMode() == SafetyMode.PROTECTIVE_STOP
        assert np.max(np.abs(np.asarray(r.getActualQ()) - HOME)) < 1e-3  # nothing wound
        # a protective stop needs "unlock protective stop" (dashboard), then a new program
        assert dash(sim, "unlock protective stop") == ["Protective stop releasing"]
        c.reuploadScript()
        wait(c.isProgramRunning, what="the program")
        # joint position limit (±360°) and a line too fast for a joint: refused the same way
        assert not c.moveJ([0.0, -1.57, 7.0, -1.57, -1.57, 0.0], 1.0, 1.4)
        assert "joint position limit" in sim.state()["messages"][-1]["text"]
        time.sleep(TESTING.unlock_after_s)
        assert dash(sim, "unlock protective stop") == ["Protective stop releasing"]
        c.reuploadScript()
        wait(c.isProgramRunning, what="the program")
        p = np.asarray(r.getActualTCPPose())
        p[0] += 0.15
        p[2] -= 0.25
        assert not c.moveL(p.tolist(), 1.0, 4.0)
        assert "joint speed limit" in sim.state()["messages"][-1]["text"]
    finally:
        c.disconnect()
        r.disconnect()


def test_acceleration_limit_and_unlock_delay(sim):
    """URScript manual, movej(a=…): joint acceleration limited; Dashboard Server ("unlock
    protective stop"): refused until 5 s after the stop on a real controller."""
    h = start_sim_controller(control_port=30096, delays="unlock_after=0.6", speed_factor=4.0)
    try:
        send_program(
            h, "def fast():\n  movej([0.3, -1.5, 1.5, -1.5, -1.5, 0.0], a=80.0, v=1.0)\nend\n"
        )
        wait(lambda: h.state()["safety_mode"] == SafetyMode.PROTECTIVE_STOP, what="the stop")
        assert "joint acceleration limit" in h.state()["messages"][-1]["text"]
        assert h.state()["runtime_state"] == RuntimeState.PAUSED  # the program pauses
        assert dash(h, "unlock protective stop")[0].startswith(
            "Cannot unlock protective stop until 5s after occurrence"
        )
        time.sleep(0.7)
        assert dash(h, "unlock protective stop") == ["Protective stop releasing"]
        assert h.state()["safety_mode"] == SafetyMode.NORMAL
    finally:
        h.stop()


# --------------------------------------------------------------- the state machine


def test_power_states_step_with_delays_and_no_motion_unless_running(fresh):
    """Dashboard Server: "power off", "power on" (POWER_OFF → BOOTING → POWER_ON → IDLE),
    "brake release" (→ RUNNING), "robotmode"; a program cannot move a robot that is off."""
    sim = fresh
    assert dash(sim, "power off", "robotmode") == ["Powering off", "Robotmode: POWER_OFF"]
    send_program(sim, "def m():\n  movej([0.3, -1.5, 1.5, -1.5, -1.5, 0.0])\nend\n")
    time.sleep(0.2)
    st = sim.state()
    assert st["runtime_state"] == RuntimeState.STOPPED and "not running" in st["program_error"]
    assert np.allclose(st["q"], HOME, atol=1e-4)
    assert dash(sim, "brake release", "robotmode") == ["Brake releasing", "Robotmode: POWER_OFF"]
    with RtdeGuideClient(sim.host) as g:
        assert g.request_protocol_version(2)
        g.setup_outputs(["timestamp", "robot_mode"], 125.0)
        assert g.start()
        assert dash(sim, "power on") == ["Powering on"]
        modes = []
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            m = g.read()["robot_mode"]
            if not modes or modes[-1] != m:
                modes.append(m)
        while modes and modes[0] == RobotMode.POWER_OFF:  # packets sent before "power on"
            modes.pop(0)
        assert modes == [RobotMode.BOOTING, RobotMode.POWER_ON, RobotMode.IDLE]
        assert dash(sim, "brake release") == ["Brake releasing"]
        assert g.read()["robot_mode"] == RobotMode.IDLE  # the brakes take their time
        wait(lambda: g.read()["robot_mode"] == RobotMode.RUNNING, what="brakes released")


def test_programs_load_play_pause_stop_as_on_polyscope(fresh):
    """Dashboard Server: "load", "get loaded program", "play", "pause", "stop",
    "programState", "running", "isProgramSaved"; failures in UR's words."""
    sim = fresh
    assert dash(sim, "play") == ["Failed to execute: play"]  # nothing loaded
    assert dash(sim, "load missing.urp") == ["File not found: missing.urp"]
    assert dash(sim, "load noscript.urp") == ["Error while loading program: noscript.urp"]
    out = dash(sim, "load wave.urp", "get loaded program", "isProgramSaved")
    assert out[0].startswith("Loading program: ") and out[0].endswith("wave.urp")
    assert out[1].startswith("Loaded program: ") and out[2] == "true wave.urp"
    assert dash(sim, "play", "running") == ["Starting program", "Program running: true"]
    time.sleep(0.15)
    assert dash(sim, "pause") == ["Pausing program"]
    st = sim.state()
    assert st["runtime_state"] == RuntimeState.PAUSED and not st["moving"]
    assert dash(sim, "programState", "pause")[0].startswith("PAUSED")
    assert dash(sim, "play") == ["Starting program"]  # resumes
    assert sim.state()["runtime_state"] == RuntimeState.PLAYING
    assert dash(sim, "stop", "programState") == ["Stopped", "STOPPED " + out[0].split(": ")[1]]
    assert dash(sim, "pause") == ["Failed to execute: pause"]


@pytest.mark.parametrize("version", ["3.15.7", "5.11.1"])
def test_dashboard_command_set_of_the_version(version, sim):
    """Dashboard Server CB-Series 3.x and e-Series 5.x: each version's own command list."""
    h = (
        sim
        if version == "3.15.7"
        else start_sim_controller(
            control_port=30097, controller_version=version, delays=TESTING.spec()
        )
    )
    try:
        cb3 = version.startswith("3")
        got = dict(
            zip(
                (
                    "remote",
                    "opmode",
                    "role",
                    "log",
                    "nolog",
                    "popup",
                    "close",
                    "safety",
                    "model",
                    "bogus",
                ),
                dash(
                    h,
                    "is in remote control",
                    "get operational mode",
                    "setUserRole operator",
                    "addToLog hello",
                    "addToLog",
                    "close safety popup",
                    "close popup",
                    "safetystatus",
                    "get robot model",
                    "make coffee",
                ),
                strict=True,
            )
        )
        un = "could not understand: "
        assert got["remote"] == (un + "'is in remote control'" if cb3 else "true")
        assert got["opmode"] == (un + "'get operational mode'" if cb3 else "NONE")
        assert got["role"] == (
            "Setting user role: operator" if cb3 else un + "'setUserRole operator'"
        )
        assert got["log"] == "Added log message" and got["nolog"] == "No log message to add"
        assert got["popup"] == "closing safety popup" and got["close"] == "closing popup"
        assert got["safety"] == "Safetystatus: NORMAL" and got["model"] == "UR5"
        assert got["bogus"] == un + "'make coffee'"
        # restart safety powers the arm off
        assert dash(h, "restart safety", "robotmode") == [
            "Restarting safety",
            "Robotmode: POWER_OFF",
        ]
    finally:
        if h is sim:
            sim.fault("clear")
        else:
            h.stop()


# ------------------------------------------------------------------------- URScript


def test_urscript_programs_run_on_the_primary_secondary_and_realtime_ports(fresh):
    """Client Interfaces: programs on 30001, 30002 and 30003; URScript manual: def/end,
    local functions, variables, if/while, movej/movel with pose literals, textmsg,
    set_standard_digital_out, get_actual_joint_positions, get_inverse_kin."""
    sim = fresh
    prim = Primary(sim)
    try:
        first = prim.messages(0.3)
        assert first and first[0][0] == 3  # VERSION on connection
        program = (
            "def cell():\n"
            "  def up(p, dz):\n"
            "    return p[p[0], p[1], p[2] + dz, p[3], p[4], p[5]]\n"
            "  end\n"
            "  movej([0.1745329, -1.3962634, 1.3962634, -1.5707963, -1.5707963, 0.1745329], a=1.4, v=1.0)\n"
            "  q = get_actual_joint_positions()\n"
            "  target = p[0.40, -0.10, 0.35, 0.0, 3.1415926, 0.0]\n"
            "  movel(target, a=1.2, v=0.25)\n"
            "  k = 0\n"
            "  while k < 2:\n"
            "    k = k + 1\n"
            "  end\n"
            "  if k == 2 and norm(q[0] - 0.1745329) < 0.001:\n"
            "    set_standard_digital_out(3, True)\n"
            "  else:\n"
            "    set_standard_digital_out(4, True)\n"
            "  end\n"
            "  qi = get_inverse_kin(target, qnear=get_actual_joint_positions())\n"
            '  textmsg("done ", k)\n'
            "end\n"
        )
        for port in (30002, 30001, 30003):
            sim.fault("clear")
            sim.request("set_q", q=HOME.tolist())
            send_program(sim, program, port)
            time.sleep(0.2)
            wait(lambda: sim.state()["runtime_state"] == RuntimeState.STOPPED, 10, "the program")
            st = sim.state()
            assert st["program_error"] == "" and st["digital_out"] == 1 << 3, (port, st)
        msgs = prim.messages(0.3)
        texts = [b.decode() for k, b in msgs if k == 0]
        assert texts.count("done 2") == 3
    finally:
        prim.close()
    from quickhealth.station.sim.arm import T_from_pose

    pose = np.asarray(sim.request("state")["q"])
    del pose  # the TCP is checked through the stream:
    with RtdeGuideClient(sim.host) as g:
        assert g.request_protocol_version(2)
        g.setup_outputs(["actual_TCP_pose"], 125.0)
        assert g.start()
        tcp = np.asarray(g.read()["actual_TCP_pose"])
    assert np.allclose(tcp[:3], [0.40, -0.10, 0.35], atol=1e-5)
    assert np.allclose(
        T_from_pose(tcp)[:3, :3], T_from_pose([0, 0, 0, 0.0, 3.1415926, 0.0])[:3, :3], atol=1e-5
    )


@pytest.mark.parametrize(
    "program, kind, words, line",
    [
        (
            "def a():\n  textmsg(1)\n  make_coffee(2)\nend\n",
            "Compile",
            "name 'make_coffee' is not defined",
            3,
        ),
        ("def a():\n  x = [1, 2]\n  textmsg(x[5])\nend\n", "Runtime", "index 5 out of range", 3),
        ("def a():\n  thread t():\n  end\nend\n", "Compile", "threads are not", 2),
        ("def a():\n  movel(p[2.5, 0, 0.3, 0, 3.14, 0])\nend\n", "Runtime", "", 0),
    ],
)
def test_anything_else_is_an_error_reported_as_the_controller_does(
    fresh, program, kind, words, line
):
    """Client Interfaces, primary interface: a ROBOT_MESSAGE of type RUNTIME_EXCEPTION
    (line, column, text); the program stops (an unreachable movel is a protective stop)."""
    sim = fresh
    prim = Primary(sim)
    try:
        prim.messages(0.05)  # the VERSION message
        send_program(sim, program)
        if not words:  # the unreachable pose: protective stop, the program paused
            wait(lambda: sim.state()["safety_mode"] == SafetyMode.PROTECTIVE_STOP, 3, "the stop")
            assert sim.state()["runtime_state"] == RuntimeState.PAUSED
            return
        exc: list[bytes] = []
        t0 = time.monotonic()
        while not exc and time.monotonic() - t0 < 3:
            exc = [b for k, b in prim.messages(0.05) if k == 10]
        assert exc, "no runtime exception message"
        ln, col = struct.unpack(">ii", exc[-1][:8])
        text = exc[-1][8:].decode()
        assert text.startswith(f"{kind} error: ") and words in text and ln == line and col > 0
        assert sim.state()["runtime_state"] == RuntimeState.STOPPED
    finally:
        prim.close()


# ------------------------------------------------------------------ factory calibration


def test_reported_tcp_is_the_controllers_calibration_not_nominal_nor_the_truth(fresh):
    """The controller computes actual_TCP_pose with its own factory calibration (RTDE guide,
    "Field names": actual_TCP_pose), which differs from nominal DH and from the real arm."""
    sim = fresh
    from quickhealth.identify.transforms import inv_T
    from quickhealth.station.sim.arm import pose_from_T
    from quickhealth.station.sim.world import build_world

    sim.request("set_q", q=Q1.tolist())
    with RtdeGuideClient(sim.host) as g:
        assert g.request_protocol_version(2)
        g.setup_outputs(["actual_q", "actual_TCP_pose"], 125.0)
        assert g.start()
        s = g.read()
    q = np.asarray(s["actual_q"])
    reported = np.asarray(s["actual_TCP_pose"])[:3]
    nominal = np.asarray(pose_from_T(ur5().fk(q)))[:3]
    w = build_world("reference", twin_seed=1)
    true_flange = (
        inv_T(w.twin.truth.T_instr_base)
        @ w.T_instr_target0(q)
        @ inv_T(w.twin.truth.T_flange_target)
    )[:3, 3]
    d_nom = np.linalg.norm(reported - nominal)
    d_true = np.linalg.norm(reported - true_flange)
    assert 1e-4 < d_nom < 5e-3, d_nom  # up to millimetres from nominal
    assert d_true > 1e-5 and abs(d_true - np.linalg.norm(nominal - true_flange)) > 1e-6
    assert math.isfinite(d_true)
