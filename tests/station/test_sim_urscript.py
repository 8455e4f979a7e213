"""The programs quickhealth writes run on the simulated controller (URScript on 30002).

``plan --cell reference`` writes ``loop.script``, the fixed loop of the paper's step 6: it
moves through the plan's poses and, at each, announces the pose in an output integer
register and waits for the station's acknowledgement in the input register of the same
number.  Here this test is the station: it watches the register and the TCP over RTDE
(``tests/helpers/qh_rtde_guide.py``, UR's RTDE guide), checks the arm is at the planned
pose, and acknowledges.  ``compensate`` rewrites the loop's joint targets; its program runs
the same way and reaches its own targets.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

import numpy as np
import pytest
from qh_rtde_guide import RtdeGuideClient

from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.identify.urscript import joint_targets
from quickhealth.station import formats
from quickhealth.station.cli import main
from quickhealth.station.hardware.urtypes import RuntimeState
from quickhealth.station.sim.arm import pose_from_T
from quickhealth.station.sim.process import start_sim_controller
from quickhealth.station.sim.states import TESTING

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

SPEED = 20.0  # the arm and the program's sleeps run this many times faster than life


@pytest.fixture(scope="module")
def plan_dir(tmp_path_factory):
    """The reference plan (150 candidates, seed 0: 74 poses) and a short one (14 poses)."""
    d = tmp_path_factory.mktemp("loop")
    for name, n in (("plan", "150"), ("short", "30")):
        args = ["plan", "--cell", "reference", "--n", n, "--seed", "0", "--out", str(d / name)]
        assert main(args) == 0
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


def run_loop(
    sim, text: str, reg: int, timeout: float = 120.0
) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Send ``text`` to 30002 and act as the station; returns the pose indices announced, the
    actual joints and the reported TCP poses at each announcement."""
    sim.request("set_q", q=np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]).tolist())
    seen: list[int] = []
    qs, tcps = [], []
    with RtdeGuideClient(sim.host) as g:
        assert g.request_protocol_version(2)
        rid, _ = g.setup_inputs([f"input_int_register_{reg}"])
        assert rid >= 1
        g.setup_outputs(
            [
                "timestamp",
                f"output_int_register_{reg}",
                "actual_q",
                "actual_TCP_pose",
                "runtime_state",
            ],
            125.0,
        )
        g.write(rid, {f"input_int_register_{reg}": 0})
        assert g.start()
        with socket.create_connection((sim.host, 30002), timeout=5) as s:
            s.sendall(text.encode())
        t0 = time.monotonic()
        started = False
        while time.monotonic() - t0 < timeout:
            d = g.read()
            started |= d["runtime_state"] == RuntimeState.PLAYING
            k = d[f"output_int_register_{reg}"]
            if k > 0 and (not seen or seen[-1] != k):
                seen.append(k)
                qs.append(d["actual_q"])
                tcps.append(d["actual_TCP_pose"])
                g.write(rid, {f"input_int_register_{reg}": k})
            if started and d["runtime_state"] == RuntimeState.STOPPED:
                break
    st = sim.state()
    assert st["program_error"] == "", st["program_error"]
    return seen, np.asarray(qs), np.asarray(tcps)


def test_plan_loop_script_visits_every_planned_pose(sim, plan_dir):
    text = (plan_dir / "plan" / "loop.script").read_text()
    from quickhealth.station.planning import load_plan

    plan = load_plan(plan_dir / "plan" / "plan.json")
    seen, qs, tcps = run_loop(sim, text, plan.motion.handshake_register)
    assert seen == [p.index for p in plan.poses]
    q_plan = np.stack([p.q for p in plan.poses])
    assert np.max(np.abs(qs - q_plan)) < 1e-4  # at rest after the settle time
    # The planned pose as this controller computes it: its factory calibration (the
    # simulator's default, seeded by the twin seed 1) and the program's TCP, set_tcp(...).
    from quickhealth.station.sim.arm import T_from_pose
    from quickhealth.station.sim.kinematics import factory_calibration
    from quickhealth.station.sim.world import build_world

    model = factory_calibration(build_world("reference", twin_seed=1).twin.robot, 1)
    T_tcp = T_from_pose(pose_from_T(plan.T_flange_target))
    want = (model.fk(q_plan) @ T_tcp)[:, :3, 3]
    err = np.linalg.norm(tcps[:, :3] - want, axis=1)
    print(f"loop.script: {len(seen)} poses, max TCP error {max(err) * 1e3:.4f} mm")
    assert max(err) < 1e-4


def test_a_compensated_program_runs_and_reaches_its_targets(sim, plan_dir, tmp_path):
    from quickhealth.identify.robot import ur5
    from quickhealth.station.planning import load_plan

    # A model fitted to measurements over the cell's joint ranges, the loop's poses among them.
    robot = ur5()
    short = load_plan(plan_dir / "short" / "plan.json")
    q = np.vstack([np.stack([p.q for p in short.poses]), random_joints(robot, 120, seed=6)])
    q = np.vstack([q, np.stack([p.q for p in load_plan(plan_dir / "plan" / "plan.json").poses])])
    meas = make_twin(robot, seed=5, geometric_pos=3e-5, geometric_rot=5e-5).measure(q)
    formats.write_measurements(tmp_path / "meas.csv", meas)
    assert main(["identify", "fit", str(tmp_path / "meas.csv"), "--robot", "ur5", "--out",
                 str(tmp_path / "fit"), "--max-order", "1", "--quiet"]) == 0  # fmt: skip
    out = tmp_path / "comp.script"
    src = plan_dir / "short" / "loop.script"
    code = main(["compensate", str(tmp_path / "fit" / "model.json"), str(src), "--out", str(out)])
    assert code in (0, 1) and out.is_file()
    text = out.read_text()
    targets = joint_targets(text, 6)
    assert not np.allclose(targets.q, joint_targets(src.read_text(), 6).q)  # it did rewrite
    from quickhealth.station.planning import load_plan

    plan = load_plan(plan_dir / "short" / "plan.json")
    seen, qs, _ = run_loop(sim, text, plan.motion.handshake_register)
    assert seen == [p.index for p in plan.poses]
    # the arm stands at the compensated joint targets (first pose: movej, then one per pose)
    assert np.max(np.abs(qs - targets.q[: len(seen)])) < 1e-4


def test_loop_script_refuses_to_start_away_from_home(sim, plan_dir):
    """The program's own check (textmsg, halt): it ends without moving."""
    text = Path(plan_dir / "short" / "loop.script").read_text()
    q = np.radians([30.0, -90.0, 90.0, -90.0, -90.0, 0.0])
    sim.request("set_q", q=q.tolist())
    with socket.create_connection((sim.host, 30002), timeout=5) as s:
        s.sendall(text.encode())
    time.sleep(0.5)
    st = sim.state()
    assert st["runtime_state"] == RuntimeState.STOPPED and st["program_error"] == ""
    assert np.allclose(st["q"], q, atol=1e-4)
    assert any("home position first" in m["text"] for m in st["messages"])
