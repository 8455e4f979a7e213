"""The robot behind a small interface: a reader that cannot move the arm, and a commander.

- :class:`RobotReader` — joints, TCP pose, controller time, robot mode and safety status, each
  joint's temperature and measured torque (:class:`JointSensors`).
- :class:`Robot` — a reader that also moves (joint or linear leg to a joint target) and stops.
- :class:`UrRobot` — the adapter on ur-rtde (``rtde_receive`` + ``rtde_control``), run in a
  child process (:mod:`.ur_client`) that alone calls into the C++ client.  Moves are sent
  asynchronously and watched there, so a protective stop, a lost connection or a frozen RTDE
  stream ends the move within a fraction of a second with a
  :class:`~quickhealth.identify.errors.HardwareError` that says what to do, never a hang; a
  stop jumps the queue and ends a move within one 4 ms watch cycle.  A stop the client cannot
  confirm (link down, stream frozen, client stuck or killed) is sent to the controller's
  dashboard server instead (``stop``: the program and the arm stop); one confirmed by neither
  raises :class:`~quickhealth.identify.errors.HardwareError`: the arm may still be moving.
- ``quickhealth.station.sim.fake_robot.FakeRobot`` — pure Python, same timing model as the
  controller simulator, with the same faults; for fast unit tests.

Every move is checked before it is sent: six finite joint angles inside the robot's limits,
speeds and accelerations positive and bounded.  Only these numbers reach the controller.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from enum import Enum
from typing import NoReturn, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...identify.errors import HardwareError, InputError
from ...identify.jointload import torque_constant
from ...identify.robot import RobotModel, ur5
from ...identify.transforms import exp_so3, make_T
from .legs import Leg
from .line_trigger import Pulse
from .ur_client import FAREWELL_ID
from .urtypes import RobotMode, SafetyMode

F = NDArray[np.float64]

MAX_JOINT_SPEED = 3.14  # rad/s, UR5 joint limit
MAX_JOINT_ACCEL = 40.0  # rad/s²
MAX_TOOL_SPEED = 3.0  # m/s
MAX_TOOL_ACCEL = 150.0  # m/s²

#: Where a UR's joint torques come from (RTDE ``actual_current`` × the torque constant).
TORQUE_FROM_CURRENT = "RTDE actual_current × the joints' torque constants (an estimate)"

#: The arm is at rest when every joint stays within REST_TOL_RAD peak to peak for
#: REST_WINDOW_S of controller time: the run's settle criterion, and what a trigger pulse
#: checks before it is sent.
REST_WINDOW_S = 0.15
REST_TOL_RAD = 2e-5
REST_WAIT_S = 2.0  # s a trigger pulse waits for the arm to come to rest after a move


def _enum(cls: type[Enum], v: int) -> Enum:
    try:
        return cls(int(v))
    except ValueError:
        return cls.UNKNOWN  # type: ignore[attr-defined, no-any-return]


@dataclass(frozen=True)
class RobotStatus:
    """What the controller says about itself."""

    robot_mode: RobotMode
    safety_mode: SafetyMode
    program_running: bool
    connected: bool = True

    @property
    def ready(self) -> bool:
        """Powered, brakes released, no safety stop."""
        return (
            self.connected
            and self.robot_mode is RobotMode.RUNNING
            and self.safety_mode in (SafetyMode.NORMAL, SafetyMode.REDUCED)
        )

    def describe(self) -> str:
        """One line for the user."""
        if not self.connected:
            return "robot controller not connected"
        return (
            f"robot mode {self.robot_mode.name}, safety {self.safety_mode.name}, "
            f"program {'running' if self.program_running else 'stopped'}"
        )


class ProtectiveStop(HardwareError):
    """The controller stopped the arm for safety (protective or emergency stop)."""


class ConnectionLost(HardwareError):
    """The RTDE connection to the controller dropped."""


class StreamFrozen(HardwareError):
    """The controller's RTDE stream stopped advancing (its timestamp froze)."""


class ProgramStopped(HardwareError):
    """The control program on the controller stopped (someone pressed stop?)."""


@dataclass(frozen=True)
class JointSample:
    """One joint reading from the stream: controller time (s) and joints (rad)."""

    t: float
    q: F


@dataclass(frozen=True)
class JointSensors:
    """What the controller reports about each joint now.

    ``temperature`` (n,) °C, or None when the controller reports none; ``torque`` (n,) N·m:
    what each joint's drive exerts (at rest it holds the arm and its payload against gravity),
    or None; ``torque_source`` says where the torque comes from (e.g. the motor currents
    times the joints' torque constants).
    """

    temperature: F | None = None
    torque: F | None = None
    torque_source: str = ""


@runtime_checkable
class RobotReader(Protocol):
    """Read-only view of a robot: cannot move the arm."""

    model: RobotModel

    def joints(self) -> F:
        """Actual joints, rad, shape (n,)."""
        ...

    def sample(self) -> JointSample:
        """Actual joints with the controller's timestamp."""
        ...

    def tcp_pose(self) -> F:
        """The controller's own TCP pose ``T_base_tcp`` (its nominal kinematics), (4, 4)."""
        ...

    def status(self) -> RobotStatus:
        """Robot mode, safety mode, program state."""
        ...

    def joint_sensors(self) -> JointSensors:
        """Each joint's temperature and measured torque now (what the controller reports)."""
        ...


@runtime_checkable
class Robot(RobotReader, Protocol):
    """A robot that moves: joint or linear leg to a joint target, stop."""

    def move(
        self, q: ArrayLike, leg: Leg = Leg.JOINT, *, speed: float = 1.0, accel: float = 1.4
    ) -> None:
        """Move to joints ``q`` (rad) and return when the controller says the move ended.

        ``speed``/``accel``: rad/s and rad/s² for joint legs, m/s and m/s² for linear legs.
        Raises :class:`ProtectiveStop`, :class:`ConnectionLost`, :class:`StreamFrozen` or
        :class:`ProgramStopped` (all ``HardwareError``) when the move cannot finish.
        """
        ...

    def stop(self) -> None:
        """Decelerate the arm to rest now; refuse further moves until :meth:`clear_stop`."""
        ...

    def clear_stop(self) -> None:
        """Allow moves again after :meth:`stop` (the start of a run)."""
        ...

    def reader(self) -> RobotReader:
        """A read-only view of this robot."""
        ...

    def close(self) -> None:
        """Stop and release the connection."""
        ...


def check_move(
    model: RobotModel, q: ArrayLike, leg: Leg, speed: float, accel: float
) -> tuple[F, Leg, float, float]:
    """Validate a move's numbers (the only things that ever reach the controller)."""
    q = np.asarray(q, dtype=float)
    if q.shape != (model.n_joints,) or not np.all(np.isfinite(q)):
        raise InputError(f"move needs {model.n_joints} finite joint angles, got {q!r}")
    if np.any(q < model.q_min - 1e-9) or np.any(q > model.q_max + 1e-9):
        raise InputError(
            f"move target {np.degrees(q).round(3).tolist()} deg is outside the joint limits"
        )
    leg = Leg(leg)
    vmax, amax = (
        (MAX_JOINT_SPEED, MAX_JOINT_ACCEL) if leg is Leg.JOINT else (MAX_TOOL_SPEED, MAX_TOOL_ACCEL)
    )
    speed, accel = float(speed), float(accel)
    if not (0.0 < speed <= vmax and math.isfinite(speed)):
        raise InputError(f"speed {speed} outside (0, {vmax}]")
    if not (0.0 < accel <= amax and math.isfinite(accel)):
        raise InputError(f"acceleration {accel} outside (0, {amax}]")
    return q, leg, speed, accel


class ReadOnly:
    """A reader wrapping a robot: exposes only the read methods."""

    def __init__(self, robot: RobotReader) -> None:
        self._robot = robot
        self.model = robot.model
        self.sample_period = float(getattr(robot, "sample_period", 0.008))

    def joints(self) -> F:
        return self._robot.joints()

    def sample(self) -> JointSample:
        return self._robot.sample()

    def tcp_pose(self) -> F:
        return self._robot.tcp_pose()

    def status(self) -> RobotStatus:
        return self._robot.status()

    def joint_sensors(self) -> JointSensors:
        return self._robot.joint_sensors()


def _pose_to_T(p: ArrayLike) -> F:
    p = np.asarray(p, dtype=float)
    return make_T(exp_so3(p[3:6]), p[:3])


# ---------------------------------------------------------------------------------------
# ur-rtde adapter
# ---------------------------------------------------------------------------------------

RECOVERY_HINT = "clear the cause, release the stop on the teach pendant, then rerun with --resume"
DASHBOARD_PORT = 29999  # the UR dashboard server (a line protocol), fixed on every controller


class MoveStopped(HardwareError):
    """The move was stopped on request (abort) or cancelled because the arm had been stopped."""


_ERRORS: dict[str, type[HardwareError]] = {
    c.__name__: c
    for c in (
        HardwareError,
        ProtectiveStop,
        ConnectionLost,
        StreamFrozen,
        ProgramStopped,
        MoveStopped,
    )
}


class _Child:
    """One ur-rtde client process (:mod:`.ur_client`) and the replies it owes us."""

    def __init__(self, argv: list[str], connect_timeout: float) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "quickhealth.station.hardware.ur_client", *argv],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            bufsize=1,
        )
        self._lock = threading.Lock()
        self._ids = iter(range(1, 1 << 62))
        self._waiting: dict[int, tuple[threading.Event, list[dict]]] = {0: (threading.Event(), [])}
        self.dead: str | None = None
        self.farewell: dict | None = None  # the client's last words after close (its threads)
        self._reader = threading.Thread(target=self._read, name="ur-client-replies", daemon=True)
        self._reader.start()
        hello = self.wait(0, connect_timeout)
        if hello is None:
            self.kill()
            raise ConnectionLost(
                f"the robot controller did not accept a connection within {connect_timeout:.0f} s"
            )
        if not hello.get("ok"):
            self.kill()
            raise ConnectionLost(str(hello.get("message", "cannot connect")))

    def _read(self) -> None:
        assert self.proc.stdout is not None
        try:
            for line in self.proc.stdout:
                try:
                    msg = json.loads(line)
                    if int(msg["id"]) == FAREWELL_ID:
                        self.farewell = dict(msg["value"])
                        continue
                    ev, box = self._waiting[int(msg["id"])]
                except (ValueError, KeyError, TypeError):
                    continue
                box.append(msg)
                ev.set()
        except (OSError, ValueError):
            pass  # the pipe was closed under us: the process is being killed
        self.proc.wait()
        with self._lock:
            self.dead = f"the ur-rtde client process ended (status {self.proc.returncode})"
            for ev, _ in self._waiting.values():
                ev.set()

    def send(self, op: str, **args: object) -> int:
        """Queue a request; returns its id (wait for the answer with :meth:`wait`)."""
        with self._lock:
            if self.dead is not None:
                raise ConnectionLost(f"{self.dead}; reconnect, then rerun with --resume")
            rid = next(self._ids)
            self._waiting[rid] = (threading.Event(), [])
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write(json.dumps({"id": rid, "op": op, **args}) + "\n")
                self.proc.stdin.flush()
            except (OSError, ValueError):
                self.dead = "the ur-rtde client process is gone"
                raise ConnectionLost(f"{self.dead}; reconnect, then rerun with --resume") from None
        return rid

    def wait(self, rid: int, timeout: float) -> dict | None:
        """The answer to request ``rid``, or None when none came within ``timeout`` s."""
        ev, box = self._waiting[rid]
        ev.wait(timeout)
        if box:
            with self._lock:
                self._waiting.pop(rid, None)
            return box[0]
        if self.dead is not None:
            raise ConnectionLost(f"{self.dead}; reconnect, then rerun with --resume")
        return None

    def forget(self, rid: int) -> None:
        with self._lock:
            self._waiting.pop(rid, None)

    def kill(self) -> None:
        """End the process now (a stuck C++ call is never disconnected from another thread)."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        if threading.current_thread() is not self._reader:
            self._reader.join(2.0)  # its last lines (the farewell) read before the pipe closes
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()  # type: ignore[union-attr]
            except (OSError, ValueError):
                pass

    def close(self, timeout: float) -> None:
        """Ask the client to stop the script and disconnect; kill it if it does not end."""
        try:
            rid = self.send("close")
            self.wait(rid, timeout)
            self.proc.wait(timeout)
        except Exception:  # noqa: BLE001 - whatever went wrong, the process must end
            pass
        self.kill()


class UrRobot:
    """A UR robot over ur-rtde (CB3 or e-Series), the client in a child process.

    The two ur-rtde objects live in their own process (:mod:`.ur_client`), each owned by one
    thread there; this object only sends requests down a pipe and waits for replies, so any
    number of threads here (the run, an abort, the TUI's status polls) may call it and never
    two threads are inside a ur-rtde object.  A client stuck inside a C++ call (a controller
    that stopped answering) is killed and replaced by :meth:`reconnect`; it can never take
    this interpreter down.  The dashboard connection (:meth:`stop`'s fallback) is opened,
    used and closed by one stop at a time, under its own lock: it too has one owner.

    Parameters
    ----------
    host : str
        Controller address.
    frequency : float
        RTDE rate, Hz (125 for CB3, up to 500 on e-Series).
    stale_after : float
        s without a new RTDE timestamp before the stream counts as frozen.
    move_timeout : float
        s a single move may take before the run is stopped.
    """

    COMMAND_TIMEOUT = 5.0  # s one call into the controller may take before the client is killed
    STOP_WAIT = 1.0  # s a stop may take to be confirmed over RTDE (deceleration included)
    DASHBOARD_TIMEOUT = 1.0  # s each step of the dashboard's stop may take
    CONNECT_TIMEOUT = 20.0  # s to connect both interfaces (the script upload included)

    def __init__(
        self,
        host: str,
        *,
        frequency: float = 125.0,
        stale_after: float = 0.5,
        move_timeout: float = 120.0,
        model: RobotModel | None = None,
    ) -> None:
        self.model = model or ur5()
        self.host = host
        self.frequency = float(frequency)
        self.stale_after = float(stale_after)
        self.move_timeout = float(move_timeout)
        self.sample_period = 1.0 / self.frequency
        self._gate = threading.Lock()  # orders moves against stops; only ever held briefly
        self._connecting = threading.RLock()  # one (re)connect at a time; a stop never waits on it
        self._dashboard = threading.Lock()  # the owner of the dashboard connection: one stop
        self._halted = False
        self._child: _Child | None = None
        self._child = self._new_child()

    # -- the client process ---------------------------------------------------------------
    def _new_child(self) -> _Child:
        argv = [
            self.host,
            f"--frequency={self.frequency}",
            f"--stale-after={self.stale_after}",
            f"--move-timeout={self.move_timeout}",
        ]
        return _Child(argv, self.CONNECT_TIMEOUT)

    def connect(self) -> None:
        """Connect when not connected (a lost link, a killed client); otherwise nothing."""
        with self._connecting:
            child = self._child
            if child is None or child.dead is not None:
                self.reconnect()

    def reconnect(self) -> None:
        """Replace the client process: after a link drop, a frozen stream or a controller
        restart (the new client uploads the control program again).  Raises
        :class:`ConnectionLost` while the controller is still away.

        A stop meanwhile is not held up (it goes to the dashboard while there is no client),
        and stays in force: moves wait for :meth:`clear_stop` (the start of a run)."""
        with self._connecting:
            with self._gate:
                old, self._child = self._child, None
            if old is not None:
                old.close(1.0)
            child = self._new_child()  # may take seconds: no lock a stop needs is held
            with self._gate:
                self._child = child

    def _live(self) -> _Child:
        child = self._child
        if child is None or child.dead is not None:
            raise ConnectionLost(
                f"not connected to the robot controller at {self.host}: reconnect, "
                "then rerun with --resume"
            )
        return child

    def _discard(self, child: _Child) -> None:
        """Kill a client that cannot be trusted any more (stuck, frozen stream, link lost)."""
        with self._gate:
            if self._child is child:
                self._child = None
        child.kill()

    def _refused(self, child: _Child, msg: dict, default: str) -> NoReturn:
        """Raise the driver's error for a command the client refused (a lost or frozen link
        also discards the client: the next :meth:`connect` replaces it)."""
        err = _ERRORS.get(str(msg.get("error")), HardwareError)
        if err in (ConnectionLost, StreamFrozen):
            self._discard(child)
        raise err(str(msg.get("message", default)))

    def _state(self, child: _Child | None = None) -> dict:
        child = child or self._live()
        rid = child.send("state")
        msg = child.wait(rid, self.COMMAND_TIMEOUT)
        if msg is None:
            child.forget(rid)
            self._discard(child)
            raise ConnectionLost(
                "the ur-rtde client process stopped answering (killed); reconnect, "
                "then rerun with --resume"
            )
        snap = msg["value"]
        if time.monotonic() - float(snap["polled"]) > self.COMMAND_TIMEOUT:  # receiver stuck
            self._discard(child)
            raise ConnectionLost("the ur-rtde receive connection stopped polling (client killed)")
        return snap

    def _fresh(self, child: _Child | None = None) -> dict:
        child = child or self._live()
        s = self._state(child)
        if not s["connected"] or s["still_for"] > self.stale_after:
            self._discard(child)  # a lost or frozen link needs a new client: reconnect
        if not s["connected"]:
            raise ConnectionLost(
                f"lost the RTDE connection to {self.host}: check the network cable and the "
                "controller, then rerun with --resume"
            )
        if s["still_for"] > self.stale_after:
            raise StreamFrozen(
                f"the controller's RTDE stream froze (timestamp {s['timestamp']:.3f} s unchanged "
                f"for {s['still_for']:.1f} s): restart the controller, then rerun with --resume"
            )
        return s

    # -- reading ---------------------------------------------------------------------------
    def joints(self) -> F:
        return np.asarray(self._fresh()["q"], dtype=float)

    def sample(self) -> JointSample:
        s = self._fresh()
        return JointSample(float(s["timestamp"]), np.asarray(s["q"], dtype=float))

    def tcp_pose(self) -> F:
        return _pose_to_T(self._fresh()["tcp_pose"])

    def status(self) -> RobotStatus:
        try:
            s = self._state()
        except ConnectionLost:
            s = {"connected": False}
        if not s["connected"]:
            if self._child is not None:
                self._discard(self._child)
            return RobotStatus(RobotMode.UNKNOWN, SafetyMode.UNKNOWN, False, connected=False)
        return RobotStatus(
            _enum(RobotMode, s["robot_mode"]),  # type: ignore[arg-type]
            _enum(SafetyMode, s["safety_mode"]),  # type: ignore[arg-type]
            int(s["runtime_state"]) == 2,
        )

    def joint_sensors(self) -> JointSensors:
        """RTDE ``joint_temperatures`` and ``actual_current`` times each joint's torque
        constant (the robot file's, else the estimate:
        :func:`~quickhealth.identify.jointload.torque_constant`; ur-rtde 1.6 reads
        no measured torque; an error in a joint's constant only rescales a compliance fitted
        on its torques)."""
        s = self._fresh()
        temps = np.asarray(s.get("joint_temperatures", ()), dtype=float)
        current = np.asarray(s.get("actual_current", ()), dtype=float)
        nj = self.model.n_joints
        return JointSensors(
            temps if temps.shape == (nj,) else None,
            current * torque_constant(self.model) if current.shape == (nj,) else None,
            TORQUE_FROM_CURRENT,
        )

    def reader(self) -> RobotReader:
        return ReadOnly(self)

    # -- commanding ------------------------------------------------------------------------
    def move(
        self, q: ArrayLike, leg: Leg = Leg.JOINT, *, speed: float = 1.0, accel: float = 1.4
    ) -> None:
        q, leg, speed, accel = check_move(self.model, q, leg, speed, accel)
        with self._gate:
            if self._halted:
                raise MoveStopped(
                    "the arm was stopped (abort): the move was not sent; start the run again"
                )
            child = self._live()
            rid = child.send(
                "move", q=[float(v) for v in q], leg=leg.value, speed=speed, accel=accel
            )
        deadline = time.monotonic() + self.move_timeout + self.COMMAND_TIMEOUT
        while True:
            msg = child.wait(rid, 0.05)
            if msg is not None:
                break
            # Still moving: watch the client from outside too, in case it is stuck in a call.
            try:
                s = self._fresh(child)
            except HardwareError:
                child.forget(rid)
                self._discard(child)
                raise
            if s["busy"] and s["busy_for"] > self.COMMAND_TIMEOUT or time.monotonic() > deadline:
                child.forget(rid)
                self._discard(child)
                raise HardwareError(
                    f"the move: the controller did not answer within {self.COMMAND_TIMEOUT:.0f} s "
                    "(client killed); restart it, then rerun with --resume"
                )
        if not msg["ok"]:
            self._refused(child, msg, "the move failed")

    def stop(self) -> None:
        """Stop the arm now (ahead of anything queued) and refuse moves until :meth:`clear_stop`.

        Returns once the stop is confirmed: by the client over RTDE (``stopJ`` done on a live
        stream, or no program running) within :attr:`STOP_WAIT` s, else by the controller's
        dashboard server (``stop`` answered ``Stopped``), which is also where the stop goes
        at once when there is no live client (link lost, frozen stream, client killed or stuck).

        Raises
        ------
        HardwareError
            Neither confirmed the stop: the arm may still be moving.
        """
        with self._gate:
            self._halted = True
            child = self._child
        why = self._stop_over_rtde(child)
        if why is None:
            return
        try:
            self._dashboard_stop()
            return
        except HardwareError as exc:
            raise HardwareError(
                f"the stop of the arm could not be confirmed ({why}; {exc}): the arm may still "
                "be moving: press the emergency stop"
            ) from None

    def _stop_over_rtde(self, child: _Child | None) -> str | None:
        """Ask the client to stop the arm; None when confirmed, else why not."""
        if child is None or child.dead is not None:
            return "no ur-rtde client (link lost or client killed)"
        try:
            rid = child.send("stop")
            msg = child.wait(rid, self.STOP_WAIT)
        except ConnectionLost as exc:
            return str(exc)
        if msg is None:
            child.forget(rid)
            self._discard(child)
            return f"the ur-rtde client did not confirm within {self.STOP_WAIT:.0f} s (killed)"
        if msg.get("ok"):
            return None
        if msg.get("error") in ("ConnectionLost", "StreamFrozen"):
            self._discard(child)  # a lost or frozen link needs a new client: reconnect
        return str(msg.get("message", "the client refused the stop"))

    def _dashboard_stop(self) -> None:
        """``stop`` through the dashboard server (29999); raises HardwareError unless confirmed.

        One short connection per stop, opened, used and closed by the caller under
        ``_dashboard``: no other thread is ever inside it."""
        where = f"the dashboard server at {self.host}:{DASHBOARD_PORT}"
        with self._dashboard:
            try:
                with socket.create_connection(
                    (self.host, DASHBOARD_PORT), timeout=self.DASHBOARD_TIMEOUT
                ) as sock:
                    f = sock.makefile("rwb", buffering=0)
                    if not f.readline():
                        raise HardwareError(f"{where} closed the connection")
                    f.write(b"stop\n")
                    reply = f.readline().decode("ascii", "replace").strip()
                    if reply.lower().startswith("stopped"):
                        return
                    # "Failed to execute: stop" when nothing runs: then nothing drives the arm.
                    f.write(b"programstate\n")
                    state = f.readline().decode("ascii", "replace").strip()
                    if state.upper().startswith("STOPPED"):
                        return
                    raise HardwareError(f"{where} did not stop the program ({reply!r}, {state!r})")
            except OSError as exc:
                raise HardwareError(f"{where} cannot be reached ({exc})") from None

    def clear_stop(self) -> None:
        """Allow moves again after :meth:`stop` (the start of a run)."""
        with self._gate:
            self._halted = False

    # -- digital outputs -------------------------------------------------------------------
    def pulse_digital_out(self, output: int, width_s: float) -> Pulse:
        """A pulse on standard digital output ``output`` (0..7) through ur-rtde's
        ``RTDEIOInterface.setStandardDigitalOut``, owned by the client's io thread
        (:mod:`.ur_io`): sent only with the arm at rest (no move under way, the joints within
        :data:`REST_TOL_RAD` over :data:`REST_WINDOW_S`; after a move it waits for that at
        most :data:`REST_WAIT_S`), each edge confirmed on the stream; ``width_s`` of
        controller time, at least two controller cycles.

        Raises HardwareError (one line) when the pulse was refused or not confirmed, and
        ConnectionLost / StreamFrozen when the link is gone (the client is then replaced at
        the next :meth:`reconnect`)."""
        output, width_s = int(output), float(width_s)
        if not 0 <= output <= 7:
            raise InputError(f"digital output {output}: a UR has standard outputs 0..7")
        if not (2.0 * self.sample_period <= width_s <= 1.0):
            raise InputError(
                f"a pulse of {width_s * 1e3:.0f} ms: at least two controller cycles "
                f"({2e3 * self.sample_period:.0f} ms at {self.frequency:.0f} Hz), at most 1 s"
            )
        child = self._live()
        rid = child.send(
            "pulse",
            output=output,
            width=width_s,
            rest_window=REST_WINDOW_S,
            rest_tol=REST_TOL_RAD,
            rest_wait=REST_WAIT_S,
        )
        limit = width_s + REST_WAIT_S + self.COMMAND_TIMEOUT
        msg = child.wait(rid, limit)
        if msg is None:
            child.forget(rid)
            self._discard(child)
            raise HardwareError(
                f"the trigger pulse on digital output {output}: the controller did not answer "
                f"within {limit:.0f} s (client killed); restart it, then rerun "
                "with --resume"
            )
        if not msg["ok"]:
            self._refused(child, msg, "the pulse failed")
        v = msg["value"]
        return Pulse(
            output,
            float(v["rise_t"]),
            float(v["fall_t"]),
            float(v["latency_s"]),
            float(v["rest_p2p_rad"]),
            float(v["rise_after_t"]),
            float(v["fall_after_t"]),
        )

    def close(self) -> None:
        with self._gate:
            child, self._child = self._child, None
        if child is not None:
            child.close(3.0)

    def __enter__(self) -> UrRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
