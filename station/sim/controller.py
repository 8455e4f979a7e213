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

from quickhealth.station.hardware.urtypes import (
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
    limit_violation,
    linear_path,
    pose_from_T,
)
from .wire import CB3_VERSION, CONTROL_PORT, HOST, max_stream_hz

# Register commands of the rtde_control script (rtde.h).
CMD_NONE = 0
CMD_MOVEJ = 1
CMD_MOVEJ_IK = 2
CMD_MOVEL = 3
CMD_MOVEL_FK = 4
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_STOP_SCRIPT = 255
MOVES = frozenset({CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK})
PLANNED = frozenset({CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK})  # planned in the planner thread

FAULT_KINDS = (
    "protective_stop",
    "emergency_stop",
    "program_stop",
    "freeze_stream",
    "drop_connection",
    "restart",
    "slow_program_start",
    "clear",
)

RESTART_DOWN_S = 2.0  # default time a restarting controller refuses connections


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


def plan_command(arm: Arm, job: PlanJob) -> Path | str:
    """The path of an accepted motion command, or an error text (pure; runs without the lock).

    A path that leaves the arm's joint limits is refused (an error text: protective stop)."""
    path = _plan_path(arm, job)
    if isinstance(path, str):
        return path
    why = limit_violation(arm.robot, path.q)
    return path if why is None else f"{_NAMES.get(job.cmd, 'move')}: {why}"


_NAMES = {
    CMD_MOVEJ: "moveJ",
    CMD_MOVEJ_IK: "moveJ_IK",
    CMD_MOVEL: "moveL",
    CMD_MOVEL_FK: "moveL_FK",
}


def _plan_path(arm: Arm, job: PlanJob) -> Path | str:
    q0 = np.asarray(job.q0)
    target = np.asarray(job.target)
    if job.cmd == CMD_MOVEL_FK:
        T = arm.robot.fk(target) @ arm.tcp
        return linear_path(arm.robot, arm.tcp, q0, T, q_goal=target)
    if job.cmd == CMD_MOVEL:
        return linear_path(arm.robot, arm.tcp, q0, T_from_pose(target))
    if job.cmd == CMD_MOVEJ_IK:
        q, ok = ik_near(arm.robot, arm.tcp, T_from_pose(target), q0)
        if not ok:
            return "moveJ_IK: no inverse kinematics solution"
        return joint_path(q0, q)
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
    ) -> None:
        self.arm = arm
        self.host = host  # the loopback address every server listens on
        self.control_port = control_port
        self.verbose = verbose
        self.version = tuple(version)
        self.lock = threading.RLock()
        self.t_start = time.monotonic()
        self.robot_mode = RobotMode.RUNNING
        self.safety_mode = SafetyMode.NORMAL
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
        """Controller time (the RTDE ``timestamp``), s."""
        return time.monotonic() - self.t_start

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

    def snapshot(self) -> dict[str, Any]:
        """Every output field's current value (the frozen copy while the stream is frozen).

        The lock is held only to advance the emulated script by one cycle (never planning)
        and copy the state; the TCP poses are computed outside it.
        """
        with self.lock:
            if self.frozen is not None:
                return self.frozen
            t = self.now()
            self._step(t)
            s = self._copy_state(t)
        return self._complete(s)

    def _copy_state(self, t: float) -> dict[str, Any]:
        q_target, _ = self.arm.target(t)
        s: dict[str, Any] = dict(self.outputs)
        s.update(
            timestamp=t,
            target_q=q_target,
            actual_q=self.arm.actual(t),
            robot_mode=int(self.robot_mode),
            safety_mode=int(self.safety_mode),
            safety_status=int(self.safety_mode),
            runtime_state=int(self.runtime_state),
            robot_status_bits=self.robot_status_bits(),
            safety_status_bits=self.safety_status_bits(),
        )
        return s

    def _complete(self, s: dict[str, Any]) -> dict[str, Any]:
        """The derived and constant fields of a copied state (no lock needed)."""
        q, q_target = list(s["actual_q"]), list(s["target_q"])
        cached = self._target_pose  # the target rests most of the time: one FK saved
        if cached[0] != q_target:
            cached = self._target_pose = (q_target, self.arm.tcp_pose(q_target))
        s.update(
            target_q=q_target,
            actual_q=q,
            actual_TCP_pose=self.arm.tcp_pose(q),
            target_TCP_pose=list(cached[1]),
            joint_mode=[253] * 6,
            speed_scaling=1.0,
            target_speed_fraction=1.0,
            joint_temperatures=[31.0] * 6,
            actual_main_voltage=48.0,
            actual_robot_voltage=48.0,
            tool_temperature=33.0,
        )
        return s

    def set_inputs(self, values: dict[str, Any]) -> None:
        """Merge a client's input-recipe packet into the register bank and run one cycle."""
        with self.lock:
            self.inputs.update(values)
            self._step(self.now())

    # -- the script main loop (register protocol) --------------------------------------
    def _step(self, t: float) -> None:
        """Advance the emulated ``rtde_control`` script by one cycle (microseconds)."""
        self._fire_due_faults(t)
        self._report_async(t)
        if self.runtime_state != RuntimeState.PLAYING or self.safety_mode != SafetyMode.NORMAL:
            return
        cmd = int(self.inputs.get("input_int_register_0", 0))
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
        d = [float(self.inputs.get(f"input_double_register_{i}", 0.0)) for i in range(8)]
        is_async = int(self.inputs.get("input_int_register_1", 0)) == 1
        if cmd in MOVES:
            self.n_moves += 1
            self._fire_move_faults()
            if self.safety_mode != SafetyMode.NORMAL or self.runtime_state != RuntimeState.PLAYING:
                return
            k = self.speed_factor  # tests run the arm faster than life
            speed, accel = max(d[6], 1e-3) * k, max(d[7], 1e-3) * k * k
            if not all(math.isfinite(v) for v in d):
                self.say(f"cmd {cmd}: non-finite argument refused")
                self._protective_stop("non-finite move argument")
                return
            self._cancel_planning()  # an async move still being planned is superseded
            q0 = self.arm.hold(t)
            job = PlanJob(self.plan_gen, cmd, tuple(d[:6]), speed, accel, is_async, tuple(q0))
            self.async_motion = None
            if is_async:
                self.async_id = (self.async_id + 1) & 0x7F
                self.outputs["output_int_register_0"] = 2
            if cmd in PLANNED:
                self.planning = job
                self._report_async(t)
                self._jobs.put(job)
            else:  # moveJ: nothing to plan but the limits
                self._install(job, plan_command(self.arm, job), t)
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
        else:  # everything else is acknowledged without effect
            self.outputs["output_int_register_0"] = 2

    def _install(self, job: PlanJob, path: Path | str, t: float) -> None:
        """Start the planned motion of ``job`` at ``t`` (under the lock)."""
        self.planning = None
        if isinstance(path, str):
            if job.is_async:
                self.outputs["output_int_register_2"] = -1
            self._protective_stop(path)
            return
        qd_max = self.arm.robot.qd_max  # the arm's joint speed limits, at the simulated clock
        m = Motion.timed(
            path, job.speed, job.accel, t, None if qd_max is None else qd_max * self.speed_factor
        )
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
    def start_program(self) -> None:
        with self.lock:
            if self.safety_mode != SafetyMode.NORMAL:
                self.say("program start refused: safety stop active")
                return
            self._cancel_planning()
            self.inputs["input_int_register_0"] = 0
            self.executing = False
            self.sync_motion = None
            self.runtime_state = RuntimeState.PLAYING
            self.outputs["output_int_register_0"] = 1
            self.outputs["output_int_register_2"] = -1
            self.say("program running")

    def note_stop(self, how: str) -> None:
        """Record a stop command as received now (for the clients' stop-latency figures)."""
        with self.lock:
            self.stops.append((time.monotonic(), how))
            del self.stops[:-100]

    def stop_program(self) -> None:
        with self.lock:
            self._cancel_planning()
            self.arm.halt(self.now())
            self.runtime_state = RuntimeState.STOPPED
            self.executing = False
            self.sync_motion = None
            self.say("program stopped")

    def _protective_stop(self, why: str) -> None:
        self._cancel_planning()
        self.arm.halt(self.now())
        self.safety_mode = SafetyMode.PROTECTIVE_STOP
        self.runtime_state = RuntimeState.PAUSED
        self.executing = False
        self.sync_motion = None
        self.say(f"protective stop: {why}")

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if self.safety_mode != SafetyMode.PROTECTIVE_STOP:
                return False
            self.safety_mode = SafetyMode.NORMAL
            self.runtime_state = RuntimeState.STOPPED
            self.say("protective stop released")
            return True

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
        """The controller's TCP report now (nominal kinematics)."""
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
        elif kind == "clear":  # back to a healthy controller (tests): faults and stops gone
            self.frozen = None
            self.refuse_connections = False
            self.refuse_until = 0.0
            self.pending_faults.clear()
            self.program_start_delay = 0.0
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
        self.runtime_state = RuntimeState.STOPPED
        self.inputs = {}
        self.outputs = {"output_int_register_0": 0}
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
