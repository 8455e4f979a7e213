"""Programs on the simulated controller: a URScript program run by the interpreter.

:func:`run` is what the controller does with a program that arrives on an interface
(30001, 30002, 30003) or is played from the dashboard:

- ``def rtde_control():`` (ur-rtde's control script) starts the emulated register protocol
  (:mod:`.controller`), as before: it is never interpreted;
- any other ``def``/bare program replaces the running program and runs in its own thread
  (:class:`ProgramHost` answers the interpreter: moves on the controller's arm, registers,
  messages); a compile error stops the old program and starts nothing;
- a ``sec`` program runs beside the main one and may not move the arm or wait.

A move of a program is planned like one of ur-rtde's (the controller's calibrated
kinematics, its joint limits): a move the limits refuse is a protective stop, and the
program pauses; ``play`` after ``unlock protective stop`` retries it.  A paused program
waits; when resumed, an interrupted move goes on to its target.  Blends (``r``) are accepted
and not blended: each move ends at its target.  ``sleep`` and motion run ``speed_factor``
times faster than life, like everything else on a sped-up simulator.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ...identify.urscript import tokenize
from ..hardware.urtypes import RuntimeState, SafetyMode
from .arm import Motion, T_from_pose, joint_path, linear_path, pose_from_T
from .kinematics import check_joint_move, check_path
from .urscript_vm import Halt, Interpreter, Pose, ScriptError, Stopped, compile_program

if TYPE_CHECKING:
    from .controller import Controller

POLL_S = 0.002


def _is_rtde_control(text: str) -> bool:
    """True for ur-rtde's control script (``def rtde_control():`` first)."""
    try:
        toks = tokenize(text[:200].split("\n", 1)[0])
    except Exception:  # noqa: BLE001 - not even its first line tokenizes: not that script
        return False
    return [t.text for t in toks[:2]] == ["def", "rtde_control"]


def run(ctrl: Controller, text: str, source: str) -> None:
    """Run the program ``text`` received on ``source`` (see the module docstring)."""
    if _is_rtde_control(text):
        delay = ctrl.program_start_delay
        if delay > 0:  # a slow controller (fault ``slow_program_start``)
            ctrl.say(f"program starts in {delay:.1f} s")
            time.sleep(delay)
        ctrl.start_program()
        return
    secondary = text.lstrip().startswith("sec")
    try:
        prog = compile_program(text)
    except ScriptError as exc:
        with ctrl.lock:
            if not secondary and ctrl.runtime_state != RuntimeState.STOPPED:
                ctrl.stop_program()
            ctrl.program_error = exc.describe()
            ctrl.message("runtime_exception", exc.describe(), exc.line, exc.col)
        return
    if secondary:
        host = ProgramHost(ctrl, -1, secondary=True)
        threading.Thread(target=_run_thread, args=(ctrl, prog, host), daemon=True).start()
        return
    with ctrl.lock:
        if not ctrl.start_program("urscript", prog.name):
            why = (
                "the robot is in a safety stop"
                if ctrl.safety_mode != SafetyMode.NORMAL
                else f"the robot is not running (robot mode {ctrl.robot_mode.name})"
            )
            ctrl.program_error = f"Runtime error: {prog.name} cannot start: {why}"
            ctrl.message("runtime_exception", ctrl.program_error)
            return
        host = ProgramHost(ctrl, ctrl.program_seq)
    threading.Thread(target=_run_thread, args=(ctrl, prog, host), daemon=True).start()


def _run_thread(ctrl: Controller, prog: Any, host: ProgramHost) -> None:
    vm = Interpreter(prog, host)
    try:
        vm.run()
        outcome = "done"
    except Halt:
        outcome = "halted"
    except Stopped:
        return
    except ScriptError as exc:
        with ctrl.lock:
            if host.current():
                ctrl._runtime_error(exc.message, exc.line, exc.col, kind=exc.kind)
        return
    except Exception as exc:  # noqa: BLE001 - a simulator bug is reported, not swallowed
        with ctrl.lock:
            if host.current():
                ctrl._runtime_error(f"internal: {type(exc).__name__}: {exc}", vm.line)
        return
    if host.secondary:
        return
    with ctrl.lock:
        if host.current():
            ctrl.program_seq += 1
            ctrl.runtime_state = RuntimeState.STOPPED
            ctrl.say(f"program {prog.name} {outcome}")


class ProgramHost:
    """The controller as a running program sees it (:class:`~.urscript_vm.Host`)."""

    def __init__(self, ctrl: Controller, seq: int, secondary: bool = False) -> None:
        self.ctrl = ctrl
        self.seq = seq
        self.secondary = secondary

    # -- program state ----------------------------------------------------------------
    def current(self) -> bool:
        return self.secondary or self.ctrl.program_seq == self.seq

    def check(self) -> None:
        """Raise :class:`Stopped` once the program was stopped; wait while it is paused."""
        ctrl = self.ctrl
        while True:
            if not self.current():
                raise Stopped()
            if self.secondary or ctrl.runtime_state == RuntimeState.PLAYING:
                return
            time.sleep(POLL_S)

    def _no_motion(self, what: str) -> None:
        if self.secondary:
            raise ScriptError("runtime", f"{what} is not allowed in a secondary program")

    # -- motion -----------------------------------------------------------------------
    def move(self, kind: str, target: Any, a: float, v: float, t: float, r: float) -> None:
        self._no_motion(kind)
        ctrl = self.ctrl
        arm = ctrl.arm
        k = ctrl.speed_factor
        while True:
            self.check()
            with ctrl.lock:
                if not ctrl.power.can_move:
                    raise ScriptError(
                        "runtime", f"{kind}: the robot is not running ({ctrl.robot_mode.name})"
                    )
                q0 = arm.hold(ctrl.now())
                lim = ctrl.current_limits()
            path, why = self._plan(kind, target, q0, a, v, lim)
            with ctrl.lock:
                if not self.current() or ctrl.runtime_state != RuntimeState.PLAYING:
                    continue
                if why is not None:
                    ctrl._protective_stop(why)
                    continue
                assert path is not None
                m = Motion.timed(path, v * k, a * k * k, ctrl.now())
                if t > 0:
                    m.duration = max(m.duration, t / k)
                arm.start(m)
                ctrl.n_moves += 1
                ctrl.next_part()
            if self._wait(m):
                return

    def _plan(
        self, kind: str, target: Any, q0: np.ndarray, a: float, v: float, lim: Any
    ) -> tuple[Any, str | None]:
        ctrl, arm = self.ctrl, self.ctrl.arm
        if kind == "movej":
            if isinstance(target, Pose):
                q = ctrl.inverse_kin(list(target), list(q0))
                if q is None:
                    raise ScriptError("runtime", "movej(): no inverse kinematics solution")
            else:
                q = list(target)
            why = check_joint_move(lim, q0, np.asarray(q), v, a)
            return (None, why) if why else (joint_path(q0, np.asarray(q)), None)
        # movel, movep: the TCP on a straight line (to the pose of joint targets)
        q_goal = None if isinstance(target, Pose) else np.asarray(target)
        if q_goal is not None:
            j = lim.outside(q_goal)
            if j is not None:
                return None, f"joint position limit: joint {j + 1} target outside its range"
            T = arm.robot.fk(q_goal) @ arm.tcp
        else:
            T = T_from_pose(np.asarray(target))
            if ctrl.inverse_kin(list(target), list(q0)) is None:
                return None, "inverse kinematics: the target pose is out of reach"
        path = linear_path(arm.robot, arm.tcp, q0, T, q_goal, arm.ik_model)
        why = check_path(arm.robot, arm.tcp, lim, path, T, v, a)
        return (None, why) if why else (path, None)

    def _wait(self, m: Motion) -> bool:
        """Wait for motion ``m``; True when it finished, False when interrupted (paused,
        stopped, protective stop: :meth:`check` decides what follows)."""
        ctrl, arm = self.ctrl, self.ctrl.arm
        while True:
            time.sleep(POLL_S)
            with ctrl.lock:
                now = ctrl.now()
                arm.target(now)  # completes the motion when it is done
                if arm.motion is m:
                    if self.current() and ctrl.runtime_state == RuntimeState.PLAYING:
                        continue
                    return False
                return m.fraction(now) >= 1.0 and bool(
                    np.allclose(arm.q_cmd, m.path[-1], atol=1e-12)
                )

    def sleep(self, seconds: float) -> None:
        self._no_motion("sleep")
        end = time.monotonic() + seconds / self.ctrl.speed_factor
        while True:
            self.check()
            left = end - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(left, 0.01))

    def sync(self) -> None:
        self._no_motion("sync")
        time.sleep(self.ctrl.step_s)
        self.check()

    def steptime(self) -> float:
        return self.ctrl.step_s

    # -- messages, I/O, registers -----------------------------------------------------
    def textmsg(self, text: str) -> None:
        self.ctrl.message("text", text)

    def popup(self, text: str, title: str, warning: bool, error: bool, blocking: bool) -> None:
        ctrl = self.ctrl
        with ctrl.lock:
            ctrl.popup_text = text
        ctrl.message("popup", f"{title}: {text}")
        while blocking and ctrl.popup_text is not None:
            self.check()
            time.sleep(0.01)

    def digital_out(self, index: int, value: bool) -> None:
        with self.ctrl.lock:  # at the next controller cycle, as an RTDE input would
            self.ctrl.io.set(index, value, self.ctrl.next_cycle(self.ctrl.now()))

    def register(self, kind: str, index: int, value: Any = None) -> Any:
        name = {
            "output_int": "output_int_register_",
            "output_float": "output_double_register_",
            "output_bit": "output_bit_register_",
            "input_int": "input_int_register_",
            "input_float": "input_double_register_",
            "input_bit": "input_bit_register_",
        }[kind] + str(index)
        with self.ctrl.lock:
            if kind.startswith("output"):
                self.ctrl.outputs[name] = value
                return None
            v = self.ctrl.inputs.get(name)
        if kind == "input_int":
            return int(v or 0)
        if kind == "input_float":
            return float(v or 0.0)
        return bool(v)

    # -- kinematics (the controller's calibrated model) -------------------------------
    def actual_q(self) -> list[float]:
        return list(map(float, self.ctrl.arm.actual(self.ctrl.now())))

    def actual_tcp_pose(self) -> list[float]:
        return self.ctrl.arm.tcp_pose(self.ctrl.arm.actual(self.ctrl.now()))

    def target_tcp_pose(self) -> list[float]:
        q, _ = self.ctrl.arm.target(self.ctrl.now())
        return self.ctrl.arm.tcp_pose(q)

    def inverse_kin(self, pose: list[float], qnear: list[float] | None) -> list[float] | None:
        return self.ctrl.inverse_kin(pose, qnear)

    def forward_kin(self, q: list[float] | None, tcp: list[float] | None) -> list[float]:
        return self.ctrl.forward_kin(q, tcp)

    def set_tcp(self, pose: list[float]) -> None:
        with self.ctrl.lock:
            self.ctrl.arm.tcp = T_from_pose(pose)

    def set_payload(self, mass: float, cog: list[float] | None) -> None:
        with self.ctrl.lock:
            self.ctrl.set_payload(mass, cog)

    def pose_of(self, q: list[float]) -> list[float]:  # pragma: no cover - helper
        return pose_from_T(self.ctrl.arm.robot.fk(np.asarray(q)) @ self.ctrl.arm.tcp)
