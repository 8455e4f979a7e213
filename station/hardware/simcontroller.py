"""UR controller simulator: the RTDE, dashboard and script servers of a UR CB3 controller.

The unmodified ur-rtde client (``rtde_receive``, ``rtde_control``) connects to it exactly as to
a real controller; the behaviour follows ``notes/ur-rtde.md`` (ports, handshake, recipes and
the register command protocol of the uploaded ``rtde_control`` script).

Servers, all on 127.0.0.1 only
------------------------------
- 30004 RTDE: protocol v2 handshake, output recipes streamed at the requested rate, input
  recipes merged into one register bank.
- 29999 dashboard: banner, ``PolyscopeVersion``, ``robotmode``, ``safetystatus``, ``stop``,
  ``play``, ``unlock protective stop``, ``power on``, ``brake release`` …
- 30003 script: accepts a URScript program (never interpreted: the register protocol of the
  ``rtde_control`` script is emulated instead) and starts it.
- control port (default 30090): JSON lines for tests and the simulated cell, see
  :class:`SimControllerHandle` — fault injection (``protective_stop``, ``program_stop``,
  ``drop_connection``, ``freeze_stream``), the true target pose of the arm for the simulated
  cameras, and ``shutdown``.

Motion
------
moveJ: synchronised trapezoidal joint profile (speed rad/s, acceleration rad/s²).  moveL and
moveL_FK: straight line of the TCP (position linear, orientation along the geodesic) sampled
and solved by damped least-squares IK from the previous sample.  After every stop the actual
joints ring with a small damped oscillation (amplitude ~1e-4 rad, time constant 60 ms) plus
encoder noise (1 µrad), so settle detection on the joint stream has something real to detect.

The arm is a :class:`Arm`: nominal UR5 kinematics for the controller's own TCP report (a real
controller only knows its nominal model), and a ``truth`` callable ``q -> T_instr_flange`` (the
digital twin) for where the flange really is.

Run ``python -m quickhealth.station.hardware.simcontroller --help``.
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from quickhealth.identify.robot import RobotModel
from quickhealth.identify.transforms import exp_so3, log_so3, make_T

HOST = "127.0.0.1"
RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
CONTROL_PORT = 30090

CONTROLLER_VERSION = (3, 15, 7, 106331)  # CB3: the client streams at 125 Hz

# Robot / safety / runtime vocabularies (UR's numbering).
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_IDLE = 5
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL = 1
SAFETY_PROTECTIVE_STOP = 3
SAFETY_ROBOT_EMERGENCY_STOP = 7
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 3

# Register commands of the rtde_control script (rtde.h).
CMD_NONE = 0
CMD_MOVEJ = 1
CMD_MOVEJ_IK = 2
CMD_MOVEL = 3
CMD_MOVEL_FK = 4
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_STOP_SCRIPT = 255
_MOVES = {CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK}

# RTDE packet types.
P_REQUEST_PROTOCOL_VERSION = ord("V")
P_GET_URCONTROL_VERSION = ord("v")
P_TEXT_MESSAGE = ord("M")
P_DATA = ord("U")
P_SETUP_OUTPUTS = ord("O")
P_SETUP_INPUTS = ord("I")
P_START = ord("S")
P_PAUSE = ord("P")

# RTDE field types as the client packs them (its own table, robot_state.cpp).
_TYPE_FMT = {
    "DOUBLE": "d",
    "VECTOR6D": "6d",
    "VECTOR3D": "3d",
    "UINT64": "Q",
    "UINT32": "I",
    "INT32": "i",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
    "UINT8": "B",
    "BOOL": "?",
}
_FIXED_TYPES = {
    "timestamp": "DOUBLE",
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tool_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "script_control_line": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
}
_VECTOR6D_PREFIXES = (
    "target_q",
    "target_qd",
    "target_qdd",
    "target_current",
    "target_moment",
    "actual_q",
    "actual_qd",
    "actual_qdd",
    "actual_current",
    "actual_moment",
    "joint_control_output",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "actual_TCP_force",
    "target_TCP_pose",
    "target_TCP_speed",
    "joint_temperatures",
    "actual_joint_voltage",
    "actual_current_as_torque",
    "external_force_torque",
)


def rtde_type(name: str) -> str | None:
    """RTDE type of a field name, or None when the controller does not know it."""
    if name in _FIXED_TYPES:
        return _FIXED_TYPES[name]
    if name in _VECTOR6D_PREFIXES:
        return "VECTOR6D"
    for prefix, typ in (
        ("output_int_register_", "INT32"),
        ("input_int_register_", "INT32"),
        ("output_double_register_", "DOUBLE"),
        ("input_double_register_", "DOUBLE"),
        ("output_bit_register_", "BOOL"),
        ("input_bit_register_", "BOOL"),
    ):
        if name.startswith(prefix):
            idx = name[len(prefix) :]
            if idx.isdigit() and int(idx) < 48:
                return typ
            return None
    if name.startswith(("standard_analog_input", "standard_analog_output", "tool_analog_input")):
        return "DOUBLE"
    return None


# ---------------------------------------------------------------------------------------
# The arm: kinematics and motion
# ---------------------------------------------------------------------------------------


def pose_from_T(T: np.ndarray) -> list[float]:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) of a transform."""
    return [*map(float, T[:3, 3]), *map(float, log_so3(T[:3, :3]))]


def T_from_pose(p: Any) -> np.ndarray:
    """Transform from a UR pose vector."""
    p = np.asarray(p, dtype=float)
    return make_T(exp_so3(p[3:6]), p[:3])


def ik_dls(
    robot: RobotModel,
    T_goal: np.ndarray,
    q0: np.ndarray,
    *,
    iters: int = 60,
    tol: float = 1e-10,
    damping: float = 1e-4,
) -> tuple[np.ndarray, bool]:
    """Damped least-squares IK of ``T_base_flange = T_goal`` from ``q0``; returns (q, converged)."""
    q = np.array(q0, dtype=float)
    eps = 1e-7
    for _ in range(iters):
        Q = np.vstack([q, q + eps * np.eye(len(q))])
        T = robot.fk(Q)
        err = _pose_error(T_goal, T[0])
        if float(err @ err) < tol**2:
            return q, True
        J = np.stack([_pose_error(T[i + 1], T[0]) for i in range(len(q))], axis=1) / eps
        dq = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), err)
        q = q + dq
    err = _pose_error(T_goal, robot.fk(q))
    return q, bool(np.linalg.norm(err) < 1e-7)


def _pose_error(T_goal: np.ndarray, T: np.ndarray) -> np.ndarray:
    dp = T_goal[:3, 3] - T[:3, 3]
    dr = log_so3(T_goal[:3, :3] @ T[:3, :3].T)
    return np.concatenate([dp, dr])


def trapezoid_duration(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest trapezoidal (or triangular) profile over ``distance``."""
    if distance <= 0.0:
        return 0.0
    if distance <= speed * speed / accel:
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


def trapezoid_fraction(t: float, duration: float, distance: float, accel: float) -> float:
    """Fraction of the path covered at time ``t`` of a trapezoidal profile."""
    if duration <= 0.0 or t >= duration:
        return 1.0
    if t <= 0.0:
        return 0.0
    # Recover the cruise speed from the duration: D = v (T - v/a)  ->  v = (aT - sqrt(a²T² - 4aD))/2
    disc = accel * accel * duration * duration - 4.0 * accel * distance
    vmax = (accel * duration - math.sqrt(max(disc, 0.0))) / 2.0
    ta = vmax / accel
    if t < ta:
        s = 0.5 * accel * t * t
    elif t < duration - ta:
        s = 0.5 * accel * ta * ta + vmax * (t - ta)
    else:
        tr = duration - t
        s = distance - 0.5 * accel * tr * tr
    return min(max(s / distance, 0.0), 1.0)


@dataclass
class Motion:
    """One commanded motion: a joint path sampled over normalised path parameter ``s``."""

    t0: float
    duration: float
    path: np.ndarray  # (m, 6) joint samples for s = linspace(0, 1, m)
    distance: float  # path length in the profile's own unit
    accel: float

    def q_at(self, t: float) -> tuple[np.ndarray, bool]:
        """Joint target at time ``t`` and whether the motion is finished."""
        f = trapezoid_fraction(t - self.t0, self.duration, self.distance, self.accel)
        m = self.path.shape[0]
        x = f * (m - 1)
        i = min(int(x), m - 2) if m > 1 else 0
        if m == 1:
            return self.path[0].copy(), True
        w = x - i
        return (1.0 - w) * self.path[i] + w * self.path[i + 1], f >= 1.0


Truth = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (q, approach) -> T_instr_target


class Arm:
    """Simulated joint state with timed motion, ringing after stops and encoder noise."""

    RING_AMPLITUDE = 1.5e-4  # rad
    RING_TAU = 0.06  # s
    RING_FREQ = 8.0  # Hz
    NOISE = 1e-6  # rad

    def __init__(self, robot: RobotModel, q0: np.ndarray, truth: Truth | None = None) -> None:
        self.robot = robot
        self.truth = truth
        self.q_cmd = np.array(q0, dtype=float)
        self.motion: Motion | None = None
        self.stop_time = -10.0
        self.ring_dir = np.zeros(6)
        self.rng = np.random.default_rng(7)
        self.lock = threading.RLock()
        self.tcp = np.eye(4)
        self.approach = np.ones(len(q0))  # direction each joint last moved in (+1 / -1)

    def target(self, now: float) -> tuple[np.ndarray, bool]:
        """Commanded joints now and whether the current motion (if any) is finished."""
        with self.lock:
            if self.motion is None:
                return self.q_cmd.copy(), True
            q, done = self.motion.q_at(now)
            if done:
                self.q_cmd = self.motion.path[-1].copy()
                self._start_ringing(now, self.motion)
                self.motion = None
                return self.q_cmd.copy(), True
            return q, False

    def _set_approach(self, q0: np.ndarray, q1: np.ndarray) -> None:
        d = np.asarray(q1) - np.asarray(q0)
        self.approach = np.where(np.abs(d) > 1e-9, np.sign(d), self.approach)

    def _start_ringing(self, now: float, motion: Motion) -> None:
        d = motion.path[-1] - motion.path[max(0, motion.path.shape[0] - 2)]
        n = np.linalg.norm(d)
        self.ring_dir = d / n if n > 0 else np.zeros(6)
        self.stop_time = now

    def actual(self, now: float) -> np.ndarray:
        """Actual (encoder) joints: the target plus post-stop ringing and noise."""
        q, _ = self.target(now)
        dt = now - self.stop_time
        if 0.0 <= dt < 8 * self.RING_TAU:
            q = q + self.ring_dir * (
                self.RING_AMPLITUDE
                * math.exp(-dt / self.RING_TAU)
                * math.sin(2 * math.pi * self.RING_FREQ * dt)
            )
        return q + self.rng.normal(0.0, self.NOISE, 6)

    def moving(self, now: float) -> bool:
        """True while a motion runs."""
        return not self.target(now)[1]

    def move_joint(self, q: np.ndarray, speed: float, accel: float, now: float) -> Motion:
        """Start a synchronised trapezoidal joint move."""
        with self.lock:
            q0, _ = self.target(now)
            self.motion = None
            self.q_cmd = q0
            D = float(np.max(np.abs(q - q0)))
            dur = trapezoid_duration(D, speed, accel)
            m = Motion(now, dur, np.stack([q0, np.asarray(q, float)]), max(D, 1e-12), accel)
            self._set_approach(q0, q)
            self.motion = m
            return m

    def move_linear(
        self,
        T_goal: np.ndarray,
        speed: float,
        accel: float,
        now: float,
        q_goal: np.ndarray | None = None,
    ) -> Motion:
        """Start a straight-line TCP move to ``T_goal`` (base frame, TCP).

        ``q_goal`` (moveL_FK): the joints the move must end at (the same TCP pose).
        """
        with self.lock:
            q0, _ = self.target(now)
            self.motion = None
            self.q_cmd = q0
            T0 = self.robot.fk(q0) @ self.tcp
            dp = T_goal[:3, 3] - T0[:3, 3]
            dr = log_so3(T_goal[:3, :3] @ T0[:3, :3].T)
            L = float(np.linalg.norm(dp))
            n = int(np.clip(max(L / 0.005, np.linalg.norm(dr) / 0.02), 2, 400))
            s = np.linspace(0.0, 1.0, n)
            path = [q0]
            q = q0
            tcp_inv = np.linalg.inv(self.tcp)
            for si in s[1:]:
                T = make_T(exp_so3(si * dr) @ T0[:3, :3], T0[:3, 3] + si * dp)
                q, _ = ik_dls(self.robot, T @ tcp_inv, q, iters=30)
                path.append(q)
            path_a = np.stack(path)
            if q_goal is not None and np.max(np.abs(path_a[-1] - q_goal)) < 1e-3:
                path_a[-1] = q_goal
            # Distance in metres (rotation-only moves: 0.1 m per rad).
            D = max(L, 0.1 * float(np.linalg.norm(dr)), 1e-12)
            dur = trapezoid_duration(D, speed, accel)
            m = Motion(now, dur, path_a, D, accel)
            self._set_approach(path_a[-2] if len(path_a) > 1 else q0, path_a[-1])
            self.motion = m
            return m

    def halt(self, now: float) -> None:
        """Stop where the arm is now (protective stop, stopJ)."""
        with self.lock:
            q, done = self.target(now)
            if not done and self.motion is not None:
                self._start_ringing(now, self.motion)
            self.motion = None
            self.q_cmd = q

    def tcp_pose(self, q: np.ndarray) -> list[float]:
        """The controller's TCP report: nominal kinematics of the actual joints."""
        return pose_from_T(self.robot.fk(q) @ self.tcp)


# ---------------------------------------------------------------------------------------
# The controller state and its servers
# ---------------------------------------------------------------------------------------


class Controller:
    """Controller state shared by the RTDE, dashboard, script and control servers."""

    def __init__(
        self, arm: Arm, *, control_port: int = CONTROL_PORT, verbose: bool = False
    ) -> None:
        self.arm = arm
        self.control_port = control_port
        self.verbose = verbose
        self.lock = threading.RLock()
        self.t_start = time.monotonic()
        self.robot_mode = ROBOT_MODE_RUNNING
        self.safety_mode = SAFETY_NORMAL
        self.runtime_state = RUNTIME_STOPPED
        self.inputs: dict[str, Any] = {}
        self.outputs: dict[str, Any] = {"output_int_register_0": 0}
        self.executing = False
        self.current_cmd = CMD_NONE
        self.sync_motion: Motion | None = None
        self.async_motion: Motion | None = None
        self.async_id = 0
        self.async_writes = 0
        self.frozen: dict[str, Any] | None = None  # last packed state while the stream is frozen
        self.refuse_connections = False
        self.connections: list[socket.socket] = []
        self.listeners: list[socket.socket] = []
        self.pending_faults: list[dict[str, Any]] = []
        self.n_moves = 0
        self.log: list[str] = []
        self.stop_event = threading.Event()
        self.world: Any = None  # the simulated cell's ground truth (world.SimWorld)
        self.speed_factor = 1.0

    # -- time and state -------------------------------------------------------------
    def now(self) -> float:
        return time.monotonic() - self.t_start

    def say(self, msg: str) -> None:
        self.log.append(f"{self.now():8.3f} {msg}")
        if self.verbose:
            sys.stderr.write(f"simcontroller: {msg}\n")

    def safety_status_bits(self) -> int:
        bits = {
            SAFETY_NORMAL: 1 << 0,
            SAFETY_PROTECTIVE_STOP: 1 << 2,
            SAFETY_ROBOT_EMERGENCY_STOP: (1 << 6) | (1 << 7),
        }
        return bits.get(self.safety_mode, 0)

    def robot_status_bits(self) -> int:
        power = 1 if self.robot_mode in (ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING) else 0
        running = 2 if self.runtime_state == RUNTIME_PLAYING else 0
        return power | running

    def snapshot(self) -> dict[str, Any]:
        """Every output field's current value (the frozen copy while the stream is frozen)."""
        with self.lock:
            if self.frozen is not None:
                return self.frozen
            t = self.now()
            self._step(t)
            q_target, _ = self.arm.target(t)
            q = self.arm.actual(t)
            s: dict[str, Any] = dict(self.outputs)
            s.update(
                timestamp=t,
                target_q=list(q_target),
                actual_q=list(q),
                actual_TCP_pose=self.arm.tcp_pose(q),
                target_TCP_pose=self.arm.tcp_pose(q_target),
                robot_mode=self.robot_mode,
                safety_mode=self.safety_mode,
                safety_status=self.safety_mode,
                runtime_state=self.runtime_state,
                robot_status_bits=self.robot_status_bits(),
                safety_status_bits=self.safety_status_bits(),
                joint_mode=[253] * 6,
                speed_scaling=1.0,
                target_speed_fraction=1.0,
                joint_temperatures=[31.0] * 6,
                actual_main_voltage=48.0,
                actual_robot_voltage=48.0,
                tool_temperature=33.0,
            )
            return s

    # -- the script main loop (register protocol) --------------------------------------
    def _step(self, t: float) -> None:
        """Advance the emulated ``rtde_control`` script by one cycle."""
        self._fire_due_faults(t)
        if self.async_motion is not None:
            _, done = self.async_motion.q_at(t)
            if done or self.arm.motion is not self.async_motion:
                # Finished: operation id and write counter kept, the running bit (15) cleared.
                self.async_writes = (self.async_writes + 1) & 0xFF
                self.outputs["output_int_register_2"] = ((self.async_id & 0x7F) << 24) | (
                    self.async_writes << 16
                )
                self.async_motion = None
            else:
                f = trapezoid_fraction(
                    t - self.async_motion.t0,
                    self.async_motion.duration,
                    self.async_motion.distance,
                    self.async_motion.accel,
                )
                self.async_writes = (self.async_writes + 1) & 0xFF
                self.outputs["output_int_register_2"] = (
                    ((self.async_id & 0x7F) << 24)
                    | (self.async_writes << 16)
                    | (1 << 15)
                    | int(f * 0x7FFF)
                )
        if self.runtime_state != RUNTIME_PLAYING or self.safety_mode != SAFETY_NORMAL:
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

    def _execute(self, cmd: int, t: float) -> None:
        d = [float(self.inputs.get(f"input_double_register_{i}", 0.0)) for i in range(8)]
        is_async = int(self.inputs.get("input_int_register_1", 0)) == 1
        if cmd in _MOVES:
            self.n_moves += 1
            self._fire_move_faults()
            if self.safety_mode != SAFETY_NORMAL or self.runtime_state != RUNTIME_PLAYING:
                return
            target = np.array(d[:6])
            k = self.speed_factor  # tests run the arm faster than life
            speed, accel = max(d[6], 1e-3) * k, max(d[7], 1e-3) * k * k
            if not all(math.isfinite(v) for v in d):
                self.say(f"cmd {cmd}: non-finite argument refused")
                self._protective_stop("non-finite move argument")
                return
            if cmd == CMD_MOVEJ:
                m = self.arm.move_joint(target, speed, accel, t)
            elif cmd == CMD_MOVEL_FK:
                T = self.arm.robot.fk(target) @ self.arm.tcp
                m = self.arm.move_linear(T, speed, accel, t, q_goal=target)
            elif cmd == CMD_MOVEL:
                m = self.arm.move_linear(T_from_pose(target), speed, accel, t)
            else:  # MOVEJ_IK
                q, ok = ik_dls(
                    self.arm.robot,
                    T_from_pose(target) @ np.linalg.inv(self.arm.tcp),
                    self.arm.q_cmd,
                )
                if not ok:
                    self._protective_stop("moveJ_IK: no inverse kinematics solution")
                    return
                m = self.arm.move_joint(q, speed, accel, t)
            self.say(f"cmd {cmd} {'async' if is_async else 'sync'} {m.duration:.3f} s")
            if is_async:
                self.async_id = (self.async_id + 1) & 0x7F
                self.async_motion = m
                self.outputs["output_int_register_0"] = 2
            else:
                self.sync_motion = m
        elif cmd in (CMD_STOPJ, CMD_STOPL):
            self.arm.halt(t)
            self.async_motion = None
            self.outputs["output_int_register_2"] = -1
            self.outputs["output_int_register_0"] = 2
        elif cmd == CMD_STOP_SCRIPT:
            self.arm.halt(t)
            self.runtime_state = RUNTIME_STOPPED
            self.executing = False
            self.say("script stopped")
        else:  # everything else is acknowledged without effect
            self.outputs["output_int_register_0"] = 2

    # -- program and safety --------------------------------------------------------------
    def start_program(self) -> None:
        with self.lock:
            if self.safety_mode != SAFETY_NORMAL:
                self.say("program start refused: safety stop active")
                return
            self.inputs["input_int_register_0"] = 0
            self.executing = False
            self.sync_motion = None
            self.runtime_state = RUNTIME_PLAYING
            self.outputs["output_int_register_0"] = 1
            self.outputs["output_int_register_2"] = -1
            self.say("program running")

    def stop_program(self) -> None:
        with self.lock:
            self.arm.halt(self.now())
            self.runtime_state = RUNTIME_STOPPED
            self.executing = False
            self.sync_motion = None
            self.say("program stopped")

    def _protective_stop(self, why: str) -> None:
        self.arm.halt(self.now())
        self.safety_mode = SAFETY_PROTECTIVE_STOP
        self.runtime_state = RUNTIME_PAUSED
        self.executing = False
        self.sync_motion = None
        self.say(f"protective stop: {why}")

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if self.safety_mode != SAFETY_PROTECTIVE_STOP:
                return False
            self.safety_mode = SAFETY_NORMAL
            self.runtime_state = RUNTIME_STOPPED
            self.say("protective stop released")
            return True

    # -- fault injection -----------------------------------------------------------------
    def add_fault(self, spec: dict[str, Any]) -> None:
        """Queue a fault: ``{"kind": ..., "after_moves": n}`` or ``{"kind": ..., "after_s": s}``."""
        kind = spec.get("kind")
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
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
            self.arm.halt(self.now())
            self.safety_mode = SAFETY_ROBOT_EMERGENCY_STOP
            self.runtime_state = RUNTIME_STOPPED
        elif kind == "program_stop":
            self.stop_program()
        elif kind == "freeze_stream":
            self.frozen = None
            self.frozen = self.snapshot()
        elif kind == "drop_connection":
            self.refuse_connections = bool(spec.get("refuse", True))
            for s in list(self.connections):
                _close(s)
            self.connections.clear()
        elif kind == "clear":  # back to a healthy controller (tests): faults and stops gone
            self.frozen = None
            self.refuse_connections = False
            self.pending_faults.clear()
            self.safety_mode = SAFETY_NORMAL
            self.robot_mode = ROBOT_MODE_RUNNING


FAULT_KINDS = (
    "protective_stop",
    "emergency_stop",
    "program_stop",
    "freeze_stream",
    "drop_connection",
    "clear",
)


def _close(s: socket.socket) -> None:
    try:
        s.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    try:
        s.close()
    except OSError:
        pass


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed")
        buf += chunk
    return buf


def _packet(ptype: int, payload: bytes) -> bytes:
    return struct.pack(">HB", len(payload) + 3, ptype) + payload


class _Recipe:
    def __init__(self, rid: int, names: list[str], types: list[str]) -> None:
        self.id = rid
        self.names = names
        self.types = types
        self.fmt = ">B" + "".join(_TYPE_FMT[t] for t in types)
        self.struct = struct.Struct(self.fmt)

    def pack(self, state: dict[str, Any]) -> bytes:
        vals: list[Any] = [self.id]
        for n, t in zip(self.names, self.types, strict=True):
            v = state.get(n)
            if t.startswith("VECTOR"):
                k = 3 if t == "VECTOR3D" else 6
                vals.extend(list(v) if v is not None else [0] * k)
            elif t in ("DOUBLE",):
                vals.append(float(v) if v is not None else 0.0)
            elif t == "BOOL":
                vals.append(bool(v))
            else:
                vals.append(int(v) if v is not None else 0)
        return self.struct.pack(*vals)

    def unpack(self, payload: bytes) -> dict[str, Any]:
        vals = list(self.struct.unpack(payload[: self.struct.size]))[1:]
        out: dict[str, Any] = {}
        for n, t in zip(self.names, self.types, strict=True):
            if t.startswith("VECTOR"):
                k = 3 if t == "VECTOR3D" else 6
                out[n], vals = vals[:k], vals[k:]
            else:
                out[n] = vals.pop(0)
        return out


class _RtdeSession:
    """One RTDE client connection."""

    def __init__(self, ctrl: Controller, conn: socket.socket) -> None:
        self.ctrl = ctrl
        self.conn = conn
        self.outputs: list[_Recipe] = []
        self.inputs: dict[int, _Recipe] = {}
        self.next_output_id = 1  # output and input recipes are numbered separately:
        self.next_input_id = 1  # the client hard-codes input recipe ids 1, 2, 3 …
        self.freq = 125.0
        self.streaming = threading.Event()
        self.send_lock = threading.Lock()
        self.closed = False

    def send(self, ptype: int, payload: bytes) -> None:
        with self.send_lock:
            self.conn.sendall(_packet(ptype, payload))

    def serve(self) -> None:
        threading.Thread(target=self._stream, daemon=True).start()
        try:
            while not self.ctrl.stop_event.is_set():
                size, ptype = struct.unpack(">HB", _recv_exact(self.conn, 3))
                payload = _recv_exact(self.conn, size - 3) if size > 3 else b""
                self._handle(ptype, payload)
        except (ConnectionError, OSError):
            pass
        finally:
            self.closed = True
            self.streaming.set()
            _close(self.conn)

    def _handle(self, ptype: int, payload: bytes) -> None:
        if ptype == P_REQUEST_PROTOCOL_VERSION:
            self.send(ptype, b"\x01")
        elif ptype == P_GET_URCONTROL_VERSION:
            self.send(ptype, struct.pack(">4I", *CONTROLLER_VERSION))
        elif ptype == P_SETUP_OUTPUTS:
            (self.freq,) = struct.unpack(">d", payload[:8])
            names = [n for n in payload[8:].decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n) or "NOT_FOUND" for n in names]
            rid = self.next_output_id
            self.next_output_id += 1
            if "NOT_FOUND" not in types:
                self.outputs.append(_Recipe(rid, names, types))
            else:
                self.ctrl.say(
                    f"unknown output field(s): {[n for n, t in zip(names, types, strict=True) if t == 'NOT_FOUND']}"
                )
            self.send(ptype, bytes([rid]) + ",".join(types).encode())
        elif ptype == P_SETUP_INPUTS:
            names = [n for n in payload.decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n) or "NOT_FOUND" for n in names]
            rid = self.next_input_id
            self.next_input_id += 1
            if "NOT_FOUND" not in types:
                self.inputs[rid] = _Recipe(rid, names, types)
            self.send(ptype, bytes([rid]) + ",".join(types).encode())
        elif ptype == P_START:
            self.send(ptype, b"\x01")
            self.streaming.set()
        elif ptype == P_PAUSE:
            self.streaming.clear()
            self.send(ptype, b"\x01")
        elif ptype == P_DATA and payload:
            recipe = self.inputs.get(payload[0])
            if recipe is not None and len(payload) >= recipe.struct.size:
                values = recipe.unpack(payload)
                with self.ctrl.lock:
                    self.ctrl.inputs.update(values)
                    self.ctrl._step(self.ctrl.now())
        elif ptype == P_TEXT_MESSAGE:
            pass

    def _stream(self) -> None:
        self.streaming.wait()
        period = 1.0 / max(min(self.freq, 500.0), 1.0)
        next_t = time.monotonic()
        while not self.closed and not self.ctrl.stop_event.is_set():
            if self.streaming.is_set() and self.outputs:
                state = self.ctrl.snapshot()
                try:
                    for r in self.outputs:
                        self.send(P_DATA, r.pack(state))
                except OSError:
                    return
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()


def _dashboard(ctrl: Controller, conn: socket.socket) -> None:
    f = conn.makefile("rwb", buffering=0)

    def reply(text: str) -> None:
        f.write((text + "\n").encode())

    reply("Connected: Universal Robots Dashboard Server")
    modes = {3: "POWER_OFF", 5: "IDLE", 7: "RUNNING"}
    safety = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}
    try:
        for raw in f:
            line = raw.decode("ascii", "replace").strip()
            if len(line) > 1024:
                reply("could not understand: command too long")
                continue
            cmd = line.lower()
            if cmd == "polyscopeversion":
                v = CONTROLLER_VERSION
                reply(f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (quickhealth simulator)")
            elif cmd == "get serial number":
                reply("20185500001")
            elif cmd == "get robot model":
                reply("UR5")
            elif cmd == "is in remote control":
                reply("true")
            elif cmd == "robotmode":
                reply(f"Robotmode: {modes.get(ctrl.robot_mode, 'RUNNING')}")
            elif cmd in ("safetystatus", "safetymode"):
                name = "Safetystatus" if cmd == "safetystatus" else "Safetymode"
                reply(f"{name}: {safety.get(ctrl.safety_mode, 'FAULT')}")
            elif cmd == "programstate":
                st = "PLAYING" if ctrl.runtime_state == RUNTIME_PLAYING else "STOPPED"
                reply(f"{st} rtde_control")
            elif cmd == "running":
                reply(f"Program running: {str(ctrl.runtime_state == RUNTIME_PLAYING).lower()}")
            elif cmd == "stop":
                ctrl.stop_program()
                reply("Stopped")
            elif cmd == "pause":
                ctrl.stop_program()
                reply("Pausing program")
            elif cmd == "play":
                ctrl.start_program()
                ok = ctrl.runtime_state == RUNTIME_PLAYING
                reply("Starting program" if ok else "Failed to execute: play")
            elif cmd == "unlock protective stop":
                ok = ctrl.unlock_protective_stop()
                reply(
                    "Protective stop releasing"
                    if ok
                    else "Cannot unlock protective stop until 5s after occurrence"
                )
            elif cmd == "power on":
                ctrl.robot_mode = ROBOT_MODE_IDLE
                reply("Powering on")
            elif cmd == "power off":
                ctrl.stop_program()
                ctrl.robot_mode = ROBOT_MODE_POWER_OFF
                reply("Powering off")
            elif cmd == "brake release":
                ctrl.robot_mode = ROBOT_MODE_RUNNING
                reply("Brake releasing")
            elif cmd == "close popup" or cmd == "close safety popup":
                reply("closing popup")
            elif cmd == "quit":
                reply("Disconnected")
                break
            else:
                reply(f"could not understand: '{line[:80]}'")
    except OSError:
        pass
    finally:
        _close(conn)


def _script(ctrl: Controller, conn: socket.socket) -> None:
    """Receive URScript programs on one connection (the client reuses it for reuploads).

    A program is complete at a trailing unindented ``end``, a 100 ms idle gap or the socket
    closing; it is never interpreted: a ``def``/``sec`` program starts the emulated script.
    """
    conn.settimeout(0.1)
    buf = b""
    closed = False
    while not closed and not ctrl.stop_event.is_set():
        complete = False
        try:
            chunk = conn.recv(65536)
            if not chunk:
                closed = complete = True
            else:
                buf += chunk
                tail = buf.rstrip()
                complete = tail.endswith(b"\nend") or tail == b"end" or len(buf) > 1_000_000
        except TimeoutError:
            complete = bool(buf)
        except OSError:
            closed = complete = True
        if complete and buf.strip():
            text = buf.decode("utf-8", "replace")
            first = text.strip().splitlines()[0][:60]
            ctrl.say(f"script received: {len(buf)} bytes, {first!r}")
            if text.lstrip().startswith(("def ", "sec ")):
                ctrl.start_program()
            buf = b""
    _close(conn)


def _control(ctrl: Controller, conn: socket.socket) -> None:
    """JSON-lines control channel for tests and the simulated cell (loopback only)."""
    f = conn.makefile("rwb", buffering=0)
    try:
        for raw in f:
            if len(raw) > 65536:
                f.write(b'{"ok": false, "error": "request too long"}\n')
                continue
            try:
                req = json.loads(raw)
                out = _control_request(ctrl, req)
                out["ok"] = True
            except (ValueError, KeyError, TypeError) as exc:
                out = {"ok": False, "error": str(exc)}
            f.write((json.dumps(out) + "\n").encode())
            if isinstance(req, dict) and req.get("cmd") == "shutdown":
                break
    except OSError:
        pass
    finally:
        _close(conn)


def _control_request(ctrl: Controller, req: dict[str, Any]) -> dict[str, Any]:
    cmd = req["cmd"]
    if cmd == "ping":
        return {"pid": _pid()}
    if cmd == "fault":
        ctrl.add_fault(req)
        return {}
    if cmd == "state":
        with ctrl.lock:
            t = ctrl.now()
            q = ctrl.arm.actual(t)
            return {
                "t": t,
                "q": list(map(float, q)),
                "moving": ctrl.arm.moving(t),
                "robot_mode": ctrl.robot_mode,
                "safety_mode": ctrl.safety_mode,
                "runtime_state": ctrl.runtime_state,
                "n_moves": ctrl.n_moves,
                "frozen": ctrl.frozen is not None,
            }
    if cmd == "truth":
        with ctrl.lock:
            t = ctrl.now()
            q = ctrl.arm.actual(t)
            approach = ctrl.arm.approach.copy()
            moving = ctrl.arm.moving(t)
        truth = ctrl.arm.truth
        T = truth(q, approach) if truth is not None else ctrl.arm.robot.fk(q)
        return {
            "t": t,
            "q": list(map(float, q)),
            "approach": list(map(float, approach)),
            "moving": moving,
            "T_instr_target0": np.asarray(T).tolist(),
        }
    if cmd == "twin":
        if ctrl.world is None:
            raise ValueError("this simulator has no digital twin")
        return {"truth": ctrl.world.twin.truth.to_dict()}
    if cmd == "set_q":
        q = np.asarray(req["q"], dtype=float)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise ValueError("set_q needs 6 finite joint angles (rad)")
        with ctrl.lock:
            ctrl.arm.halt(ctrl.now())
            ctrl.arm.q_cmd = q
        return {}
    if cmd == "log":
        return {"log": ctrl.log[-200:]}
    if cmd == "shutdown":
        ctrl.stop_event.set()
        for s in ctrl.listeners:
            _close(s)
        return {}
    raise ValueError(f"unknown control command {cmd!r}")


def _pid() -> int:
    import os

    return os.getpid()


def _listen(port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((HOST, port))  # loopback only, always
    s.listen(8)
    return s


def serve(ctrl: Controller, *, rtde_port: int = RTDE_PORT) -> None:
    """Run all servers until a ``shutdown`` control request (blocks)."""
    handlers: list[tuple[int, Callable[[Controller, socket.socket], None], bool]] = [
        (rtde_port, lambda c, s: _RtdeSession(c, s).serve(), True),
        (DASHBOARD_PORT, _dashboard, True),
        (SCRIPT_PORT, _script, True),
        (ctrl.control_port, _control, False),
    ]
    listeners = []
    for port, _, _ in handlers:
        try:
            listeners.append(_listen(port))
        except OSError as exc:
            for s in listeners:
                _close(s)
            raise OSError(f"cannot listen on {HOST}:{port}: {exc.strerror}") from exc
    ctrl.listeners = listeners

    def accept_loop(sock: socket.socket, handler: Callable[..., None], faultable: bool) -> None:
        while not ctrl.stop_event.is_set():
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            if faultable and ctrl.refuse_connections:
                _close(conn)
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if faultable:
                ctrl.connections.append(conn)
            threading.Thread(target=handler, args=(ctrl, conn), daemon=True).start()

    threads = [
        threading.Thread(target=accept_loop, args=(s, h, f), daemon=True)
        for s, (_, h, f) in zip(listeners, handlers, strict=True)
    ]
    for t in threads:
        t.start()
    ctrl.say("listening on 127.0.0.1")
    ctrl.stop_event.wait()
    for s in listeners + ctrl.connections:
        _close(s)


# ---------------------------------------------------------------------------------------
# Process helpers
# ---------------------------------------------------------------------------------------


class SimControllerHandle:
    """A running simulator process, driven over its loopback control port.

    Examples
    --------
    >>> sim = start_sim_controller()                       # doctest: +SKIP
    >>> sim.fault("protective_stop", after_moves=3)        # doctest: +SKIP
    >>> sim.stop()                                         # doctest: +SKIP
    """

    def __init__(self, proc: Any, control_port: int, port_lock: int = -1) -> None:
        self.proc = proc
        self.control_port = control_port
        self._port_lock = port_lock
        self._sock: socket.socket | None = None
        self._file: Any = None
        self._lock = threading.Lock()

    def request(self, cmd: str, **kw: Any) -> dict[str, Any]:
        """Send one control request and return the decoded answer (raises on error)."""
        with self._lock:
            if self._sock is None:
                self._sock = socket.create_connection((HOST, self.control_port), timeout=5.0)
                self._file = self._sock.makefile("rwb", buffering=0)
            self._file.write((json.dumps({"cmd": cmd, **kw}) + "\n").encode())
            line = self._file.readline()
        if not line:
            raise ConnectionError("simulator control channel closed")
        out: dict[str, Any] = json.loads(line)
        if not out.get("ok"):
            raise ValueError(out.get("error", "simulator refused the request"))
        return out

    def fault(self, kind: str, **when: Any) -> None:
        """Inject a fault now, ``after_s=`` seconds or ``after_moves=`` motion commands."""
        self.request("fault", kind=kind, **when)

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Actual joints (rad) and the true target frame at pan 0, ``T_instr_target0``, now."""
        out = self.request("truth")
        return np.asarray(out["q"]), np.asarray(out["T_instr_target0"])

    def twin_truth(self) -> dict[str, Any]:
        """The digital twin's truth document (``TwinTruth.to_dict``)."""
        return self.request("twin")["truth"]

    def state(self) -> dict[str, Any]:
        """Modes, joints and whether the arm moves."""
        return self.request("state")

    def stop(self, timeout: float = 5.0) -> None:
        """Shut the simulator down and reap the process."""
        try:
            self.request("shutdown")
        except (OSError, ValueError):
            pass
        if self._sock is not None:
            _close(self._sock)
            self._sock = None
        if self.proc is not None:
            try:
                self.proc.wait(timeout=timeout)
            except Exception:  # noqa: BLE001 - last resort: the process did not exit in time
                self.proc.kill()
                self.proc.wait(timeout=timeout)
            self.proc = None
        if self._port_lock >= 0:
            import os

            os.close(self._port_lock)  # releases the host-wide port lock
            self._port_lock = -1

    def __enter__(self) -> SimControllerHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


PORT_LOCK = "/tmp/quickhealth-ur-ports.lock"


def _take_port_lock(wait_s: float) -> int:
    import fcntl
    import os

    from quickhealth.identify.errors import HardwareError

    fd = os.open(PORT_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            if time.monotonic() > deadline:
                os.close(fd)
                raise HardwareError(
                    f"another controller simulator holds the UR ports (waited {wait_s:.0f} s)"
                ) from None
            time.sleep(0.1)


def ports_free() -> bool:
    """True when the fixed UR ports are free on 127.0.0.1."""
    for port in (RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT):
        s = socket.socket()
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((HOST, port))
        except OSError:
            return False
        finally:
            s.close()
    return True


def start_sim_controller(
    *,
    control_port: int = CONTROL_PORT,
    q0_deg: list[float] | None = None,
    twin_seed: int = 1,
    cell: str = "reference",
    timeout: float = 15.0,
    verbose: bool = False,
    speed_factor: float = 1.0,
    wait_s: float = 120.0,
    degrade: dict[str, float] | None = None,
) -> SimControllerHandle:
    """Start the simulator as a separate process and wait until it answers.

    The ur-rtde constructors hold the GIL, so the simulator must never run as a thread of
    the process that uses the client.  The UR ports are fixed, so one simulator runs per
    host: a host-wide lock (``/tmp/quickhealth-ur-ports.lock``) is taken first, waiting up to
    ``wait_s`` seconds for another simulator started this way to stop (tests run serially).

    Raises
    ------
    HardwareError
        The ports are taken (another simulator or a controller on this host) or the process
        did not come up within ``timeout`` seconds.
    """
    import os
    import subprocess

    from quickhealth.identify.errors import HardwareError

    lock = _take_port_lock(wait_s)
    if not ports_free():
        os.close(lock)
        raise HardwareError(
            "UR ports 30004/29999/30003 on 127.0.0.1 are in use: another simulator runs; stop it first"
        )
    cmd = [
        sys.executable,
        "-m",
        "quickhealth.station.hardware.simcontroller",
        "--control-port",
        str(control_port),
        "--twin-seed",
        str(twin_seed),
        "--cell",
        cell,
        "--speed-factor",
        str(speed_factor),
        "--parent-pid",
        str(os.getpid()),
    ]
    if q0_deg is not None:
        cmd += ["--q0-deg", ",".join(f"{v:.9g}" for v in q0_deg)]
    if degrade:
        cmd += ["--degrade", ",".join(f"{k}={v:.12g}" for k, v in degrade.items())]
    if verbose:
        cmd.append("--verbose")
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL)
    handle = SimControllerHandle(proc, control_port, lock)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            handle.stop()
            raise HardwareError(f"controller simulator exited at start (status {proc.returncode})")
        try:
            handle.request("ping")
            return handle
        except OSError:
            time.sleep(0.05)
    handle.stop(timeout=1.0)
    raise HardwareError(f"controller simulator did not answer within {timeout:.0f} s")


HOME_Q_DEG = [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]


def build_controller(
    *,
    control_port: int = CONTROL_PORT,
    q0_deg: list[float] | None = None,
    twin_seed: int = 1,
    cell: str = "reference",
    verbose: bool = False,
    degrade: dict[str, float] | None = None,
) -> Controller:
    """A controller whose arm is the digital twin of ``twin_seed`` placed in ``cell``."""
    from .world import build_world

    world = build_world(cell, twin_seed=twin_seed, degrade=degrade)
    q0 = np.radians(q0_deg if q0_deg is not None else HOME_Q_DEG)
    arm = Arm(world.twin.robot, q0, truth=world.T_instr_target0)
    ctrl = Controller(arm, control_port=control_port, verbose=verbose)
    ctrl.world = world
    return ctrl


def main(argv: list[str] | None = None) -> int:
    """Command line of the simulator process."""
    p = argparse.ArgumentParser(
        prog="quickhealth sim-controller",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    args = p.parse_args(argv)
    return run_from_args(args)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``quickhealth sim-controller`` and ``python -m``."""
    p.add_argument(
        "--control-port",
        type=int,
        default=CONTROL_PORT,
        help="loopback port of the JSON control channel (default %(default)s)",
    )
    p.add_argument("--q0-deg", default=None, help="start joints, comma-separated degrees")
    p.add_argument(
        "--twin-seed",
        type=int,
        default=1,
        help="seed of the digital twin whose errors the arm has (default %(default)s)",
    )
    p.add_argument("--cell", default="reference", help="cell name or file (camera placement)")
    p.add_argument(
        "--degrade",
        default=None,
        help="change the twin's true errors, e.g. j2.ex.c0=5e-4 (m or rad; comma-separated)",
    )
    p.add_argument("--verbose", action="store_true", help="log controller events to stderr")
    p.add_argument(
        "--speed-factor",
        type=float,
        default=1.0,
        help="run every motion this many times faster (tests; default %(default)s)",
    )
    p.add_argument(
        "--parent-pid",
        type=int,
        default=0,
        help="exit when this process is gone (set by start_sim_controller)",
    )


def _watch_parent(ctrl: Controller, pid: int) -> None:
    """Shut down when the process that started the simulator dies (e.g. ``kill -9``)."""
    import os

    while not ctrl.stop_event.wait(0.2):
        if os.getppid() != pid:
            ctrl.say("parent process gone: shutting down")
            ctrl.stop_event.set()
            for s in ctrl.listeners:
                _close(s)
            return


def run_from_args(args: argparse.Namespace) -> int:
    """Build and serve; returns the exit status."""
    q0 = None
    if args.q0_deg:
        try:
            q0 = [float(v) for v in args.q0_deg.split(",")]
        except ValueError:
            q0 = None
        if q0 is None or len(q0) != 6 or not all(math.isfinite(v) for v in q0):
            sys.stderr.write("quickhealth: error: --q0-deg needs 6 comma-separated numbers\n")
            return 2
    if not (0.1 <= args.speed_factor <= 100.0):
        sys.stderr.write("quickhealth: error: --speed-factor must be in 0.1..100\n")
        return 2
    if not 1024 <= args.control_port <= 65535:
        sys.stderr.write("quickhealth: error: --control-port must be in 1024..65535\n")
        return 2
    from quickhealth.identify.errors import InputError

    from .world import parse_degradation

    try:
        degrade = parse_degradation(getattr(args, "degrade", None))
        ctrl = build_controller(
            control_port=args.control_port,
            q0_deg=q0,
            twin_seed=args.twin_seed,
            cell=args.cell,
            verbose=args.verbose,
            degrade=degrade,
        )
    except InputError as exc:
        sys.stderr.write(f"quickhealth: error: {exc}\n")
        return 2
    ctrl.speed_factor = float(args.speed_factor)
    if args.parent_pid:
        threading.Thread(target=_watch_parent, args=(ctrl, args.parent_pid), daemon=True).start()
    try:
        serve(ctrl)
    except OSError as exc:
        sys.stderr.write(f"quickhealth: error: {exc}\n")
        return 3
    except KeyboardInterrupt:
        return 0
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
