"""The simulated controller's parts in this process: URScript, dashboard table, dynamics,
limits, calibration and power states (fast; the socket-level conformance suite is
test_sim_conformance.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quickhealth.identify.robot import BUILTIN_ROBOTS, UR_ARMS, builtin_robot, gravity_torques
from quickhealth.station.hardware.urtypes import RobotMode, RuntimeState, SafetyMode
from quickhealth.station.sim import dashboard
from quickhealth.station.sim.arm import HOME_Q_DEG, Arm, T_from_pose, pose_from_T
from quickhealth.station.sim.controller import CMD_MOVEL, CMD_NONE, Controller
from quickhealth.station.sim.dynamics import ArmDynamics
from quickhealth.station.sim.kinematics import (
    JointLimits,
    calibration_from_yaml,
    calibration_offset,
    check_joint_move,
    factory_calibration,
)
from quickhealth.station.sim.states import Delays, PowerStates
from quickhealth.station.sim.urscript_vm import (
    Halt,
    Interpreter,
    Pose,
    ScriptError,
    compile_program,
)


class FakeHost:
    """A controller that records what the program asks."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.regs: dict[str, object] = {}
        self.q = [0.0] * 6

    def move(self, kind, target, a, v, t, r):
        self.calls.append((kind, list(target), isinstance(target, Pose), a, v))
        if not isinstance(target, Pose):
            self.q = list(target)

    def sleep(self, s):
        self.calls.append(("sleep", s))

    def sync(self):
        pass

    def steptime(self):
        return 0.008

    def textmsg(self, text):
        self.calls.append(("textmsg", text))

    def popup(self, *a):
        self.calls.append(("popup", *a))

    def actual_q(self):
        return list(self.q)

    def actual_tcp_pose(self):
        return [0.0] * 6

    def target_tcp_pose(self):
        return [0.0] * 6

    def inverse_kin(self, pose, qnear):
        return None if pose[0] > 1.0 else [0.1] * 6

    def forward_kin(self, q, tcp):
        return [0.0] * 6

    def set_tcp(self, pose):
        self.calls.append(("set_tcp", pose))

    def set_payload(self, m, cog):
        pass

    def register(self, kind, index, value=None):
        if kind.startswith("output"):
            self.regs[f"{kind}{index}"] = value
            return None
        return self.regs.get(f"{kind}{index}", 0)

    def digital_out(self, i, v):
        self.calls.append(("dout", i, v))

    def check(self):
        pass


def run(text: str) -> FakeHost:
    h = FakeHost()
    Interpreter(compile_program(text), h).run()
    return h


# ------------------------------------------------------------------------ URScript


def test_urscript_subset_semantics():
    host = FakeHost()
    prog = compile_program(
        "def prog():\n"
        "  global total = 0\n"
        "  def add(x, y=10):\n"
        "    return x + y\n"
        "  end\n"
        "  xs = [1, 2, 3]\n"
        "  xs[0] = add(5)  # 15\n"
        "  i = 0\n"
        "  while True:\n"
        "    i = i + 1\n"
        "    if i == 2:\n"
        "      continue\n"
        "    elif i > 3:\n"
        "      break\n"
        "    end\n"
        "    total = total + xs[i - 1]\n"
        "  end\n"
        '  textmsg("total ", total)\n'
        "  movel(p[0.3, -0.1, 0.4, 0, 3.1416, 0], a=1.2, v=0.25, r=0.01)\n"
        "  movej([0.1, -1.5, 1.5, -1.5, -1.5, 0], t=2)\n"
        "  movep(p[0.3, -0.1, 0.3, 0, 3.1416, 0])\n"
        "  set_standard_digital_out(2, not False)\n"
        "  write_output_integer_register(24, 7 % 4)\n"
        '  popup("hello", title="T", blocking=False)\n'
        "  sleep(0.5)\n"
        "  q = get_inverse_kin(p[0.3, 0, 0.3, 0, 3.14, 0])\n"
        "  textmsg(norm([3, 4]) + 10 / 4)\n"
        "  halt\n"
        '  textmsg("never")\n'
        "end\n"
    )
    assert prog.name == "prog"
    with pytest.raises(Halt):
        Interpreter(prog, host).run()
    calls = host.calls
    assert ("textmsg", "total 18") in calls  # 15 + 3 (i == 2 skipped)
    assert ("movel", [0.3, -0.1, 0.4, 0.0, 3.1416, 0.0], True, 1.2, 0.25) in calls
    assert ("movej", [0.1, -1.5, 1.5, -1.5, -1.5, 0.0], False, 1.4, 1.05) in calls
    assert any(c[0] == "movep" for c in calls) and ("dout", 2, True) in calls
    assert host.regs["output_int24"] == 3 and ("sleep", 0.5) in calls
    assert ("textmsg", "7.5") in calls and ("textmsg", "never") not in calls


@pytest.mark.parametrize(
    "text, kind, words, line",
    [
        ("def a():\n  foo(1)\nend\n", "compile", "name 'foo' is not defined", 2),
        ("def a():\n  x = 1\n  x = x +\nend\n", "compile", "syntax error", 3),
        ("def a():\n  if True:\n    x = 1\n", "compile", "has no 'end'", 2),
        ("def a():\n  run t()\nend\n", "compile", "threads are not", 2),
        ("def a():\n  x = 1 / 0\nend\n", "runtime", "division by zero", 2),
        ("def a():\n  x = [1]\n  textmsg(x[1])\nend\n", "runtime", "index 1 out of range", 3),
        ("def a():\n  textmsg(y)\nend\n", "runtime", "variable 'y' is not defined", 2),
        ("def a():\n  movej(p[1, 2, 3])\nend\n", "runtime", "a pose has 6 elements", 2),
        ("def a():\n  movej([1, 2])\nend\n", "runtime", "6 joint angles", 2),
        (
            "def a():\n  q = get_inverse_kin(p[2.0, 0, 0.3, 0, 3.14, 0])\nend\n",
            "runtime",
            "no solution",
            2,
        ),
        ("def a():\n  sleep(-1)\nend\n", "runtime", "finite number >= 0", 2),
        ("def a():\n  write_output_integer_register(48, 1)\nend\n", "runtime", "does not exist", 2),
        ('def a():\n  x = "unterminated\nend\n', "compile", "string literal", 2),
        ("def a():\n  if 3 + [1]:\n  end\nend\n", "runtime", "a number is needed", 2),
    ],
)
def test_urscript_errors_are_the_controllers(text, kind, words, line):
    with pytest.raises(ScriptError) as e:
        run(text)
    assert e.value.kind == kind and words in e.value.message and e.value.line == line
    assert e.value.describe().startswith(f"{kind.capitalize()} error: ")


def test_the_plan_loop_program_compiles():
    from quickhealth.station.planning.urscript import render_urscript  # noqa: F401

    prog = compile_program(
        "def quickhealth_loop():\n"
        "  set_tcp(p[0, 0, 0.1, 0, 0, 0])\n"
        "  def qh_measure(index):\n"
        "    sleep(0.5)\n"
        "    write_output_integer_register(24, index)\n"
        "    qh_t = 0.0\n"
        "    while read_input_integer_register(24) != index:\n"
        "      sync()\n"
        "      qh_t = qh_t + get_steptime()\n"
        "      if qh_t > 0.05:\n"
        '        textmsg("no acknowledgement at pose ", index)\n'
        "        halt\n"
        "      end\n"
        "    end\n"
        "  end\n"
        "  qh_measure(1)\n"
        "end\n"
    )
    host = FakeHost()
    with pytest.raises(Halt):  # nobody acknowledges: the program's own timeout
        Interpreter(prog, host).run()
    assert ("textmsg", "no acknowledgement at pose 1") in host.calls


# ---------------------------------------------------------------- dashboard table


@pytest.fixture
def ctrl():
    from quickhealth.identify.robot import ur5

    c = Controller(Arm(ur5(), np.radians(HOME_Q_DEG)), delays=Delays(0.0, 0.0, 0.0, 0.0))
    yield c
    c.close()


def test_dashboard_replies_follow_the_version(ctrl):
    ask = lambda line: dashboard.answer(ctrl, line)  # noqa: E731
    assert ask("get operational mode").startswith("could not understand")
    assert ask("setUserRole programmer") == "Setting user role: programmer"
    ctrl.version = (5, 11, 1, 0)
    assert ask("get operational mode") == "NONE" and ask("is in remote control") == "true"
    assert ask("setUserRole programmer").startswith("could not understand")
    ctrl.version = (5, 3, 0, 0)  # before 5.6: no remote control query, no serial number
    assert ask("is in remote control").startswith("could not understand")
    assert ask("get serial number").startswith("could not understand")
    assert ask("PolyscopeVersion").startswith("URSoftware 5.3.0")
    assert ask("x" * 2000) == "could not understand: command too long"


def test_dashboard_power_brakes_and_the_state_machine(ctrl):
    ask = lambda line: dashboard.answer(ctrl, line)  # noqa: E731
    assert ask("power off") == "Powering off" and ctrl.robot_mode == RobotMode.POWER_OFF
    assert not ctrl.start_program()  # no program runs on a powered-off arm
    assert ask("power on") == "Powering on"
    assert ctrl.robot_mode == RobotMode.IDLE  # zero delays
    assert ask("brake release") == "Brake releasing" and ctrl.robot_mode == RobotMode.RUNNING
    assert ctrl.start_program() and ask("running") == "Program running: true"
    assert ask("pause") == "Pausing program" and ctrl.runtime_state == RuntimeState.PAUSED
    assert ask("programState") == "PAUSED rtde_control"
    assert ask("play") == "Starting program" and ctrl.runtime_state == RuntimeState.PLAYING
    ctrl._protective_stop("test")
    assert ask("unlock protective stop") == "Protective stop releasing"
    assert ctrl.safety_mode == SafetyMode.NORMAL
    assert ask("restart safety") == "Restarting safety" and ctrl.robot_mode == RobotMode.POWER_OFF


def test_power_states_take_their_time():
    p = PowerStates(Delays(boot_s=1.0, power_on_s=0.5, brake_release_s=2.0))
    p.power_off()
    assert p.power_on(10.0) and p.advance(10.0) == RobotMode.BOOTING
    assert p.advance(11.0) == RobotMode.POWER_ON and p.advance(11.5) == RobotMode.IDLE
    assert not p.can_move and p.brake_release(12.0)
    assert p.advance(13.9) == RobotMode.IDLE and p.advance(14.0) == RobotMode.RUNNING
    assert p.can_move
    with pytest.raises(ValueError, match="unknown delay"):
        Delays.parse("warp=1")
    with pytest.raises(ValueError, match="0..600"):
        Delays.parse("boot=-1")
    assert Delays.parse(Delays().spec()) == Delays()


# --------------------------------------------------------- per-model facts of each arm


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_dynamics_gravity_matches_the_arms_published_masses(name):
    robot = builtin_robot(name)
    q = np.random.default_rng(3).uniform(-3, 3, (5, 6))
    dyn = ArmDynamics(robot)
    for qi in q:
        tau = dyn.torques(qi, np.zeros(6), np.zeros(6), friction=False)
        assert np.allclose(tau, -gravity_torques(robot, qi)[0], atol=1e-9)
    # inertia: accelerating the base joint of a stretched arm takes torque, more for bigger arms
    stretched = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    t = dyn.torques(stretched, np.zeros(6), np.array([1.0, 0, 0, 0, 0, 0]), friction=False)
    assert t[0] > 0.3 * UR_ARMS[name].payload_kg / 5


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_limits_and_calibration_of_each_arm(name, tmp_path):
    robot = builtin_robot(name)
    lim = JointLimits.of(robot)
    assert np.allclose(lim.qd_max, np.radians(UR_ARMS[name].qd_max_deg))
    assert np.allclose(lim.q_max, 2 * np.pi)
    lead = float(np.min(lim.qd_max))
    assert check_joint_move(lim, np.zeros(6), np.full(6, 0.5), lead, 1.0) is None
    why = check_joint_move(lim, np.zeros(6), np.full(6, 0.5), lead * 1.2, 1.0)
    assert why is not None and why.startswith("joint speed limit")
    assert check_joint_move(lim, np.zeros(6), np.full(6, 0.5), 0.5, 60.0).startswith(
        "joint acceleration limit"
    )
    cal = factory_calibration(robot, seed=4)
    off = calibration_offset(robot, cal)
    assert 1e-4 < off < 5e-3, off  # up to millimetres, as a real factory calibration
    assert cal.nominal is not None and "factory calibration" in cal.nominal.calibration
    # the UR ROS driver's calibration YAML describes it; read back, the same kinematics
    from quickhealth.identify.ur_calibration import kinematics_of, kinematics_yaml

    path = tmp_path / "cal.yaml"
    export = kinematics_of(cal, reference=robot)
    assert export.flange_pos < 1e-9  # the layout holds all of it
    path.write_text(kinematics_yaml(export.kinematics))
    back = calibration_from_yaml(robot, str(path))
    q = np.random.default_rng(1).uniform(-3, 3, (20, 6))
    assert np.max(np.abs(back.fk(q)[:, :3, 3] - cal.fk(q)[:, :3, 3])) < 1e-8


# --------------------------------------------------------------- controller in process


def test_unreachable_line_and_calibrated_ik_in_process(ctrl):
    robot = ctrl.arm.robot
    ctrl.arm.robot = factory_calibration(robot, 2)  # calibrated kinematics, nominal closed form
    ctrl.arm.ik_model = robot
    ctrl.arm._pose_fk = type(ctrl.arm._pose_fk)(ctrl.arm.robot)
    assert ctrl.start_program()
    q = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])
    ctrl.set_q(q)
    pose = ctrl.forward_kin(None, None)
    assert np.allclose(ctrl.inverse_kin(pose, q.tolist()), q, atol=1e-6)
    assert ctrl.inverse_kin([2.0, 0.0, 0.3, 0.0, 3.14, 0.0], None) is None
    regs = {f"input_double_register_{i}": v for i, v in enumerate([1.5, 0, 0.3, 0, 3.14, 0])}
    regs.update(
        input_int_register_0=CMD_MOVEL,
        input_double_register_6=0.25,
        input_double_register_7=1.0,
        input_int_register_1=0,
    )
    ctrl.set_inputs(regs)
    import time

    t0 = time.monotonic()
    while ctrl.safety_mode != SafetyMode.PROTECTIVE_STOP and time.monotonic() - t0 < 5:
        ctrl.snapshot()
        time.sleep(0.005)
    assert ctrl.safety_mode == SafetyMode.PROTECTIVE_STOP
    assert "out of reach" in ctrl.messages[-1]["text"]
    assert np.allclose(ctrl.arm.q_cmd, q, atol=1e-9)  # nothing moved, nothing wound
    ctrl.set_inputs({"input_int_register_0": CMD_NONE})
    T = T_from_pose(pose)
    assert math.isclose(np.linalg.norm(T[:3, 3]), np.linalg.norm(pose[:3]))
    assert pose_from_T(T)[:3] == pytest.approx(pose[:3])
