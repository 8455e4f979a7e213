"""The UR controller simulator as the unmodified ur-rtde client sees it (separate process).

The simulator binds the fixed UR ports; ``start_sim_controller`` holds a host-wide lock for
them, so simulator tests never run at once whatever the test runner, each under a timeout.
"""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from quickhealth.station.hardware.urtypes import SafetyMode
from quickhealth.station.sim import wire
from quickhealth.station.sim.process import start_sim_controller
from quickhealth.station.sim.states import TESTING

# The timeout includes waiting for the UR ports (one simulator per host).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(200)]


@pytest.fixture(scope="module")
def sim():
    # start_sim_controller takes the host-wide port lock: simulator tests never overlap
    h = start_sim_controller(control_port=30091, speed_factor=4.0, delays=TESTING.spec())
    try:
        yield h
    finally:
        h.stop()


def _listening(port: int) -> list[str]:
    out = []
    for line in open("/proc/net/tcp").read().splitlines()[1:]:
        f = line.split()
        local, state = f[1], f[3]
        if state == "0A" and int(local.split(":")[1], 16) == port:
            out.append(local.split(":")[0])
    return out


def test_every_server_listens_on_loopback_only(sim):
    mine = "".join(f"{int(b):02X}" for b in reversed(sim.host.split(".")))  # /proc/net/tcp order
    for port in (wire.RTDE_PORT, wire.DASHBOARD_PORT, wire.SCRIPT_PORT, 30091):
        where = _listening(port)
        assert mine in where, port
        assert all(a.endswith("7F") for a in where), (port, where)  # 127.x.y.z, nothing else


def test_dashboard_speaks_the_protocol(sim):
    with socket.create_connection((sim.host, wire.DASHBOARD_PORT), timeout=5) as s:
        f = s.makefile("rwb", buffering=0)
        assert f.readline() == b"Connected: Universal Robots Dashboard Server\n"
        for cmd, want in (
            (b"PolyscopeVersion", rb"URSoftware 3.15.7.106331"),
            (b"robotmode", b"Robotmode: RUNNING"),
            (b"safetystatus", b"Safetystatus: NORMAL"),
            (b"popup evil'); os.system('x", b"showing popup"),  # text shown, never run
            (b"os.system('x')", b"could not understand: 'os.system('x')'"),
        ):
            f.write(cmd + b"\n")
            assert f.readline().startswith(want)


def test_control_channel_refuses_unknown_requests(sim):
    with pytest.raises(ValueError, match="unknown fault kind"):
        sim.fault("meltdown")
    with pytest.raises(ValueError, match="unknown control command"):
        sim.request("exec", code="print(1)")
    with pytest.raises(ValueError, match="6 finite"):
        sim.request("set_q", q=[0, 0, "nan"])


def test_real_client_moves_the_simulated_arm(sim):
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
    c = rtde_control.RTDEControlInterface(sim.host, 125.0)
    try:
        assert r.getRobotMode() == 7 and r.getSafetyMode() == 1 and c.isProgramRunning()
        q = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])
        assert c.moveJ(q.tolist(), 1.0, 1.4)
        time.sleep(0.05)
        assert np.allclose(r.getTargetQ(), q, atol=1e-9)
        assert np.allclose(r.getActualQ(), q, atol=3e-4)  # ringing after the stop
        p = np.array(r.getActualTCPPose())
        p[2] += 0.05
        assert c.moveL(p.tolist(), 0.25, 1.0)
        time.sleep(0.3)
        assert np.allclose(r.getActualTCPPose()[:3], p[:3], atol=1e-5)
        # asynchronous move: progress while running, -1 when done
        assert c.moveJ(q.tolist(), 1.0, 1.4, True)
        time.sleep(0.03)
        assert c.getAsyncOperationProgress() >= 0
        t0 = time.monotonic()
        while c.getAsyncOperationProgress() >= 0 and time.monotonic() - t0 < 5:
            time.sleep(0.01)
        assert c.getAsyncOperationProgress() < 0
        # protective stop: the client's move returns False; unlock + reupload recovers
        sim.fault("protective_stop", after_s=0.05)
        assert not c.moveJ(np.zeros(6).tolist(), 0.3, 0.5)
        time.sleep(0.05)  # the receive connection may lag the control one by a packet
        assert r.isProtectiveStopped() and r.getSafetyMode() == SafetyMode.PROTECTIVE_STOP
        with socket.create_connection((sim.host, wire.DASHBOARD_PORT), timeout=5) as s:
            f = s.makefile("rwb", buffering=0)
            f.readline()
            f.write(b"unlock protective stop\n")
            assert f.readline().startswith(b"Protective stop releasing")
        c.reuploadScript()
        t0 = time.monotonic()
        while not c.isProgramRunning() and time.monotonic() - t0 < 5:
            time.sleep(0.01)
        assert c.moveJ(q.tolist(), 1.0, 1.4)
    finally:
        c.disconnect()
        r.disconnect()


def test_truth_is_the_digital_twin_not_the_nominal_arm(sim):
    from quickhealth.identify.twin import TwinTruth

    truth = TwinTruth.from_dict(sim.twin_truth())
    q, T0 = sim.truth()
    from quickhealth.station.sim.world import build_world

    w = build_world("reference", twin_seed=1)
    assert np.allclose(truth.coeffs, w.twin.truth.coeffs)
    nominal = w.twin.truth.T_instr_base @ w.twin.robot.fk(q) @ w.twin.truth.T_flange_target
    dev = np.linalg.norm(T0[:3, 3] - nominal[:3, 3])
    assert 1e-5 < dev < 5e-3  # the twin's errors: tens of µm to a few mm
