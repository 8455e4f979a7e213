"""The simulated controller streams like a real one, as the unmodified ur-rtde client sees it.

Behaviour, not speed targets (those live in ``benchmarks/sim_stream.py``): the stream never
pauses while a long straight line is planned, an e-Series version streams at 500 Hz, and a
controller restart drops every link and takes new ones after its down time.  The simulator
runs in its own process and holds the host-wide UR port lock, so these tests never overlap
other simulator tests.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from quickhealth.station.sim.process import start_sim_controller
from quickhealth.station.sim.wire import DASHBOARD_PORT, RTDE_PORT

pytestmark = [pytest.mark.slow, pytest.mark.timeout(200)]

Q_START = np.radians([-20.0, -100.0, 100.0, -90.0, -90.0, 0.0])
LINE = np.array([0.25, 0.3, -0.2])  # m: a 0.44 m straight line (87 path samples)


class Poller:
    """Polls the client's timestamp in a thread; keeps (local time, timestamp) at each change."""

    def __init__(self, r) -> None:
        self.r = r
        self.seen: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        last = None
        while not self._stop.is_set():
            ts = self.r.getTimestamp()
            if ts != last:
                self.seen.append((time.monotonic(), ts))
                last = ts
            time.sleep(0.0005)

    def __enter__(self) -> Poller:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join(5)


def test_stream_keeps_going_while_a_long_move_l_is_planned():
    import rtde_control
    import rtde_receive

    sim = start_sim_controller(control_port=30092, speed_factor=4.0)
    r = c = None
    try:
        r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
        c = rtde_control.RTDEControlInterface(sim.host, 125.0)
        assert c.moveJ(Q_START.tolist(), 1.0, 1.4)
        goal = np.array(r.getActualTCPPose())
        goal[:3] += LINE
        with Poller(r) as poll:
            time.sleep(0.1)
            t_cmd = time.monotonic()
            assert c.moveL(goal.tolist(), 0.25, 1.2, True)  # async: planned in the simulator
            while c.getAsyncOperationProgress() >= 0 and time.monotonic() - t_cmd < 20:
                time.sleep(0.01)
            time.sleep(0.1)
        arrivals = np.array([a for a, _ in poll.seen])
        stamps = np.array([s for _, s in poll.seen])
        assert np.all(np.diff(stamps) > 0)
        assert len(arrivals) > 50 and arrivals[0] < t_cmd < arrivals[-1]
        gaps = np.diff(arrivals)
        # Before the planner thread, this line stopped the stream for ~0.4-1 s.
        assert gaps.max() < 0.25, f"stream paused {gaps.max():.3f} s"
        time.sleep(0.05)
        assert np.allclose(r.getActualTCPPose()[:3], goal[:3], atol=1e-5)
        assert any("analytic" in line for line in sim.request("log")["log"])
    finally:
        for client in (c, r):
            if client is not None:
                client.disconnect()
        sim.stop()


def test_e_series_version_streams_at_500_hz():
    import rtde_receive

    sim = start_sim_controller(control_port=30093, controller_version="5.11.1")
    r = None
    try:
        r = rtde_receive.RTDEReceiveInterface(sim.host)  # the client picks 500 Hz itself
        with socket.create_connection((sim.host, DASHBOARD_PORT), timeout=5) as s:
            f = s.makefile("rwb", buffering=0)
            f.readline()
            f.write(b"PolyscopeVersion\n")
            assert f.readline().startswith(b"URSoftware 5.11.1.")
        (s0,) = sim.state()["streams"]
        with Poller(r) as poll:
            time.sleep(1.0)
        (s1,) = sim.state()["streams"]
        assert s1["hz"] == 500.0
        rate = (s1["packets"] - s0["packets"]) / 1.0
        assert rate > 250, f"{rate:.0f} packets/s"  # 500 Hz, not a CB3's 125
        stamps = np.array([t for _, t in poll.seen])
        assert np.median(np.diff(stamps)) < 0.005  # the client sees 2 ms steps, not 8 ms
    finally:
        if r is not None:
            r.disconnect()
        sim.stop()


def test_cb3_version_streams_at_125_hz_whatever_the_client_asks():
    import rtde_receive

    sim = start_sim_controller(control_port=30094)
    r = None
    try:
        r = rtde_receive.RTDEReceiveInterface(sim.host, 500.0)
        time.sleep(0.3)
        (st,) = sim.state()["streams"]
        assert st["hz"] == 125.0
    finally:
        if r is not None:
            r.disconnect()
        sim.stop()


def test_restart_drops_every_link_refuses_for_down_s_then_reconnects():
    import rtde_control
    import rtde_receive

    sim = start_sim_controller(control_port=30095, speed_factor=4.0)
    r = c = None
    try:
        r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
        dash = socket.create_connection((sim.host, DASHBOARD_PORT), timeout=5)
        dash.recv(100)
        sim.fault("restart", down_s=1.5)
        t0 = time.monotonic()
        st = sim.state()
        assert st["runtime_state"] == 1 and not st["accepting"] and st["n_restarts"] == 1
        assert st["safety_mode"] == 1 and st["robot_mode"] == 7 and not st["moving"]
        assert dash.recv(100) == b""  # the dashboard link is gone
        dash.close()
        while r.isConnected() and time.monotonic() - t0 < 1.0:
            time.sleep(0.01)
        assert not r.isConnected()
        # refused while down: the socket is closed at once
        with socket.create_connection((sim.host, RTDE_PORT), timeout=5) as s:
            s.settimeout(2.0)
            assert s.recv(10) == b""
        r.disconnect()
        r = None
        while not sim.state()["accepting"]:
            assert time.monotonic() - t0 < 5.0
            time.sleep(0.05)
        r = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
        c = rtde_control.RTDEControlInterface(sim.host, 125.0)  # uploads, program runs
        assert c.isProgramRunning()
        q = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])
        assert c.moveJ(q.tolist(), 1.0, 1.4)
        time.sleep(0.05)
        assert np.allclose(r.getActualQ(), q, atol=3e-4)
    finally:
        for client in (c, r):
            if client is not None:
                client.disconnect()
        sim.stop()
