"""The cell behind the TUI: devices, pre-flight and run control around ``station.run``.

:class:`CellControl` wraps a :class:`quickhealth.station.station.Station` (robot, pan motor,
stereo camera) and one run folder.  It turns ``run_plan``'s progress events into the per-pose
table the Run screen shows, and adds what a person at the station needs:

- **pause**: the run stops cleanly after the current pose (``run_plan``'s ``cancel``), the
  worker waits, and **resume** continues the same run folder (``resume=True``);
- **abort**: the robot is stopped *first*, then the run ends after the current pose; every
  captured pose stays in the journal and ``r`` later continues without repeating one;
- **faults** (lost connection, protective stop, frozen stream): the run stops, the fault is
  classified from the robot's own status and shown with what to do; after the technician
  fixes it, :meth:`reconnect` checks the robot is back and the run resumes.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ...identify.errors import HardwareError, QuickhealthError
from ..hardware.robot import Robot
from ..planning.planfile import Plan
from ..run.journal import JOURNAL, JournalState, read_journal
from ..run.loop import run_plan
from ..run.preflight import preflight
from ..run.progress import Progress, ProgressKind
from ..run.settings import RunSettings
from ..station import Station as Hardware
from .views import CellState, Check, Connection, Fault, PoseStatus, Preflight, RunProgress

WHAT_TO_DO = {
    "connection-lost": "check the network cable and the power of the robot controller; "
    "wait until its screen is up",
    "protective-stop": "make the cell safe, then release the protective stop on the teach "
    "pendant and start the control program again",
    "frozen-stream": "the controller stopped streaming: restart its RTDE interface "
    "(or the controller)",
    "program-stopped": "start the control program on the teach pendant again",
    "stop-unconfirmed": "press the emergency stop now and check the arm; then find why the "
    "controller could not be reached",
    "error": "read the message, fix the cause",
}
PREFLIGHT_ORDER = ("robot", "plan", "home", "cameras", "pan motor", "disk")


def classify(robot: Robot, message: str) -> Fault:
    """What stopped the run, from the robot's own status (the message is kept as said)."""
    kind = "error"
    try:
        st = robot.status()
        if not st.connected:
            kind = "connection-lost"
        elif st.safety_mode.name not in ("NORMAL", "REDUCED"):
            kind = "protective-stop"
        elif not st.program_running:
            kind = "program-stopped"
    except Exception:  # the status itself is unreachable: the connection is gone
        kind = "connection-lost"
    if kind == "error" and "froze" in message:
        kind = "frozen-stream"
    for cli_hint in (
        ", then rerun with --resume",
        "; rerun with --resume",
        " then rerun with --resume",
    ):
        message = message.replace(cli_hint, "")
    words = {
        "connection-lost": "Lost the connection to the robot controller",
        "protective-stop": "The robot is in a protective stop",
        "frozen-stream": "The controller's data stream froze",
        "program-stopped": "The control program on the robot stopped",
        "error": "The run stopped",
    }[kind]
    return Fault(kind, f"{words}: {message}", WHAT_TO_DO[kind])


class CellControl:
    """Devices and run control of one run folder (thread-safe control methods)."""

    def __init__(
        self,
        station: Hardware,
        plan: Plan,
        run_dir: Path,
        *,
        settings: RunSettings | None = None,
        on_finished: Callable[[Path], None] | None = None,
    ) -> None:
        self.station = station
        self.plan = plan
        self.run_dir = Path(run_dir)
        self.settings = settings or RunSettings()
        self.on_finished = on_finished
        self._cancel = threading.Event()
        self._wake = threading.Event()
        self._abort = False
        self._lock = threading.Lock()
        self.running = False
        self.paused = False
        self.state = CellState.IDLE
        self.fault: Fault | None = None
        self._status: dict[int, PoseStatus] = {}
        self._t_pose: list[float] = []
        self._t_last: float | None = None
        self._current: PoseStatus | None = None
        self._last: PoseStatus | None = None
        self._load_journal()

    # ----- devices ---------------------------------------------------------------------------
    def connect(self) -> None:
        """Reconnect what lost its link (the robot's ur-rtde client); idempotent."""
        connect = getattr(self.station.robot, "connect", None)
        if callable(connect):
            connect()

    def connections(self) -> tuple[Connection, ...]:
        """Robot mode and safety, camera and pan motor, each tried now."""
        s = self.station
        out = []
        try:
            st = s.robot.status()
            state = "ok" if st.ready else ("down" if not st.connected else "warn")
            out.append(
                Connection("robot", state, f"{s.robot_name or s.robot.model.name}: {st.describe()}")
            )
        except Exception as exc:
            out.append(Connection("robot", "down", str(exc)))
        try:
            rig = s.camera.rig
            w, h = rig.left.image_size
            out.append(Connection("stereo camera", "ok", f"{s.instrument}, {w}×{h} px"))
        except Exception as exc:
            out.append(Connection("stereo camera", "down", str(exc)))
        try:
            s.motor.ping()
            out.append(
                Connection(
                    "pan motor", "ok", f"answers, at {math.degrees(s.motor.position()):.1f}°"
                )
            )
        except Exception as exc:
            out.append(Connection("pan motor", "down", str(exc)))
        return tuple(out)

    def preflight(self) -> Preflight:
        """``station.run.preflight.preflight`` (it captures one frame, pings the motor; nothing moves)."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        resume = (self.run_dir / JOURNAL).is_file()
        remaining = sum(1 for p in self.plan.poses if p.index not in self._done_indices())
        checks: list[Check] = []
        try:
            lines = preflight(
                self.station, self.plan, self.run_dir, remaining, self.settings, resume=resume
            )
        except (QuickhealthError, OSError) as exc:
            lines, failure = [], str(exc).removeprefix("pre-flight: ")
        else:
            failure = None
        for ln in lines:
            name, sep, why = ln.partition(": ")
            if not sep:  # a sentence without a "name: " head, e.g. "robot at the plan's home …"
                name, why = ("home" if "home" in ln else "check"), ln
            checks.append(Check(name, True, why))
        if failure is not None:
            done = {c.name for c in checks}
            todo = [n for n in PREFLIGHT_ORDER if n not in done]
            name = next(
                (n for n in todo if n.split()[-1] in failure.lower()), todo[0] if todo else "check"
            )
            checks.append(Check(name, False, failure))
            checks += [
                Check(n, False, "not checked: an earlier check failed") for n in todo if n != name
            ]
        return Preflight(tuple(checks))

    # ----- per-pose table --------------------------------------------------------------------
    def _done_indices(self) -> set[int]:
        return {i for i, p in self._status.items() if p.status in ("done", "failed", "measuring")}

    def _load_journal(self) -> None:
        """Statuses from an existing journal (a run continued after a restart of the TUI)."""
        for p in self.plan.poses:
            self._status[p.index] = PoseStatus(p.index - 1, p.name, "pending")
        path = self.run_dir / JOURNAL
        if path.is_file():
            st = read_journal(path)
            for i in st.captured:
                self._status[i] = self._from_journal(st, i)
            for i in st.failed:
                self._status[i] = self._from_journal(st, i)

    def _from_journal(self, st: JournalState, index: int) -> PoseStatus:
        name = self._status[index].pose_id
        cap = st.captured.get(index)
        mea = st.measured.get(index)
        fail = st.failed.get(index)
        q_rad = cap.q if cap is not None else (fail.q if fail is not None else None)
        q = () if q_rad is None else tuple(float(v) for v in np.degrees(q_rad))
        markers = sum(cap.markers) if cap is not None else None
        if fail is not None:
            return PoseStatus(index - 1, name, "failed", q, reason=fail.reason)
        if mea is None:
            return PoseStatus(index - 1, name, "measuring", q, markers)
        if not mea.ok:
            return PoseStatus(index - 1, name, "failed", q, markers, reason=mea.reason)
        rms = float("nan") if mea.rms_px is None else float(mea.rms_px)
        return PoseStatus(index - 1, name, "done", q, markers, rms)

    def pose_table(self) -> tuple[PoseStatus, ...]:
        with self._lock:
            return tuple(self._status[p.index] for p in self.plan.poses)

    # ----- the run ---------------------------------------------------------------------------
    def _snapshot(self) -> RunProgress:
        with self._lock:
            n = len(self.plan.poses)
            done = sum(1 for p in self._status.values() if p.status in ("done", "failed"))
            left = n - done
            eta = None
            if self._t_pose:
                per = sum(self._t_pose[-5:]) / len(self._t_pose[-5:])
                eta = per * left
            return RunProgress(
                self.state, done, n, eta, self._current, self._last, str(self.run_dir), self.fault
            )

    def _on_event(self, ev: Progress, emit: Callable[[RunProgress], None]) -> None:
        if ev.index <= 0 or ev.index not in self._status:
            return
        if ev.kind == ProgressKind.MOVE:
            now = time.monotonic()
            with self._lock:
                if self._t_last is not None:
                    self._t_pose.append(now - self._t_last)
                self._t_last = now
                q = tuple(float(v) for v in self.plan.poses[ev.index - 1].q * 57.29577951308232)
                ps = PoseStatus(ev.index - 1, ev.name, "moving", q)
                self._status[ev.index] = ps
                self._current = ps
        elif ev.kind in (ProgressKind.POSE, ProgressKind.MEASURED):
            st = read_journal(self.run_dir / JOURNAL)
            ps = self._from_journal(st, ev.index)
            if ev.kind == ProgressKind.POSE and ev.status == "failed":
                ps = PoseStatus(
                    ps.index, ps.pose_id, "failed", ps.q_deg, ps.markers, reason=ev.message
                )
            with self._lock:
                self._status[ev.index] = ps
                if ps.status in ("done", "failed"):
                    self._last = ps
                if self._current is not None and self._current.index == ps.index:
                    self._current = ps
        else:
            return
        emit(self._snapshot())

    def run(self, emit: Callable[[RunProgress], None]) -> RunProgress:
        """Run (or continue) the plan until it finishes, is aborted or a fault stops it.

        Blocks (call it from a worker); pauses wait inside.  Returns the final progress.
        """
        with self._lock:
            if self.running:
                raise HardwareError("the run is already going")
            self.running, self.paused, self._abort = True, False, False
            self.fault = None
            self._cancel.clear()
            self.state = CellState.RUNNING
        emit(self._snapshot())
        try:
            while True:
                resume = (self.run_dir / JOURNAL).is_file()
                try:
                    res = run_plan(
                        self.station,
                        self.plan,
                        self.run_dir,
                        resume=resume,
                        settings=self.settings,
                        progress=lambda ev: self._on_event(ev, emit),
                        cancel=self._cancel,
                    )
                except QuickhealthError as exc:  # pre-flight refused: nothing moved
                    self.fault = classify(self.station.robot, str(exc))
                    self.state = CellState.FAULT
                    break
                if res.stopped is None:
                    self.state = CellState.FINISHED
                    break
                if self._abort:
                    self.state = CellState.ABORTED
                    break
                if self._cancel.is_set():  # paused: wait for resume or abort
                    self.state = CellState.PAUSED
                    emit(self._snapshot())
                    self._wake.wait()
                    self._wake.clear()
                    self._cancel.clear()
                    if self._abort:
                        self.state = CellState.ABORTED
                        break
                    self.paused = False
                    self.state = CellState.RUNNING
                    emit(self._snapshot())
                    continue
                self.fault = classify(self.station.robot, res.stopped)
                self.state = CellState.FAULT
                break
        finally:
            with self._lock:
                self.running = False
                self.paused = False
                self._current = None
                for i, ps in self._status.items():  # a move that did not finish: still to do
                    if ps.status == "moving":
                        self._status[i] = PoseStatus(ps.index, ps.pose_id, "pending")
        if (self.run_dir / "measurements.csv").is_file() and self.on_finished is not None:
            self.on_finished(self.run_dir / "measurements.csv")
        final = self._snapshot()
        emit(final)
        return final

    def exclusive(self, work: Callable[[Hardware, threading.Event], object]) -> object:
        """Run ``work(station, cancel)`` with the devices to itself (a quick check): refused
        while the run goes; ``abort`` stops the robot and sets ``cancel``."""
        with self._lock:
            if self.running:
                raise HardwareError("the run is going: the devices are the run's")
            self.running, self._abort = True, False
            self._cancel.clear()
            self.state = CellState.RUNNING
        try:
            return work(self.station, self._cancel)
        finally:
            with self._lock:
                self.running = False
                self.state = CellState.ABORTED if self._abort else CellState.IDLE

    def pause(self) -> None:
        """Stop after the current pose and wait (the journal keeps everything)."""
        with self._lock:
            if self.running and not self.paused:
                self.paused = True
                self._cancel.set()

    def resume(self) -> None:
        """Continue a paused run."""
        with self._lock:
            if self.paused:
                self._wake.set()

    def abort(self) -> None:
        """Stop the robot now, then end the run (blocks up to a second: call from a worker).

        The robot's stop jumps its owner's queue, ends the move under way and refuses any
        move sent after it until the run is started again; the run then ends at once.

        A stop the robot could not confirm raises its HardwareError and stays as the fault
        shown with the aborted run: the arm may still be moving."""
        try:
            self.station.robot.stop()
        except HardwareError as exc:
            with self._lock:
                self.fault = Fault(
                    "stop-unconfirmed",
                    f"The stop was not confirmed: {exc}",
                    WHAT_TO_DO["stop-unconfirmed"],
                )
            raise
        finally:
            with self._lock:
                self._abort = True
                self._cancel.set()
                self._wake.set()

    def reconnect(self) -> None:
        """After a fault: reconnect and check the robot is connected, powered and safe.

        After a link fault (lost connection, frozen stream) the robot's client is always
        replaced, whatever the old one still believes; otherwise only a dead one is."""
        link = self.fault is not None and self.fault.kind in ("connection-lost", "frozen-stream")
        again = getattr(self.station.robot, "reconnect", None)
        if link and callable(again):
            again()
        else:
            self.connect()
        st = self.station.robot.status()
        if not st.ready:
            raise HardwareError(f"robot not ready: {st.describe()}")
        with self._lock:
            self.fault = None
            if self.state == CellState.FAULT:
                self.state = CellState.IDLE

    def close(self) -> None:
        """Stop the arm if it moves, end the run, release the hardware."""
        if self.running:
            self.abort()
        self.station.close()
