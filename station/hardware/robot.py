"""The robot behind a small interface: a reader that cannot move the arm, and a commander.

- :class:`RobotReader` — joints, TCP pose, controller time, robot mode and safety status.
- :class:`Robot` — a reader that also moves (joint or linear leg to a joint target) and stops.
- :class:`UrRobot` — the adapter on ur-rtde (``rtde_receive`` + ``rtde_control``), imported
  lazily.  Moves are sent asynchronously and watched here, so a protective stop, a lost
  connection or a frozen RTDE stream ends the move within a fraction of a second with a
  :class:`~quickhealth.identify.errors.HardwareError` that says what to do, never a hang.
- :class:`FakeRobot` — pure Python, same timing model as the controller simulator, with the
  same faults; for fast unit tests.

Every move is checked before it is sent: six finite joint angles inside the robot's limits,
speeds and accelerations positive and bounded.  Only these numbers reach the controller.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quickhealth.identify.errors import HardwareError, InputError
from quickhealth.identify.robot import RobotModel, ur5

from .urtypes import RobotMode, SafetyMode

F = NDArray[np.float64]

MAX_JOINT_SPEED = 3.14  # rad/s, UR5 joint limit
MAX_JOINT_ACCEL = 40.0  # rad/s²
MAX_TOOL_SPEED = 3.0  # m/s
MAX_TOOL_ACCEL = 150.0  # m/s²


class Leg(Enum):
    """How the robot travels to a pose (the plan's ``leg``)."""

    JOINT = "joint"
    LINEAR = "linear"


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
        """Decelerate the arm to rest now."""
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


def _pose_to_T(p: ArrayLike) -> F:
    from quickhealth.identify.transforms import exp_so3, make_T

    p = np.asarray(p, dtype=float)
    return make_T(exp_so3(p[3:6]), p[:3])


# ---------------------------------------------------------------------------------------
# ur-rtde adapter
# ---------------------------------------------------------------------------------------

RECOVERY_HINT = "clear the cause, release the stop on the teach pendant, then rerun with --resume"


class UrRobot:
    """A UR robot over ur-rtde (CB3 or e-Series).

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

    def __init__(
        self,
        host: str,
        *,
        frequency: float = 125.0,
        stale_after: float = 0.5,
        move_timeout: float = 120.0,
        model: RobotModel | None = None,
    ) -> None:
        try:
            import rtde_control
            import rtde_receive
        except ImportError as exc:  # pragma: no cover - ur-rtde is a dependency
            raise HardwareError(f"ur-rtde is not installed ({exc})") from None
        self.model = model or ur5()
        self.host = host
        self.stale_after = stale_after
        self.move_timeout = move_timeout
        self.command_timeout = 5.0  # s for a command to be acknowledged
        self._stuck = False
        self._rc = None
        try:
            self._rr = rtde_receive.RTDEReceiveInterface(host, frequency)
        except RuntimeError as exc:
            raise ConnectionLost(
                f"cannot connect to the robot controller at {host}: {exc}"
            ) from None
        try:
            self._rc = rtde_control.RTDEControlInterface(host, frequency)
        except RuntimeError as exc:
            self._rr.disconnect()
            raise ConnectionLost(
                f"cannot start the control interface at {host}: {exc} "
                "(is the robot in remote control and the dashboard server reachable?)"
            ) from None
        self._last_ts = (-1.0, time.monotonic())

    # -- reading ---------------------------------------------------------------------------
    def _check_stream(self) -> float:
        if not self._rr.isConnected():
            raise ConnectionLost(
                f"lost the RTDE connection to {self.host}: check the network cable and the "
                f"controller, then rerun with --resume"
            )
        ts = float(self._rr.getTimestamp())
        last, since = self._last_ts
        now = time.monotonic()
        if ts != last:
            self._last_ts = (ts, now)
        elif now - since > self.stale_after:
            raise StreamFrozen(
                f"the controller's RTDE stream froze (timestamp {ts:.3f} s unchanged for "
                f"{now - since:.1f} s): restart the controller, then rerun with --resume"
            )
        return ts

    def joints(self) -> F:
        self._check_stream()
        return np.asarray(self._rr.getActualQ(), dtype=float)

    def sample(self) -> JointSample:
        ts = self._check_stream()
        return JointSample(ts, np.asarray(self._rr.getActualQ(), dtype=float))

    def tcp_pose(self) -> F:
        self._check_stream()
        return _pose_to_T(self._rr.getActualTCPPose())

    def status(self) -> RobotStatus:
        if not self._rr.isConnected():
            return RobotStatus(RobotMode.UNKNOWN, SafetyMode.UNKNOWN, False, connected=False)
        return RobotStatus(
            _enum(RobotMode, self._rr.getRobotMode()),  # type: ignore[arg-type]
            _enum(SafetyMode, self._rr.getSafetyMode()),  # type: ignore[arg-type]
            int(self._rr.getRuntimeState()) == 2,
        )

    def reader(self) -> RobotReader:
        return ReadOnly(self)

    # -- commanding ------------------------------------------------------------------------
    def move(
        self, q: ArrayLike, leg: Leg = Leg.JOINT, *, speed: float = 1.0, accel: float = 1.4
    ) -> None:
        q, leg, speed, accel = check_move(self.model, q, leg, speed, accel)
        self._check_ready()
        qs = [float(v) for v in q]
        fn = self._rc.moveJ if leg is Leg.JOINT else self._rc.moveL_FK
        ok = self._call("the move", fn, qs, speed, accel, True)
        if not ok:
            self._raise_for_state("the controller refused the move")
        self._wait_move(q)

    def _wait_move(self, q: F) -> None:
        t0 = time.monotonic()
        idle_since: float | None = None
        time.sleep(0.01)
        while True:
            self._check_stream()
            st = self.status()
            if not st.ready or not st.program_running:
                self._raise_for_state("the move did not finish")
            progress = self._rc.getAsyncOperationProgress()
            if progress < 0:
                qa = np.asarray(self._rr.getTargetQ(), dtype=float)
                if np.max(np.abs(qa - q)) < 1e-4:
                    return
                # Not there yet: the two RTDE connections may lag each other by a packet, or
                # the progress register still shows the previous move.  Persisting = stopped.
                if idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > 0.25:
                    self._raise_for_state("the move ended away from its target")
            else:
                idle_since = None
            if time.monotonic() - t0 > self.move_timeout:
                self.stop()
                raise HardwareError(
                    f"a move took longer than {self.move_timeout:.0f} s: check the robot"
                )
            time.sleep(0.004)

    def _check_ready(self) -> None:
        self._check_stream()
        st = self.status()
        if not st.ready:
            self._raise_for_state("the robot is not ready")
        if not st.program_running:
            # The control script stopped (e.g. after a released protective stop): restart it.
            self._call("restart the control program", self._rc.reuploadScript)
            deadline = time.monotonic() + 5.0
            while not self._rc.isProgramRunning():
                if time.monotonic() > deadline:
                    raise ProgramStopped("the control program on the robot does not start")
                time.sleep(0.01)

    def _call(self, what: str, fn: Callable[..., object], *args: object) -> object:
        """Call a ur-rtde command that may block (it waits for the controller's answer) in a
        helper thread, and watch the stream meanwhile: a frozen or lost stream ends the wait
        with the right error instead of the client's 300 s timeout."""
        import threading

        box: dict[str, object] = {}

        def run() -> None:
            try:
                box["value"] = fn(*args)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
                box["error"] = exc

        th = threading.Thread(target=run, daemon=True, name="ur-rtde-call")
        th.start()
        deadline = time.monotonic() + self.command_timeout
        while True:
            th.join(0.02)
            if not th.is_alive():
                break
            try:
                self._check_stream()
            except HardwareError:
                self._stuck = True  # the client thread may never return: close gently
                raise
            if time.monotonic() > deadline:
                self._stuck = True
                raise HardwareError(
                    f"{what}: the controller did not answer within {self.command_timeout:.0f} s; "
                    "restart it, then rerun with --resume"
                )
        if "error" in box:
            err = box["error"]
            raise ConnectionLost(f"{what}: ur-rtde failed ({err}); rerun with --resume")
        return box.get("value")

    def _raise_for_state(self, what: str) -> None:
        # The receive connection may lag the control connection by a packet or two: give the
        # cause a moment to show before settling for a generic message.
        deadline = time.monotonic() + 0.2
        while True:
            self._check_stream()
            st = self.status()
            if not st.ready or not st.program_running or time.monotonic() > deadline:
                break
            time.sleep(0.008)
        st = self.status()
        if not st.connected or not self._rc.isConnected():
            raise ConnectionLost(f"{what}: lost the connection to {self.host}; rerun with --resume")
        if st.safety_mode in (SafetyMode.PROTECTIVE_STOP, SafetyMode.SAFEGUARD_STOP):
            raise ProtectiveStop(
                f"{what}: {st.safety_mode.name.lower().replace('_', ' ')}; {RECOVERY_HINT}"
            )
        if st.safety_mode not in (SafetyMode.NORMAL, SafetyMode.REDUCED):
            raise ProtectiveStop(f"{what}: safety mode {st.safety_mode.name}; {RECOVERY_HINT}")
        if st.robot_mode is not RobotMode.RUNNING:
            raise HardwareError(
                f"{what}: robot mode {st.robot_mode.name}; power on and release the brakes"
            )
        if not st.program_running:
            raise ProgramStopped(
                f"{what}: the control program stopped (stop pressed on the pendant?); "
                "rerun with --resume"
            )
        raise HardwareError(f"{what}: {st.describe()}")

    def stop(self) -> None:
        if self._rc is not None and not self._stuck and self._rc.isConnected():
            try:
                self._call("stop", self._rc.stopJ, 2.0, False)
            except (RuntimeError, HardwareError):
                pass

    def close(self) -> None:
        rc, self._rc = self._rc, None
        if rc is not None:
            if not self._stuck:
                try:
                    if rc.isConnected() and self._rr.isConnected():
                        self._call("stop script", rc.stopScript)
                except (RuntimeError, HardwareError):
                    pass
            self._safe_disconnect(rc)
        self._safe_disconnect(self._rr)

    def _safe_disconnect(self, iface: object) -> None:
        """Disconnect; after a stuck call, in a helper thread that may be abandoned."""
        import threading

        def run() -> None:
            try:
                iface.disconnect()  # type: ignore[attr-defined]
            except RuntimeError:
                pass

        if not self._stuck:
            run()
            return
        th = threading.Thread(target=run, daemon=True, name="ur-rtde-disconnect")
        th.start()
        th.join(3.0)

    def __enter__(self) -> UrRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
