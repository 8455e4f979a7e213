"""A robot in this process: the controller simulator's arm model behind the driver's interface.

:class:`FakeRobot` implements :class:`~quickhealth.station.hardware.robot.Robot` in pure
Python with the same timing model and faults as the controller simulator, for fast unit
tests, the in-process simulated cell of the TUI and the planner's dry run.  It is a fake at
the hardware boundary: the driver never imports it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...identify.jointload import JointThermal, drive_torques, joint_power, torque_constant
from ...identify.robot import RobotModel, ur5
from ..hardware.robot import (
    RECOVERY_HINT,
    ConnectionLost,
    JointSample,
    JointSensors,
    Leg,
    MoveStopped,
    ProgramStopped,
    ProtectiveStop,
    ReadOnly,
    RobotReader,
    RobotStatus,
    StreamFrozen,
    check_move,
)
from ..hardware.urtypes import RobotMode, SafetyMode
from .arm import HOME_Q_DEG, Arm

F = NDArray[np.float64]

AMBIENT_C = 25.0  # the air around the fake arm (°C), as the controller simulator's


class FakeRobot:
    """A robot in this process: the simulator's arm model, a settable clock speed, faults.

    Parameters
    ----------
    q0 : array, rad
        Start joints.
    time_scale : float
        Motions run this many times faster than on the real arm (tests use 20–100).
    truth : callable, optional
        ``q -> T_instr_flange`` of the simulated world (for :mod:`cameras`).

    Faults: :meth:`inject` ``("protective_stop" | "connection_drop" | "frozen_stream" |
    "program_stop", after_moves=n)``.
    """

    def __init__(
        self,
        q0: ArrayLike | None = None,
        *,
        time_scale: float = 1.0,
        model: RobotModel | None = None,
        truth: Callable[[F], F] | None = None,
        stale_after: float = 0.5,
    ) -> None:
        self.model = model or ur5()
        q0 = np.radians(HOME_Q_DEG) if q0 is None else np.asarray(q0, dtype=float)
        self.arm = Arm(self.model, q0, truth=truth)
        self.time_scale = float(time_scale)
        self.stale_after = stale_after
        self._t0 = time.monotonic()
        self.safety_mode = SafetyMode.NORMAL
        self.robot_mode = RobotMode.RUNNING
        self.program_running = True
        self.connected = True
        self.frozen_at: float | None = None
        self.n_moves = 0
        self._faults: list[tuple[str, int]] = []
        self.moves: list[tuple[F, Leg]] = []
        # the controller's stream in simulated time: 125 Hz (CB3) or 500 Hz (e-Series)
        self.sample_period = 1.0 / (self.model.control_hz or 125.0) / self.time_scale
        self._halted = threading.Event()
        # the joints' temperatures, on the simulated clock (the controller simulator's model)
        self._thermal = JointThermal.start(self.model.n_joints, AMBIENT_C)
        self._thermal_at: tuple[float, F] = (self.now(), self.arm.actual(self.now()))
        self._thermal_lock = threading.Lock()

    def now(self) -> float:
        """Simulated controller time, s."""
        return (time.monotonic() - self._t0) * self.time_scale

    def inject(self, kind: str, *, after_moves: int = 0) -> None:
        """Fault at the start of move number ``n_moves + after_moves + 1`` (0: now)."""
        if kind not in ("protective_stop", "connection_drop", "frozen_stream", "program_stop"):
            raise ValueError(f"unknown fault {kind!r}")
        if after_moves <= 0:
            self._apply(kind)
        else:
            self._faults.append((kind, self.n_moves + after_moves))

    def _apply(self, kind: str) -> None:
        self.arm.halt(self.now())
        if kind == "protective_stop":
            self.safety_mode = SafetyMode.PROTECTIVE_STOP
            self.program_running = False
        elif kind == "connection_drop":
            self.connected = False
        elif kind == "frozen_stream":
            self.frozen_at = self.now()
        elif kind == "program_stop":
            self.program_running = False

    def release(self) -> None:
        """Clear every fault (the technician released the stop, the network is back)."""
        self.safety_mode = SafetyMode.NORMAL
        self.program_running = True
        self.connected = True
        self.frozen_at = None

    def _check_stream(self) -> float:
        if not self.connected:
            raise ConnectionLost("lost the RTDE connection to the fake robot; rerun with --resume")
        if self.frozen_at is not None:
            raise StreamFrozen(
                "the controller's RTDE stream froze: restart the controller, then rerun with --resume"
            )
        return self.now()

    def joints(self) -> F:
        return self.arm.actual(self._check_stream())

    def sample(self) -> JointSample:
        t = self._check_stream()
        return JointSample(t, self.arm.actual(t))

    def tcp_pose(self) -> F:
        return self.model.fk(self.joints())

    def status(self) -> RobotStatus:
        return RobotStatus(
            self.robot_mode, self.safety_mode, self.program_running, connected=self.connected
        )

    def joint_sensors(self) -> JointSensors:
        """Each joint's temperature (warmed since the last call by the torque it held and the
        way it moved, :mod:`~quickhealth.identify.jointload`) and the torque its drive holds
        the model's masses with (None for a model without masses)."""
        t = self._check_stream()
        q = self.arm.actual(t)
        has = self.model.masses is not None and self.model.coms is not None
        tau = drive_torques(self.model, q)[0] if has else None
        with self._thermal_lock:
            t0, q0 = self._thermal_at
            dt = t - t0
            if dt > 0:
                held = tau if tau is not None else np.zeros_like(q)
                kt = torque_constant(self.model)
                power = joint_power(held / kt, held, (q - q0) / dt)
                self._thermal.advance(dt, power, AMBIENT_C)
                self._thermal_at = (t, q)
            temps = self._thermal.temps.copy()
        return JointSensors(temps, tau, "the model's masses held against gravity (simulated)")

    def reader(self) -> RobotReader:
        return ReadOnly(self)

    def move(
        self, q: ArrayLike, leg: Leg = Leg.JOINT, *, speed: float = 1.0, accel: float = 1.4
    ) -> None:
        q, leg, speed, accel = check_move(self.model, q, leg, speed, accel)
        self._check_stream()
        self.n_moves += 1
        for kind, at in list(self._faults):
            if at <= self.n_moves:
                self._faults.remove((kind, at))
                self._apply(kind)
        self._raise_unless_ready()
        if self._halted.is_set():
            raise MoveStopped("the arm was stopped (abort): the move was not sent")
        self.moves.append((q, leg))
        if leg is Leg.JOINT:
            m = self.arm.move_joint(q, speed, accel, self.now())
        else:
            m = self.arm.move_joint(q, speed * 3.0, accel * 3.0, self.now())  # ≈ tool speed
        if self._halted.wait(max(m.duration / self.time_scale, 0.0)):
            raise MoveStopped("the move was stopped by the operator")
        self.arm.target(self.now())

    def _raise_unless_ready(self) -> None:
        self._check_stream()
        if self.safety_mode is not SafetyMode.NORMAL:
            raise ProtectiveStop(f"the move did not finish: protective stop; {RECOVERY_HINT}")
        if not self.program_running:
            raise ProgramStopped(
                "the move did not finish: the control program stopped; rerun with --resume"
            )

    def stop(self) -> None:
        """Halt the arm where it is and refuse moves until :meth:`clear_stop` (as UrRobot)."""
        self._halted.set()
        self.arm.halt(self.now())

    def clear_stop(self) -> None:
        """Allow moves again after :meth:`stop`."""
        self._halted.clear()

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> FakeRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
