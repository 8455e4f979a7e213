"""The programs quickhealth writes run on the simulated controller (URScript on 30002).

``plan --cell reference`` writes ``loop.script``, the fixed loop of the paper's step 6: it
moves through the plan's poses and, at each, announces the pose in an output integer
register and waits for the station's acknowledgement in the input register of the same
number.  Here the test is the station (``qh_rtde_guide.run_loop``: RTDE as in UR's guide):
it acknowledges each pose and checks, from the stream, that the arm is at the planned pose.
``compensate`` rewrites the loop's joint targets; its program runs the same way and reaches
its own targets.  The loop of the full reference plan (74 poses) is
``benchmarks/sim_loop.py``; here a 14-pose plan of the same cell keeps the test short.
"""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest
from qh_rtde_guide import run_loop

from quickhealth.identify.robot import ur5
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.identify.urscript import joint_targets
from quickhealth.station import formats
from quickhealth.station.cli import main
from quickhealth.station.hardware.urtypes import RuntimeState
from quickhealth.station.planning import load_plan
from quickhealth.station.sim.arm import T_from_pose, pose_from_T
from quickhealth.station.sim.kinematics import factory_calibration
from quickhealth.station.sim.process import start_sim_controller
from quickhealth.station.sim.states import TESTING
from quickhealth.station.sim.world import build_world

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

SPEED = 20.0  # the arm and the program's sleeps run this many times faster than life


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    d = tmp_path_factory.mktemp("loop") / "plan"
    assert main(["plan", "--cell", "reference", "--n", "30", "--seed", "0", "--out", str(d)]) == 0
    return d


@pytest.fixture(scope="module")
def sim():
    # An e-Series controller: its 2 ms cycle makes each pose's handshake quicker.
    h = start_sim_controller(
        control_port=30099, speed_factor=SPEED, delays=TESTING.spec(), controller_version="5.11.1"
    )
    try:
        yield h
    finally:
        h.stop()


def test_plan_loop_script_visits_every_planned_pose(sim, plan):
    p = load_plan(plan / "plan.json")
    text = (plan / "loop.script").read_text()
    seen, qs, tcps = run_loop(sim, text, p.motion.handshake_register, p.home)
    assert sim.state()["program_error"] == ""
    assert seen == [pose.index for pose in p.poses]
    q_plan = np.stack([pose.q for pose in p.poses])
    assert np.max(np.abs(qs - q_plan)) < 1e-4  # at rest after the settle time
    # The planned pose as this controller computes it: its factory calibration (the
    # simulator's default, seeded by the twin seed 1) and the program's TCP, set_tcp(...).
    model = factory_calibration(build_world("reference", twin_seed=1).twin.robot, 1)
    T_tcp = T_from_pose(pose_from_T(p.T_flange_target))
    want = (model.fk(q_plan) @ T_tcp)[:, :3, 3]
    err = np.linalg.norm(tcps[:, :3] - want, axis=1)
    assert np.max(err) < 1e-4, np.max(err)  # 0.1 mm


def test_a_compensated_program_runs_and_reaches_its_targets(sim, plan, tmp_path):
    # A model fitted to measurements over the cell's joint ranges, the loop's poses among them.
    robot = ur5()
    p = load_plan(plan / "plan.json")
    q = np.vstack([np.stack([pose.q for pose in p.poses]), random_joints(robot, 120, seed=6)])
    meas = make_twin(robot, seed=5, geometric_pos=3e-5, geometric_rot=5e-5).measure(q)
    formats.write_measurements(tmp_path / "meas.csv", meas)
    fit = ["identify", "fit", str(tmp_path / "meas.csv"), "--robot", "ur5", "--out",
           str(tmp_path / "fit"), "--max-order", "1", "--quiet"]  # fmt: skip
    assert main(fit) == 0
    out = tmp_path / "comp.script"
    src = plan / "loop.script"
    code = main(["compensate", str(tmp_path / "fit" / "model.json"), str(src), "--out", str(out)])
    assert code in (0, 1) and out.is_file()
    text = out.read_text()
    targets = joint_targets(text, 6)
    assert not np.allclose(targets.q, joint_targets(src.read_text(), 6).q)  # it did rewrite
    seen, qs, _ = run_loop(sim, text, p.motion.handshake_register, p.home)
    assert sim.state()["program_error"] == ""
    assert seen == [pose.index for pose in p.poses]
    # the arm stands at the compensated joint targets (first pose: movej, then one per pose)
    assert np.max(np.abs(qs - targets.q[: len(seen)])) < 1e-4


def test_loop_script_refuses_to_start_away_from_home(sim, plan):
    """The program's own check (textmsg, halt): it ends without moving."""
    text = (plan / "loop.script").read_text()
    q = np.radians([30.0, -90.0, 90.0, -90.0, -90.0, 0.0])
    sim.request("set_q", q=q.tolist())
    with socket.create_connection((sim.host, 30002), timeout=5) as s:
        s.sendall(text.encode())
    time.sleep(0.5)
    st = sim.state()
    assert st["runtime_state"] == RuntimeState.STOPPED and st["program_error"] == ""
    assert np.allclose(st["q"], q, atol=1e-4)
    assert any("home position first" in m["text"] for m in st["messages"])
