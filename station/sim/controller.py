"""The simulated controller's state machine: modes, the ``rtde_control`` register protocol, faults.

One :class:`Controller` is shared by the socket servers (:mod:`.servers`).  It emulates
the main loop of the URScript program ``rtde_control`` uploads (``notes/ur-rtde.md``): a
command in ``input_int_register_0``, the handshake on ``output_int_register_0`` (1 ready,
2 done), async progress in ``output_int_register_2``.

Timing guarantees
-----------------
- The controller lock is only ever held for microseconds: copying state, accepting a
  command, installing a planned motion.  :meth:`Controller.snapshot` (what the RTDE
  stream sends) takes the lock only to copy state; forward kinematics and packing happen
  outside it.
- Commands that take time to plan (moveL, moveL_FK, moveJ_IK) are accepted under the lock
  (the arm holds where it is) and handed to the planner thread, which computes the path
  without the lock and installs it with its start time.  While it plans, a synchronous move
  is simply not done yet and an asynchronous one reports "running, 0 %".  A stop, a
  protective stop, a program stop or a restart meanwhile cancels the plan.
"""

from __future__ import annotations

import math
import queue
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...identify.transforms import log_so3
from ..hardware.urtypes import (
    RobotMode,
    RuntimeState,
    SafetyMode,
    safety_status_bits,
)
from .arm import (
    Arm,
    Motion,
    Path,
    T_from_pose,
    ik_near,
    joint_path,
    linear_path,
    pose_from_T,
)
from .dynamics import TORQUE_CONSTANT, ArmDynamics, Thermal
from .io import DigitalOutputs
from .kinematics import JointLimits, check_joint_move, check_path
from .states import Delays, PowerStates
from .wire import CB3_VERSION, CONTROL_PORT, HOST, max_stream_hz

#: Where a picked part sits on the flange (m, flange frame): in the gripper beyond the target.
PART_COM = (0.0, 0.0, 0.12)

# Register commands of the rtde_control script (rtde.h).
CMD_NONE = 0
CMD_MOVEJ = 1
CMD_MOVEJ_IK = 2
CMD_MOVEL = 3
CMD_MOVEL_FK = 4
CMD_SET_PAYLOAD = 17
CMD_GET_STEPTIME = 26
CMD_SET_TCP = 29
CMD_GET_IK_ARGS = 30
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_POSE_SAFE = 36
CMD_JOINTS_SAFE = 37
CMD_GET_JOINT_TORQUES = 38
CMD_POSE_TRANS = 39
CMD_GET_TCP_OFFSET = 40
CMD_GET_FK_DEFAULT = 43
CMD_GET_FK_ARGS = 44
CMD_GET_IK_DEFAULT = 46
CMD_IS_STEADY = 47
CMD_GET_FLANGE_POSE = 58
CMD_IK_HAS_SOLUTION_DEFAULT = 60
CMD_IK_HAS_SOLUTION_ARGS = 61
CMD_STOP_SCRIPT = 255
MOVES = frozenset({CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK})
# Commands the script processes every cycle while they stand in the register, signalling
# "ready" each time; the client does not wait for them (servo, speed, force mode, and the
# queries get_joint_torques, get_steptime, the flange pose …: ur-rtde 1.6's script).
REALTIME = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
PLANNED = frozenset({CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK})  # planned in the planner thread

FAULT_KINDS = (
    "protective_stop",
    "emergency_stop",
    "program_stop",
    "freeze_stream",
    "drop_connection",
    "restart",
    "slow_program_start",
    "power_off",
    "pause",
    "joint_speed_limit",
    "unknown_command",
    "clear",
)

RESTART_DOWN_S = 2.0  # default time a restarting controller refuses connections

# RTDE joint_mode of each robot mode (UR's JointMode numbers).
_JOINT_MODE = {
    RobotMode.POWER_OFF: 239,
    RobotMode.BOOTING: 247,
    RobotMode.POWER_ON: 246,
    RobotMode.IDLE: 255,
    RobotMode.RUNNING: 253,
}


@dataclass(frozen=True)
class PlanJob:
    """A motion command accepted by the controller and waiting for its path."""

    gen: int  # the controller's plan generation when accepted (a stop bumps it: cancelled)
    cmd: int
    target: tuple[float, ...]  # q (moveJ_IK: TCP pose; moveL: TCP pose; moveL_FK: q)
    speed: float
    accel: float
    is_async: bool
    q0: tuple[float, ...]  # where the arm holds while the path is planned
    limits: JointLimits | None = None  # the controller's joint limits (checked when given)
    speed_factor: float = 1.0  # speed and accel are scaled by it (and by its square)


def plan_command(arm: Arm, job: PlanJob) -> Path | str:
    """The path of an accepted motion command, or an error text (pure; runs without the lock).

    A path that leaves the joint limits anywhere along it is refused too (an error text:
    protective stop), not only one whose target lies outside them."""
    path = _plan_path(arm, job)
    if isinstance(path, str) or job.limits is None:
        return path
    j = job.limits.outside(path.q)
    if j is None:
        return path
    return f"{_NAMES.get(job.cmd, 'move')}: joint position limit: joint {j + 1} leaves its range"


_NAMES = {
    CMD_MOVEJ: "moveJ",
    CMD_MOVEJ_IK: "moveJ_IK",
    CMD_MOVEL: "moveL",
    CMD_MOVEL_FK: "moveL_FK",
}


def _plan_path(arm: Arm, job: PlanJob) -> Path | str:
    q0 = np.asarray(job.q0)
    target = np.asarray(job.target)
    lim = job.limits
    k = job.speed_factor
    speed, accel = job.speed / k, job.accel / (k * k)  # as commanded, for the limit checks
    if job.cmd in (CMD_MOVEL, CMD_MOVEL_FK):
        q_goal = target if job.cmd == CMD_MOVEL_FK else None
        T = arm.robot.fk(target) @ arm.tcp if q_goal is not None else T_from_pose(target)
        if lim is not None:
            # The goal first: an unreachable one is refused before a line is planned to it.
            if q_goal is None:
                q_end, ok = ik_near(arm.robot, arm.tcp, T, q0, arm.ik_model)
                if not ok:
                    return "inverse kinematics: the target pose is out of reach"
            j = lim.outside(target if q_goal is not None else q_end)
            if j is not None:
                return f"joint position limit: joint {j + 1} target outside its range"
        path = linear_path(arm.robot, arm.tcp, q0, T, q_goal, arm.ik_model)
        if lim is not None:
            why = check_path(arm.robot, arm.tcp, lim, path, T, speed, accel)
            if why is not None:
                return why
        return path
    if job.cmd == CMD_MOVEJ_IK:
        q, ok = ik_near(arm.robot, arm.tcp, T_from_pose(target), q0, arm.ik_model)
        if not ok:
            return "moveJ_IK: no inverse kinematics solution"
        target = q
    if lim is not None:
        why = check_joint_move(lim, q0, target, speed, accel)
        if why is not None:
            return why
    return joint_path(q0, target)


class Controller:
    """Controller state shared by the RTDE, dashboard, script and control servers."""

    def __init__(
        self,
        arm: Arm,
        *,
        control_port: int = CONTROL_PORT,
        verbose: bool = False,
        version: tuple[int, int, int, int] = CB3_VERSION,
        host: str = HOST,
        delays: Delays | None = None,
        payload_kg: float = 0.0,
        payload_com: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.arm = arm
        self.host = host  # the loopback address every server listens on
        self.control_port = control_port
        self.verbose = verbose
        self.version = tuple(version)
        self.lock = threading.RLock()
        self.t_start = time.monotonic()
        self.power = PowerStates(delays or Delays())
        self.limits = JointLimits.of(arm.ik_model or arm.robot)
        self.limit_scale = 1.0  # safety limits lowered (fault ``joint_speed_limit``)
        self.safety_mode = SafetyMode.NORMAL
        self.protective_since = 0.0  # controller time the last protective stop began
        self.program_kind: str | None = None  # "rtde_control" (emulated), "urscript" or None
        self.program_name = "<unnamed>"
        self.program_seq = 0  # bumped by every start and stop: a program thread sees it end
        self.program_error = ""  # the last compile or runtime error, the controller's words
        self.loaded: str | None = None  # the program loaded on the dashboard (``load``)
        self.programs_dir: str | None = None  # where ``load`` finds programs
        self.popup_text: str | None = None  # an open popup (``popup``), closed on the dashboard
        self.resume_job: PlanJob | None = None  # the rtde_control move a pause interrupted
        self.messages: list[dict[str, Any]] = []  # robot messages (textmsg, runtime exceptions)
        self.on_message: Callable[[dict[str, Any]], None] | None = None  # primary clients
        self.input_owners: dict[str, Any] = {}  # input field -> the RTDE session writing it
        self.io = DigitalOutputs()  # the digital output terminal (RTDE masks, URScript)
        self.unknown_command_pending = False
        # Dynamics: the real arm carries the true payload; the controller's model only the
        # payload it was told (set_payload), none at start.
        self.true_payload = (float(payload_kg), tuple(map(float, payload_com)))
        dyn_robot = arm.ik_model or arm.robot
        self.dyn_true = ArmDynamics(dyn_robot, payload_kg, np.asarray(payload_com, float))
        self.dyn_model = ArmDynamics(dyn_robot, 0.0)
        self.thermal = Thermal.start(arm.robot.n_joints)
        # pick and place (pick_and_place): at each move the gripper takes up or puts down a
        # part of up to this mass (kg) on top of the true payload; 0: the payload stays
        self.part_max_kg = 0.0
        self._part_rng = np.random.default_rng(23)
        self.part_kg = 0.0
        self._derived_lock = threading.Lock()
        self._rng = np.random.default_rng(11)
        self.runtime_state = RuntimeState.STOPPED
        self.inputs: dict[str, Any] = {}
        self.outputs: dict[str, Any] = {"output_int_register_0": 0}
        self.executing = False
        self.current_cmd = CMD_NONE
        self.sync_motion: Motion | None = None
        self.async_motion: Motion | None = None
        self.async_id = 0
        self.async_writes = 0
        self.planning: PlanJob | None = None  # accepted, path being planned
        self.last_job: PlanJob | None = None  # the last motion installed
        self.plan_gen = 0
        self.plan_fn: Callable[[Arm, PlanJob], Path | str] = plan_command
        self.frozen: dict[str, Any] | None = None  # last state while the stream is frozen
        self.refuse_connections = False
        self.refuse_until = 0.0  # time.monotonic() before which connections are refused
        self.connections: list[socket.socket] = []
        self.listeners: list[socket.socket] = []
        self.sessions: list[Any] = []  # the RTDE sessions (servers.RtdeSession) now open
        self.pending_faults: list[dict[str, Any]] = []
        self.n_moves = 0
        self.n_restarts = 0
        # Every stop command received: (time.monotonic(), how).  The clock is the host's
        # CLOCK_MONOTONIC, shared by every process: a client measures its stop latency with it.
        self.stops: list[tuple[float, str]] = []
        self.program_start_delay = 0.0  # s from a script upload to the program running
        self.log: list[str] = []
        self.stop_event = threading.Event()
        self.world: Any = None  # the simulated cell's ground truth (world.SimWorld)
        self.speed_factor = 1.0
        self._target_pose: tuple[list[float], list[float]] = ([], [])
        self._jobs: queue.SimpleQueue[PlanJob | None] = queue.SimpleQueue()
        self._planner = threading.Thread(target=self._plan_loop, name="planner", daemon=True)
        self._planner.start()

    # -- time and state -------------------------------------------------------------
    def now(self) -> float:
        """Controller time, s (continuous; the RTDE ``timestamp`` is :meth:`cycle_time`)."""
        return time.monotonic() - self.t_start

    @property
    def step_s(self) -> float:
        """The controller cycle: 8 ms on CB3, 2 ms on e-Series (URScript ``get_steptime``)."""
        return 1.0 / self.stream_hz

    def cycle_time(self, t: float) -> float:
        """Controller time at the start of the cycle ``t`` falls in: timestamps advance in
        whole controller steps, as a real controller's do."""
        k = math.floor(t / self.step_s + 1e-6)
        return k * self.step_s

    @property
    def robot_mode(self) -> RobotMode:
        return self.power.advance(self.now())

    @robot_mode.setter
    def robot_mode(self, mode: RobotMode) -> None:
        self.power.force(mode)

    def can_move(self) -> bool:
        """Powered, brakes released, safety normal: the arm may move."""
        return self.power.can_move and self.safety_mode in (SafetyMode.NORMAL, SafetyMode.REDUCED)

    def message(self, kind: str, text: str, line: int = 0, col: int = 0) -> None:
        """A robot message (``text``, ``runtime_exception``, ``popup``, ``error``) for the
        primary and secondary clients and the log."""
        msg = {"kind": kind, "text": text, "line": line, "col": col, "t": self.now()}
        self.messages.append(msg)
        del self.messages[:-200]
        self.say(f"{kind}: {text}" + (f" (line {line})" if line else ""))
        hook = self.on_message
        if hook is not None:
            try:
                hook(msg)
            except Exception:  # noqa: BLE001 - a broken client must not stop the controller
                pass

    def say(self, msg: str) -> None:
        """Log an event (kept for the ``log`` control request; stderr when verbose)."""
        self.log.append(f"{self.now():8.3f} {msg}")
        del self.log[:-1000]
        if self.verbose:
            sys.stderr.write(f"simcontroller: {msg}\n")

    @property
    def stream_hz(self) -> float:
        """Highest RTDE output rate of the reported controller version."""
        return max_stream_hz(self.version)

    def accepting(self) -> bool:
        """False while new connections are refused (dropped link, restarting controller)."""
        return not self.refuse_connections and time.monotonic() >= self.refuse_until

    def safety_status_bits(self) -> int:
        return safety_status_bits(self.safety_mode)

    def robot_status_bits(self) -> int:
        power = 1 if self.robot_mode in (RobotMode.IDLE, RobotMode.RUNNING) else 0
        running = 2 if self.runtime_state == RuntimeState.PLAYING else 0
        return power | running

    def snapshot(self, t_cycle: float | None = None) -> dict[str, Any]:
        """Every output field's current value (the frozen copy while the stream is frozen).

        The lock is held only to advance the emulated script by one cycle (never planning)
        and copy the state; the TCP poses are computed outside it.
        """
        with self.lock:
            if self.frozen is not None:
                return self.frozen
            t = self.cycle_time(self.now() if t_cycle is None else t_cycle)
            self._step(t)
            s = self._copy_state(t)
        return self._complete(s)

    def _copy_state(self, t: float) -> dict[str, Any]:
        q_target, _ = self.arm.target(t)
        qd, qdd = self.arm.derivatives(t)
        s: dict[str, Any] = dict(self.inputs)  # input registers read back in output recipes
        s.update(self.outputs)
        mode = self.robot_mode
        s.update(
            timestamp=t,
            target_q=q_target,
            target_qd=qd,
            target_qdd=qdd,
            actual_q=self.arm.actual(t),
            robot_mode=int(mode),
            safety_mode=int(self.safety_mode),
            safety_status=int(self.safety_mode),
            runtime_state=int(self.runtime_state),
            robot_status_bits=self.robot_status_bits(),
            safety_status_bits=self.safety_status_bits(),
            joint_mode=[_JOINT_MODE.get(mode, 253)] * 6,
            tcp_offset=pose_from_T(self.arm.tcp),
            payload=self.dyn_model.payload_kg,
            payload_cog=list(map(float, self.dyn_model.payload_com)),
            actual_digital_output_bits=self.io.bits,
            _running=mode == RobotMode.RUNNING,
            _powered=self.power.powered,
        )
        return s

    def _complete(self, s: dict[str, Any]) -> dict[str, Any]:
        """The derived and constant fields of a copied state (no controller lock needed)."""
        qa, qt = np.asarray(s["actual_q"]), np.asarray(s["target_q"])
        qd, qdd = np.asarray(s["target_qd"]), np.asarray(s["target_qdd"])
        q, q_target = list(map(float, qa)), list(map(float, qt))
        cached = self._target_pose  # the target rests most of the time: one FK saved
        if cached[0] != q_target:
            cached = self._target_pose = (q_target, self.arm.tcp_pose(q_target))
        moving = bool(np.any(qd != 0.0))
        tcp_speed = self._tcp_speed(qt, qd) if moving else [0.0] * 6
        running, powered = s.pop("_running"), s.pop("_powered")
        with self._derived_lock:
            if running:  # the motors hold the arm: torques and currents
                tau_true = self.dyn_true.torques(qa, qd, qdd)
                tau_model = self.dyn_model.torques(qt, qd, qdd)
                noise = self._rng.normal(0.0, 0.01, 6)
            else:  # brakes hold it (or it is off): no current
                tau_true = tau_model = noise = np.zeros(6)
            current = tau_true / TORQUE_CONSTANT + noise
            # the joints warm on the arm's own clock: N× faster than life at the speed
            # factor N, with the loads the motion has at life speed
            k = self.speed_factor
            tau_life = tau_true
            if running and k != 1.0 and moving:
                tau_life = self.dyn_true.torques(qa, qd / k, qdd / (k * k))
            temps = self.thermal.advance(
                s["timestamp"], tau_life / TORQUE_CONSTANT, tau_life, qd / k, powered, k
            )
            qd_actual = qd + (self._rng.normal(0.0, 1e-4, 6) if moving else 0.0)
        s.update(
            target_q=q_target,
            actual_q=q,
            target_qd=list(map(float, qd)),
            target_qdd=list(map(float, qdd)),
            actual_qd=list(map(float, qd_actual)),
            actual_TCP_pose=self.arm.tcp_pose(q),
            target_TCP_pose=list(cached[1]),
            actual_TCP_speed=tcp_speed,
            target_TCP_speed=tcp_speed,
            actual_current=list(map(float, current)),
            target_current=list(map(float, tau_model / TORQUE_CONSTANT)),
            target_moment=list(map(float, tau_model)),
            actual_current_as_torque=list(map(float, tau_true)),
            joint_control_output=list(map(float, current)),
            actual_robot_current=float(0.4 * powered + np.sum(np.abs(current)) * 0.12),
            speed_scaling=1.0,
            target_speed_fraction=1.0,
            joint_temperatures=list(map(float, temps)),
            actual_main_voltage=48.0,
            actual_robot_voltage=48.0 if powered else 0.0,
            actual_joint_voltage=[48.0 if powered else 0.0] * 6,
            tool_temperature=float(temps[-1]) + 2.0,
        )
        return s

    def _tcp_speed(self, q: np.ndarray, qd: np.ndarray, h: float = 1e-3) -> list[float]:
        """TCP velocity (m/s, rad/s in the base frame) of joints ``q`` moving at ``qd``."""
        robot, tcp = self.arm.robot, self.arm.tcp
        Ta = robot.fk(q - qd * h) @ tcp
        Tb = robot.fk(q + qd * h) @ tcp
        v = (Tb[:3, 3] - Ta[:3, 3]) / (2 * h)
        w = log_so3(Tb[:3, :3] @ Ta[:3, :3].T) / (2 * h)
        return [*map(float, v), *map(float, w)]

    def joint_torques(self) -> list[float]:
        """URScript ``get_joint_torques()``: the real torques minus the controller's model."""
        t = self.now()
        with self.lock:
            qa = self.arm.actual(t)
            q, _ = self.arm.target(t)
            qd, qdd = self.arm.derivatives(t)
            running = self.robot_mode == RobotMode.RUNNING
        if not running:
            return [0.0] * 6
        with self._derived_lock:
            d = self.dyn_true.torques(qa, qd, qdd) - self.dyn_model.torques(q, qd, qdd)
            d += self._rng.normal(0.0, 0.05, 6)
        return list(map(float, d))

    @property
    def digital_out(self) -> int:
        """The digital outputs now (``actual_digital_output_bits``)."""
        return self.io.bits

    def next_cycle(self, t: float) -> float:
        """The start of the controller cycle after the one ``t`` falls in: where an input
        received at ``t`` takes effect."""
        return (math.floor(t / self.step_s + 1e-6) + 1) * self.step_s  # as the stream stamps it

    def set_inputs(self, values: dict[str, Any]) -> None:
        """Merge a client's input-recipe packet into the register bank and run one cycle;
        digital output masks and levels take effect at the next cycle (:mod:`.io`)."""
        with self.lock:
            self.inputs.update(values)
            t = self.now()
            self.io.request(values, self.next_cycle(t))
            self._step(t)

    # -- the script main loop (register protocol) --------------------------------------
    def _step(self, t: float) -> None:
        """Advance the emulated ``rtde_control`` script by one cycle (microseconds)."""
        self.power.advance(t)
        self.io.advance(t)
        self._fire_due_faults(t)
        self._report_async(t)
        if (
            self.program_kind != "rtde_control"
            or self.runtime_state != RuntimeState.PLAYING
            or self.safety_mode != SafetyMode.NORMAL
        ):
            return
        cmd = int(self.inputs.get("input_int_register_0", 0))
        if cmd in REALTIME:
            d = [float(self.inputs.get(f"input_double_register_{i}", 0.0)) for i in range(14)]
            self._query(cmd, d)
            self.executing = False
            self.outputs["output_int_register_0"] = 1
            return
        if self.executing:
            if self.sync_motion is not None:
                if not self.arm.moving(t) and self.arm.motion is None:
                    self.sync_motion = None
                    self.outputs["output_int_register_0"] = 2
            if cmd == CMD_NONE:
                self.executing = False
                self.sync_motion = None
                self.outputs["output_int_register_0"] = 1
            return
        if cmd == CMD_NONE:
            return
        self.executing = True
        self.current_cmd = cmd
        self._execute(cmd, t)

    def _report_async(self, t: float) -> None:
        """Async progress in output_int_register_2: id, write counter, running bit, progress."""
        job = self.planning
        if self.async_motion is None and (job is None or not job.is_async):
            return
        self.async_writes = (self.async_writes + 1) & 0xFF
        head = ((self.async_id & 0x7F) << 24) | (self.async_writes << 16)
        m = self.async_motion
        if m is None:  # still planning: running, 0 %
            self.outputs["output_int_register_2"] = head | (1 << 15)
        elif m.q_at(t)[1] or self.arm.motion is not m:
            # Finished: operation id and write counter kept, the running bit (15) cleared.
            self.outputs["output_int_register_2"] = head
            self.async_motion = None
        else:
            self.outputs["output_int_register_2"] = head | (1 << 15) | int(m.fraction(t) * 0x7FFF)

    def _execute(self, cmd: int, t: float) -> None:
        d = [float(self.inputs.get(f"input_double_register_{i}", 0.0)) for i in range(14)]
        is_async = int(self.inputs.get("input_int_register_1", 0)) == 1
        if self.unknown_command_pending:  # fault: a command this controller does not know
            self.unknown_command_pending = False
            self._runtime_error(f"name 'rtde_cmd_{cmd}' is not defined", kind="compile")
            return
        if cmd in MOVES:
            self.n_moves += 1
            self._fire_move_faults()
            self.next_part()
            if self.safety_mode != SafetyMode.NORMAL or self.runtime_state != RuntimeState.PLAYING:
                return
            if not self.power.can_move:  # a program cannot move an arm that is not running
                self._runtime_error(f"the robot is not running (robot mode {self.robot_mode.name})")
                return
            k = self.speed_factor  # tests run the arm faster than life
            speed, accel = max(d[6], 1e-3) * k, max(d[7], 1e-3) * k * k
            if not all(math.isfinite(v) for v in d[:8]):
                self.say(f"cmd {cmd}: non-finite argument refused")
                self._protective_stop("non-finite move argument")
                return
            self._cancel_planning()  # an async move still being planned is superseded
            q0 = self.arm.hold(t)
            job = PlanJob(
                self.plan_gen,
                cmd,
                tuple(d[:6]),
                speed,
                accel,
                is_async,
                tuple(q0),
                self.current_limits(),
                k,
            )
            self.async_motion = None
            if is_async:
                self.async_id = (self.async_id + 1) & 0x7F
                self.outputs["output_int_register_0"] = 2
            if cmd in PLANNED:
                self.planning = job
                self._report_async(t)
                self._jobs.put(job)
            else:  # moveJ: only the limits to check
                self._install(job, plan_command(self.arm, job), t)  # no planner thread
        elif cmd in (CMD_STOPJ, CMD_STOPL):
            self.note_stop("stopj" if cmd == CMD_STOPJ else "stopl")
            self._cancel_planning()
            self.arm.halt(t)
            self.async_motion = None
            self.outputs["output_int_register_2"] = -1
            self.outputs["output_int_register_0"] = 2
        elif cmd == CMD_STOP_SCRIPT:
            self.note_stop("stop_script")
            self._cancel_planning()
            self.arm.halt(t)
            self.runtime_state = RuntimeState.STOPPED
            self.executing = False
            self.say("script stopped")
        else:
            self._query(cmd, d)
            self.outputs["output_int_register_0"] = 2

    def _query(self, cmd: int, d: list[float]) -> None:
        """The rtde_control script's computing commands: results in output_double_register_0..5
        (poses, joints, torques) or output_int_register_1 (yes/no), as the script writes them.
        Any other command is acknowledged without effect (force mode, jogging, …)."""
        out = self.outputs
        t = self.now()

        def put(vals: list[float]) -> None:
            for i, v in enumerate(vals):
                out[f"output_double_register_{i}"] = float(v)

        q_now = self.arm.actual(t)
        if cmd == CMD_SET_PAYLOAD:
            self.set_payload(d[0], d[1:4])
        elif cmd == CMD_GET_STEPTIME:
            put([self.step_s])
        elif cmd == CMD_SET_TCP:
            self.arm.tcp = T_from_pose(d[:6])
        elif cmd in (CMD_GET_IK_ARGS, CMD_GET_IK_DEFAULT):
            near = d[6:12] if cmd == CMD_GET_IK_ARGS else None
            q = self.inverse_kin(d[:6], near)
            put(q if q is not None else [0.0] * 6)  # the script writes what it gets
            if q is None:
                self._runtime_error("get_inverse_kin(): no solution: the pose is out of reach")
        elif cmd in (CMD_IK_HAS_SOLUTION_DEFAULT, CMD_IK_HAS_SOLUTION_ARGS):
            near = d[6:12] if cmd == CMD_IK_HAS_SOLUTION_ARGS else None
            out["output_int_register_1"] = int(self.inverse_kin(d[:6], near) is not None)
        elif cmd == CMD_PROTECTIVE_STOP:
            self._protective_stop("protective_stop() called by the program")
        elif cmd == CMD_POSE_SAFE:
            out["output_int_register_1"] = int(self.inverse_kin(d[:6], None) is not None)
        elif cmd == CMD_JOINTS_SAFE:
            out["output_int_register_1"] = int(self.limits.outside(np.asarray(d[:6])) is None)
        elif cmd == CMD_GET_JOINT_TORQUES:
            put(self.joint_torques())
        elif cmd == CMD_POSE_TRANS:
            put(pose_from_T(T_from_pose(d[:6]) @ T_from_pose(d[6:12])))
        elif cmd == CMD_GET_TCP_OFFSET:
            put(pose_from_T(self.arm.tcp))
        elif cmd == CMD_GET_FK_DEFAULT:
            put(self.forward_kin(None, None))
        elif cmd == CMD_GET_FK_ARGS:
            put(self.forward_kin(d[:6], d[6:12]))
        elif cmd == CMD_IS_STEADY:
            out["output_int_register_1"] = int(self.is_steady(t))
        elif cmd == CMD_GET_FLANGE_POSE:
            put(pose_from_T(self.arm.robot.fk(q_now)))

    # -- kinematics the programs ask for (the controller's calibrated model) ----------
    def inverse_kin(self, pose: Any, qnear: Any) -> list[float] | None:
        """Joints reaching TCP ``pose`` nearest ``qnear`` (default: the actual joints) within
        the joint limits, or None (out of reach)."""
        p = np.asarray(pose, dtype=float)
        if p.shape != (6,) or not np.all(np.isfinite(p)):
            return None
        ref = self.arm.actual(self.now()) if qnear is None else np.asarray(qnear, dtype=float)
        q, ok = ik_near(self.arm.robot, self.arm.tcp, T_from_pose(p), ref, self.arm.ik_model)
        if not ok or self.limits.outside(q) is not None:
            return None
        return list(map(float, q))

    def forward_kin(self, q: Any, tcp: Any) -> list[float]:
        """TCP pose of joints ``q`` (default: actual) with ``tcp`` (default: the active TCP)."""
        qq = self.arm.actual(self.now()) if q is None else np.asarray(q, dtype=float)
        T_tcp = self.arm.tcp if tcp is None else T_from_pose(tcp)
        return pose_from_T(self.arm.robot.fk(qq) @ T_tcp)

    def is_steady(self, t: float) -> bool:
        """Not moving, and the ringing after the last stop has died down."""
        return not self.arm.moving(t) and t - self.arm.stop_time > 8 * self.arm.RING_TAU

    def pick_and_place(self, max_kg: float) -> None:
        """From the next move on, the real arm carries a part of up to ``max_kg`` or none,
        changed at the start of every move (seeded): what the joint torques show and a
        compliance bends under, which the controller's model is never told."""
        self.part_max_kg = max(float(max_kg), 0.0)

    def next_part(self) -> None:
        """At the start of a move: take up or put down a part (:meth:`pick_and_place`)."""
        if self.part_max_kg <= 0.0:
            return
        rng = self._part_rng
        part = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.2, 1.0)) * self.part_max_kg
        mass, com = self.true_payload
        total = mass + part
        at = (np.asarray(com) * mass + np.array(PART_COM) * part) / max(total, 1e-12)
        dyn = ArmDynamics(self.arm.ik_model or self.arm.robot, total, at)
        with self._derived_lock:
            self.dyn_true, self.part_kg = dyn, part

    def joint_conditions(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """What the real arm's joints are at, now, at rest at ``q``: their temperatures (°C)
        and the torques their drives exert (N·m, the true payload held against gravity)."""
        with self._derived_lock:
            temps = self.thermal.temps
            tau = self.dyn_true.torques(np.asarray(q, float), np.zeros(len(q)), np.zeros(len(q)))
        return {"joint_temp": temps, "joint_torque": tau}

    def set_payload(self, mass: float, cog: Any) -> None:
        """The payload the controller's model carries (``set_payload``)."""
        if not (math.isfinite(mass) and 0.0 <= mass <= 1000.0):
            return
        com = np.zeros(3) if cog is None else np.asarray(cog, dtype=float)
        robot = self.arm.ik_model or self.arm.robot
        self.dyn_model = ArmDynamics(robot, mass, com)

    def current_limits(self) -> JointLimits:
        """The joint limits in force (the hardware's, lowered by ``joint_speed_limit``)."""
        lim = self.limits
        if self.limit_scale >= 1.0:
            return lim
        return JointLimits(lim.q_min, lim.q_max, lim.qd_max * self.limit_scale, lim.qdd_max)

    def _install(self, job: PlanJob, path: Path | str, t: float) -> None:
        """Start the planned motion of ``job`` at ``t`` (under the lock)."""
        self.planning = None
        self.last_job = job
        if isinstance(path, str):
            if job.is_async:
                self.outputs["output_int_register_2"] = -1
            self._protective_stop(path)
            return
        m = Motion.timed(path, job.speed, job.accel, t)  # within the limits: plan_command
        self.arm.start(m)
        self.say(
            f"cmd {job.cmd} {'async' if job.is_async else 'sync'} {m.duration:.3f} s"
            f" ({path.method}, {path.q.shape[0]} samples)"
        )
        if job.is_async:
            self.async_motion = m
        else:
            self.sync_motion = m

    def _cancel_planning(self) -> None:
        job = self.planning
        if job is not None:
            self.say(f"cmd {job.cmd}: planning cancelled")
            if job.is_async:  # the operation ends: running bit cleared
                self.async_writes = (self.async_writes + 1) & 0xFF
                self.outputs["output_int_register_2"] = ((self.async_id & 0x7F) << 24) | (
                    self.async_writes << 16
                )
        self.planning = None
        self.plan_gen += 1

    # -- the planner thread ------------------------------------------------------------
    def _plan_loop(self) -> None:
        try:  # warm up (imports, first calls) before the first real command
            q = self.arm.q_cmd.copy()
            T = self.arm.robot.fk(q) @ self.arm.tcp
            T[2, 3] += 0.01
            linear_path(self.arm.robot, self.arm.tcp, q, T)
        except Exception:  # noqa: BLE001 - only a warm-up
            pass
        while True:
            job = self._jobs.get()
            if job is None:
                return
            t0 = time.monotonic()
            try:
                path: Path | str = self.plan_fn(self.arm, job)  # no lock: pure computation
            except Exception as exc:  # noqa: BLE001 - a planning bug must not kill the thread
                path = f"path planning failed: {type(exc).__name__}: {exc}"
            with self.lock:
                if self.planning is not job or self.plan_gen != job.gen:
                    continue  # stopped, restarted or superseded meanwhile
                dt = time.monotonic() - t0
                if dt > 0.05:
                    self.say(f"cmd {job.cmd}: planning took {dt * 1000:.0f} ms")
                self._install(job, path, self.now())

    def close(self) -> None:
        """Stop the planner thread."""
        self._jobs.put(None)

    # -- program and safety --------------------------------------------------------------
    def start_program(self, kind: str = "rtde_control", name: str = "rtde_control") -> bool:
        """Start a program (the emulated ``rtde_control`` script by default); False (and the
        reason logged) when the robot cannot run one: safety stop, not powered or braked."""
        with self.lock:
            if self.safety_mode != SafetyMode.NORMAL:
                self.say("program start refused: safety stop active")
                return False
            if not self.power.can_move:
                self.say(f"program start refused: robot mode {self.robot_mode.name}")
                return False
            self._cancel_planning()
            self.program_seq += 1
            self.program_kind = kind
            self.program_name = name
            self.program_error = ""
            self.resume_job = None
            self.inputs["input_int_register_0"] = 0
            self.executing = False
            self.sync_motion = None
            self.runtime_state = RuntimeState.PLAYING
            if kind == "rtde_control":
                self.outputs["output_int_register_0"] = 1
                self.outputs["output_int_register_2"] = -1
            self.say(f"program running: {name}")
            return True

    def note_stop(self, how: str) -> None:
        """Record a stop command as received now (for the clients' stop-latency figures)."""
        with self.lock:
            self.stops.append((time.monotonic(), how))
            del self.stops[:-100]

    def stop_program(self) -> bool:
        """Stop the program; False when none was running or paused."""
        with self.lock:
            was = self.runtime_state in (RuntimeState.PLAYING, RuntimeState.PAUSED)
            self._cancel_planning()
            self.arm.halt(self.now())
            self.program_seq += 1
            self.runtime_state = RuntimeState.STOPPED
            self.executing = False
            self.sync_motion = None
            self.resume_job = None
            self.say("program stopped")
            return was

    def pause_program(self) -> bool:
        """Pause the running program (the arm stops where it is; ``play`` resumes it)."""
        with self.lock:
            if self.runtime_state != RuntimeState.PLAYING:
                return False
            if self.program_kind == "rtde_control" and self.sync_motion is not None:
                self.resume_job = self.last_job  # the interrupted move goes on after a resume
            self._cancel_planning()
            self.arm.halt(self.now())
            self.runtime_state = RuntimeState.PAUSED
            self.say("program paused")
            return True

    def resume_program(self) -> bool:
        """Resume a paused program; False when none is paused or the robot cannot move."""
        with self.lock:
            if self.runtime_state != RuntimeState.PAUSED or not self.can_move():
                return False
            self.runtime_state = RuntimeState.PLAYING
            job = self.resume_job
            self.resume_job = None
            if job is not None and self.program_kind == "rtde_control":
                t = self.now()
                q0 = self.arm.hold(t)
                again = PlanJob(
                    self.plan_gen,
                    job.cmd,
                    job.target,
                    job.speed,
                    job.accel,
                    job.is_async,
                    tuple(q0),
                    job.limits,
                    job.speed_factor,
                )
                if job.cmd in PLANNED:
                    self.planning = again
                    self._jobs.put(again)
                else:
                    self._install(again, plan_command(self.arm, again), t)
            self.say("program resumed")
            return True

    def _protective_stop(self, why: str) -> None:
        self._cancel_planning()
        self.arm.halt(self.now())
        self.safety_mode = SafetyMode.PROTECTIVE_STOP
        self.protective_since = self.now()
        if self.runtime_state == RuntimeState.PLAYING:
            self.runtime_state = RuntimeState.PAUSED
        self.executing = False
        self.sync_motion = None
        self.message("error", f"protective stop: {why}")

    def _runtime_error(self, text: str, line: int = 0, col: int = 0, kind: str = "runtime") -> None:
        """The program stops with an error, reported as the controller reports it."""
        self._cancel_planning()
        self.arm.halt(self.now())
        self.program_seq += 1
        self.runtime_state = RuntimeState.STOPPED
        self.executing = False
        self.sync_motion = None
        self.program_error = f"{kind.capitalize()} error: {text}"
        self.message("runtime_exception", self.program_error, line, col)

    def unlock_protective_stop(self) -> str:
        """``unlock protective stop``: ``"ok"``, ``"not stopped"`` or ``"too early"``."""
        with self.lock:
            if self.safety_mode != SafetyMode.PROTECTIVE_STOP:
                return "not stopped"
            if self.now() - self.protective_since < self.power.delays.unlock_after_s:
                return "too early"
            self.safety_mode = SafetyMode.NORMAL
            self.say("protective stop released")
            return "ok"

    def restart_safety(self) -> None:
        """``restart safety``: a safety fault or stop is cleared and the arm powered off."""
        with self.lock:
            self._cancel_planning()
            self.arm.halt(self.now())
            self.program_seq += 1
            self.runtime_state = RuntimeState.STOPPED
            self.safety_mode = SafetyMode.NORMAL
            self.power.power_off()
            self.say("safety restarted: robot powered off")

    def power_on(self) -> bool:
        with self.lock:
            return self.power.power_on(self.now())

    def brake_release(self) -> bool:
        with self.lock:
            return self.power.brake_release(self.now())

    def power_off(self) -> None:
        with self.lock:
            if self.runtime_state != RuntimeState.STOPPED:
                self.stop_program()
            self.arm.halt(self.now())
            self.power.power_off()
            self.say("robot powered off")

    def set_robot_mode(self, mode: RobotMode) -> None:
        with self.lock:
            self.robot_mode = mode

    def set_q(self, q: np.ndarray) -> None:
        """Put the arm at joints ``q`` at rest (tests)."""
        with self.lock:
            self._cancel_planning()
            self.arm.halt(self.now())
            self.arm.q_cmd = np.array(q, dtype=float)

    def tcp_pose_now(self) -> list[float]:
        """The controller's TCP report now (its calibrated kinematics)."""
        with self.lock:
            q = self.arm.actual(self.now())
        return pose_from_T(self.arm.robot.fk(q) @ self.arm.tcp)

    # -- fault injection -----------------------------------------------------------------
    def add_fault(self, spec: dict[str, Any]) -> None:
        """Queue a fault: ``{"kind": ..., "after_moves": n}`` or ``{"kind": ..., "after_s": s}``.

        ``restart`` takes ``down_s`` (default 2 s): how long new connections are refused.
        ``slow_program_start`` takes ``delay_s``: from now on (until ``clear``) an uploaded
        script starts running that long after it arrived, as on a busy real controller.
        """
        kind = spec.get("kind")
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
        if kind == "restart":
            down = spec.get("down_s", RESTART_DOWN_S)
            if not isinstance(down, int | float) or not 0.0 <= float(down) <= 600.0:
                raise ValueError("restart: down_s must be a number of seconds in 0..600")
        if kind == "joint_speed_limit":
            scale = spec.get("scale", 0.05)
            if not isinstance(scale, int | float) or not 0.001 <= float(scale) <= 1.0:
                raise ValueError("joint_speed_limit: scale must be a number in 0.001..1")
        if kind == "slow_program_start":
            delay = spec.get("delay_s")
            if not isinstance(delay, int | float) or not 0.0 <= float(delay) <= 60.0:
                raise ValueError("slow_program_start: delay_s must be a number of seconds in 0..60")
        with self.lock:
            spec = dict(spec)
            if "after_s" in spec:
                spec["at_t"] = self.now() + float(spec["after_s"])
            if "after_moves" in spec:
                spec["at_move"] = self.n_moves + int(spec["after_moves"])
            if "at_t" not in spec and "at_move" not in spec:
                self._apply_fault(spec)
            else:
                self.pending_faults.append(spec)

    def _fire_due_faults(self, t: float) -> None:
        for f in [f for f in self.pending_faults if f.get("at_t", math.inf) <= t]:
            self.pending_faults.remove(f)
            self._apply_fault(f)

    def _fire_move_faults(self) -> None:
        for f in [f for f in self.pending_faults if f.get("at_move", math.inf) <= self.n_moves]:
            self.pending_faults.remove(f)
            self._apply_fault(f)

    def _apply_fault(self, spec: dict[str, Any]) -> None:
        kind = spec["kind"]
        self.say(f"fault injected: {kind}")
        if kind == "protective_stop":
            self._protective_stop("injected")
        elif kind == "emergency_stop":
            self._cancel_planning()
            self.arm.halt(self.now())
            self.safety_mode = SafetyMode.ROBOT_EMERGENCY_STOP
            self.runtime_state = RuntimeState.STOPPED
        elif kind == "program_stop":
            self.stop_program()
        elif kind == "freeze_stream":
            t = self.now()
            self.frozen = self._complete(self._copy_state(t))
        elif kind == "drop_connection":
            self.refuse_connections = bool(spec.get("refuse", True))
            self.drop_connections()
        elif kind == "restart":
            self._restart(float(spec.get("down_s", RESTART_DOWN_S)))
        elif kind == "slow_program_start":
            self.program_start_delay = float(spec["delay_s"])
        elif kind == "power_off":  # the arm loses power (someone pressed power off)
            self.power_off()
        elif kind == "pause":  # the program paused from the dashboard or the pendant
            self.note_stop("dashboard pause")
            self.pause_program()
        elif kind == "joint_speed_limit":  # the safety limits drop: the next move is too fast
            self.limit_scale = float(spec.get("scale", 0.05))
        elif kind == "unknown_command":  # the next command is one this controller lacks
            self.unknown_command_pending = True
        elif kind == "clear":  # back to a healthy controller (tests): faults and stops gone
            self.frozen = None
            self.refuse_connections = False
            self.refuse_until = 0.0
            self.pending_faults.clear()
            self.program_start_delay = 0.0
            self.limit_scale = 1.0
            self.unknown_command_pending = False
            self.safety_mode = SafetyMode.NORMAL
            self.robot_mode = RobotMode.RUNNING

    def _restart(self, down_s: float) -> None:
        """A controller restart: links dropped, refused for ``down_s``, everything reset.

        The program is stopped, the arm halted, modes RUNNING / NORMAL, the register bank
        cleared.  The controller clock keeps running (a real one restarts it at 0).
        """
        self._cancel_planning()
        self.arm.halt(self.now())
        self.n_restarts += 1
        self.refuse_until = time.monotonic() + down_s
        self.frozen = None
        self.robot_mode = RobotMode.RUNNING
        self.safety_mode = SafetyMode.NORMAL
        self.program_seq += 1
        self.program_kind = None
        self.limit_scale = 1.0
        self.unknown_command_pending = False
        self.runtime_state = RuntimeState.STOPPED
        self.inputs = {}
        self.outputs = {"output_int_register_0": 0}
        self.io.reset(self.cycle_time(self.now()))  # the outputs go low as the box reboots
        self.executing = False
        self.current_cmd = CMD_NONE
        self.sync_motion = None
        self.async_motion = None
        self.async_id = 0
        self.async_writes = 0
        self.drop_connections()

    def drop_connections(self) -> None:
        """Close every client connection (RTDE, dashboard, script; not the control channel)."""
        with self.lock:
            conns, self.connections = self.connections, []
        for s in conns:
            close_socket(s)

    def track(self, conn: socket.socket) -> bool:
        """Register a new client connection; False (and closed) while connections are refused."""
        with self.lock:
            if not self.accepting():
                close_socket(conn)
                return False
            self.connections.append(conn)
            return True

    def untrack(self, conn: socket.socket) -> None:
        with self.lock:
            if conn in self.connections:
                self.connections.remove(conn)


def close_socket(s: socket.socket) -> None:
    """Shut down and close, ignoring a socket that is already gone."""
    try:
        s.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    try:
        s.close()
    except OSError:
        pass
