"""The ur-rtde client pair in its own process: the only place that ever calls into ur_rtde.

:class:`~quickhealth.station.hardware.robot.UrRobot` starts this module as a child process
(``python -m quickhealth.station.hardware.ur_client HOST``) and talks to it over its standard
input and output, one JSON object a line.  Inside, each C++ object has exactly one owner
thread, and nothing else ever calls into it:

- the **receiver** thread constructs ``RTDEReceiveInterface`` and polls it every 4 ms into an
  immutable :class:`Snapshot` (joints, modes, the controller's timestamp and how long it has
  stood still);
- the **commander** thread constructs ``RTDEControlInterface`` and executes commands from a
  priority queue, one at a time: ``move`` (sent asynchronously, then watched from the
  snapshots until the controller says it ended), ``stop`` and ``close``;
- the **io** thread constructs ``RTDEIOInterface`` (at the first ``pulse``) and executes the
  pulses on a standard digital output one at a time (:meth:`Client.pulse`: the arm at rest,
  rise, hold, fall, each edge confirmed on the receive stream);
- the **main** thread reads requests.  ``state`` is answered at once from the latest
  snapshot; ``stop`` is queued ahead of everything else and also flags the move being
  watched, which stops the arm within one 4 ms watch cycle (the wait for a re-uploaded
  control program and the last check before a move is sent watch the flag too).  A stop
  cancels every move received before it (a move already on the way when the operator
  aborted never starts).

The stop's reply is a promise kept honestly: ``ok`` only when ``stopJ`` was done and the
stream then shows the controller's target joints standing still, or when the stream shows
that no program drives the arm.  It fails at
once when the link is down or the stream has not advanced for :data:`STOP_STALE_S`, and
when the commander has not begun acting on the stop within :data:`ACT_WITHIN_S` (it is
inside a C++ call that does not return: a handshake on a frozen stream); the parent then
stops the program through the dashboard server instead.

Replies: ``{"id": n, "ok": true, "value": ...}`` or ``{"id": n, "ok": false, "error":
CLASS, "message": TEXT}`` where CLASS names one of the driver's exception classes.  Before
the process ends after ``close`` it writes ``{"id": -2, "ok": true, "value": {"threads":
[...]}}``: the threads still alive then (none, unless one was stuck inside the client).  The
child never needs to be disconnected from another thread: when a C++ call hangs (a
controller that stopped answering) the parent kills the whole process, and the operating
system closes its sockets.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import queue
import sys
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Any

from .ur_io import IoOwner, Refused
from .urtypes import RobotMode, RuntimeState, SafetyMode

POLL_S = 0.004  # receiver and move-watch period, s
ACT_WITHIN_S = 0.05  # s the commander has to begin acting on a stop before the parent is told
STOP_STALE_S = 0.1  # s without new RTDE data after which stopJ cannot be confirmed over RTDE
STOP_DECEL = 4.0  # rad/s², stopJ's deceleration
STOP_CONFIRM_S = 0.5  # s after stopJ returned for the stream to show the target joints still
HISTORY = 512  # joint samples kept for the rest check before a pulse (~2 s at the 4 ms poll)
FAREWELL_ID = -2  # the id of the last line the process writes (its threads' states)
RECOVERY_HINT = "clear the cause, release the stop on the teach pendant, then rerun with --resume"


@dataclass(frozen=True)
class Snapshot:
    """What the receive connection said at its last poll (SI units, UR's mode numbers)."""

    polled: float  # monotonic time of the poll, s (this process's clock)
    connected: bool
    timestamp: float = -1.0  # controller time, s
    still_for: float = 0.0  # s the controller timestamp has not advanced, as of ``polled``
    q: tuple[float, ...] = ()
    target_q: tuple[float, ...] = ()
    tcp_pose: tuple[float, ...] = ()
    robot_mode: int = -1
    safety_mode: int = -1
    runtime_state: int = -1
    joint_temperatures: tuple[float, ...] = ()  # °C, RTDE joint_temperatures
    actual_current: tuple[float, ...] = ()  # A, RTDE actual_current (each joint's motor)
    digital_out: int = 0  # RTDE actual_digital_output_bits (0-7 standard, 8-15 configurable)
    busy: str = ""  # the C++ call the commander is inside, "" when none
    busy_for: float = 0.0  # s it has been inside it

    @property
    def ready(self) -> bool:
        return (
            self.connected
            and self.robot_mode == RobotMode.RUNNING
            and self.safety_mode in (SafetyMode.NORMAL, SafetyMode.REDUCED)
        )

    @property
    def program_running(self) -> bool:
        return self.runtime_state == RuntimeState.PLAYING


@dataclass(order=True)
class _Job:
    priority: int
    seq: int
    req: dict[str, Any] = field(compare=False)


class Client:
    """The owner of one controller's ur-rtde objects (see the module docstring)."""

    OVERSLEEP_S = 0.05  # a poll this much later than planned means we were not running

    def __init__(self, host: str, frequency: float, stale_after: float, move_timeout: float):
        self.host = host
        self.frequency = frequency
        self.stale_after = stale_after
        self.move_timeout = move_timeout
        self.out_lock = threading.Lock()
        self.jobs: queue.PriorityQueue[_Job] = queue.PriorityQueue()
        self.snap = Snapshot(time.monotonic(), False)
        self.closing = threading.Event()
        self.rr_ready = threading.Event()
        self.rr_error: str | None = None
        self.stop_seq = -1  # sequence number of the last stop request
        self.moving_seq = -1  # sequence number of the move being watched
        self.acted = threading.Condition()
        self.stop_acted = -1  # sequence number of the last stop the commander acted on
        # The outcome of the last stop performed, and the request it served: the stop job
        # that follows a stop made by the move watch reports it instead of stopping again.
        self.stop_outcome: tuple[int, str | Refused] = (-1, "")
        self._busy: tuple[str, float] = ("", 0.0)
        self.rc: Any = None
        self._closed_receiver: Any = None  # the receive interface once disconnected
        self.io_jobs: queue.Queue[dict[str, Any]] = queue.Queue()
        self.io: Any = None  # RTDEIOInterface, built by the io thread at its first pulse
        # (controller time, joints) of the receive stream's packets, for the rest check
        self._history: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=HISTORY)
        self._history_lock = threading.Lock()

    # -- output -------------------------------------------------------------------------
    def reply(self, rid: int, value: Any = None, *, error: Refused | None = None) -> None:
        msg: dict[str, Any] = {"id": rid, "ok": error is None}
        if error is None:
            msg["value"] = value
        else:
            msg.update(error=error.kind, message=str(error))
        line = json.dumps(msg, allow_nan=False) + "\n"
        with self.out_lock:
            sys.stdout.write(line)
            sys.stdout.flush()

    # -- receiver thread: the only caller of RTDEReceiveInterface --------------------------
    def receiver(self) -> None:
        import rtde_receive  # the C++ client, in this thread only: its one owner

        try:
            rr = rtde_receive.RTDEReceiveInterface(self.host, self.frequency)
        except RuntimeError as exc:
            self.rr_error = f"cannot connect to the robot controller at {self.host}: {exc}"
            self.rr_ready.set()
            return
        self.rr_ready.set()
        last_ts, changed = -1.0, time.monotonic()
        last_poll = changed
        while not self.closing.is_set():
            now = time.monotonic()
            # Time this thread did not run (a loaded machine descheduled the process) is no
            # evidence against the controller: only time we watched counts towards a freeze.
            missed = now - last_poll - self.OVERSLEEP_S
            if missed > 0:
                changed += missed
            last_poll = now
            busy, since = self._busy
            if rr.isConnected():
                ts = float(rr.getTimestamp())
                q = tuple(rr.getActualQ())
                if ts != last_ts:
                    last_ts, changed = ts, now
                    with self._history_lock:
                        self._history.append((ts, q))
                self.snap = Snapshot(
                    polled=now,
                    connected=True,
                    timestamp=ts,
                    still_for=now - changed,
                    q=q,
                    target_q=tuple(rr.getTargetQ()),
                    tcp_pose=tuple(rr.getActualTCPPose()),
                    robot_mode=int(rr.getRobotMode()),
                    safety_mode=int(rr.getSafetyMode()),
                    runtime_state=int(rr.getRuntimeState()),
                    joint_temperatures=tuple(rr.getJointTemperatures()),
                    actual_current=tuple(rr.getActualCurrent()),
                    digital_out=int(rr.getActualDigitalOutputBits()),
                    busy=busy,
                    busy_for=now - since if busy else 0.0,
                )
            else:
                self.snap = Snapshot(now, False, busy=busy, busy_for=now - since if busy else 0.0)
            time.sleep(POLL_S)
        try:
            rr.disconnect()
        except RuntimeError:
            pass
        # Kept past the thread: ur-rtde's destructor takes another 0.5 s (its io threads),
        # and the process ends with os._exit, which need not wait for it.
        self._closed_receiver = rr

    # -- commander thread: the only caller of RTDEControlInterface -------------------------
    def _cxx(self, what: str, fn: Any, *args: Any) -> Any:
        """Call into the control interface, recording which call we are in (for the parent)."""
        self._busy = (what, time.monotonic())
        try:
            return fn(*args)
        except RuntimeError as exc:
            raise Refused(
                "ConnectionLost", f"{what}: ur-rtde failed ({exc}); rerun with --resume"
            ) from None
        finally:
            self._busy = ("", 0.0)

    def commander(self, started: threading.Event) -> None:
        import rtde_control  # the C++ client, in this thread only: its one owner

        try:
            self.rc = rtde_control.RTDEControlInterface(self.host, self.frequency)
        except RuntimeError as exc:
            self.rr_error = (
                f"cannot start the control interface at {self.host}: {exc} "
                "(is the robot in remote control and the dashboard server reachable?)"
            )
        started.set()
        if self.rc is None:
            return
        while True:
            job = self.jobs.get()
            op, rid = job.req["op"], int(job.req["id"])
            try:
                if op == "move":
                    if job.seq < self.stop_seq:
                        raise Refused(
                            "MoveStopped", "the move was cancelled: the arm was stopped before it"
                        )
                    self.moving_seq = job.seq
                    try:
                        self.move(job.req)
                    finally:
                        self.moving_seq = -1
                    self.reply(rid, True)
                elif op == "stop":
                    answered = self._act(job.seq, job.req)
                    seq, outcome = self.stop_outcome
                    if seq < job.seq:  # not stopped for this request yet: stop now
                        outcome = self._stop_for(job.seq)
                    if answered:
                        pass
                    elif isinstance(outcome, Refused):
                        self.reply(rid, error=outcome)
                    else:
                        self.reply(rid, outcome)
                elif op == "close":
                    self.close_control()
                    self.reply(rid, True)
                    return
                else:
                    raise Refused("HardwareError", f"unknown command {op!r}")
            except Refused as exc:
                self.reply(rid, error=exc)
            except Exception as exc:  # noqa: BLE001 - a bug here must not silence the commander
                self.reply(
                    rid, error=Refused("HardwareError", f"{op}: {type(exc).__name__}: {exc}")
                )

    def _stop_requested(self) -> bool:
        return self.stop_seq > self.moving_seq >= 0

    def _act(self, seq: int, req: dict[str, Any] | None = None) -> bool:
        """Note that the commander acts on stop ``seq`` now; True when the main thread already
        answered that stop (it was not acted on in time)."""
        with self.acted:
            self.stop_acted = max(self.stop_acted, seq)
            self.acted.notify_all()
            return bool(req is not None and req.get("answered"))

    def _stop_for(self, seq: int) -> str | Refused:
        """Stop the arm for stop request ``seq``; the outcome is kept for that request."""
        try:
            outcome: str | Refused = self.stop()
        except Refused as exc:
            outcome = exc
        self.stop_outcome = (seq, outcome)
        return outcome

    def _stop_move(self) -> None:
        """Stop the move being watched on the operator's request (the stop job that follows
        reports whether the stop was confirmed)."""
        seq = self.stop_seq
        self._act(seq)
        self._stop_for(seq)
        raise Refused("MoveStopped", "the move was stopped by the operator")

    def check_stream(self) -> Snapshot:
        s = self.snap
        if not s.connected:
            raise Refused(
                "ConnectionLost",
                f"lost the RTDE connection to {self.host}: check the network cable and the "
                "controller, then rerun with --resume",
            )
        if s.still_for > self.stale_after:
            raise Refused(
                "StreamFrozen",
                f"the controller's RTDE stream froze (timestamp {s.timestamp:.3f} s unchanged for "
                f"{s.still_for:.1f} s): restart the controller, then rerun with --resume",
            )
        return s

    def move(self, req: dict[str, Any]) -> None:
        q = [float(v) for v in req["q"]]
        speed, accel = float(req["speed"]), float(req["accel"])
        self.check_ready()
        if self._stop_requested():  # the stop came while the program was being restarted
            self._stop_move()
        fn = self.rc.moveJ if req["leg"] == "joint" else self.rc.moveL_FK
        if not self._cxx("the move", fn, q, speed, accel, True):
            self.raise_for_state("the controller refused the move")
        t0 = time.monotonic()
        idle_since: float | None = None
        time.sleep(0.01)
        while True:
            if self._stop_requested():
                self._stop_move()
            s = self.check_stream()
            if not s.ready or not s.program_running:
                self.raise_for_state("the move did not finish")
            progress = self._cxx("progress", self.rc.getAsyncOperationProgress)
            if progress < 0:
                if (
                    s.target_q
                    and max(abs(a - b) for a, b in zip(s.target_q, q, strict=True)) < 1e-4
                ):
                    return
                # Not there yet: the two RTDE connections may lag each other by a packet, or
                # the progress register still shows the previous move.  Persisting = stopped;
                # but a stream that does not advance says nothing (the client reads a progress
                # register whose write counter stands still as "idle"): the freeze check decides.
                if s.still_for > STOP_STALE_S:
                    idle_since = None
                elif idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > 0.25:
                    self.raise_for_state("the move ended away from its target")
            else:
                idle_since = None
            if time.monotonic() - t0 > self.move_timeout:
                try:
                    self.stop()
                except Refused:
                    pass
                raise Refused(
                    "HardwareError",
                    f"a move took longer than {self.move_timeout:.0f} s: check the robot",
                )
            time.sleep(POLL_S)

    def check_ready(self) -> None:
        s = self.check_stream()
        if not s.ready:
            self.raise_for_state("the robot is not ready")
        if not s.program_running:
            # The control script stopped (e.g. after a released protective stop): restart it.
            self._cxx("restart the control program", self.rc.reuploadScript)
            deadline = time.monotonic() + 5.0
            while not self._cxx("program state", self.rc.isProgramRunning):
                if self._stop_requested():
                    self._stop_move()
                if time.monotonic() > deadline:
                    raise Refused(
                        "ProgramStopped", "the control program on the robot does not start"
                    )
                time.sleep(0.01)

    def raise_for_state(self, what: str) -> None:
        # The receive connection may lag the control connection by a packet or two: give the
        # cause a moment to show before settling for a generic message.
        deadline = time.monotonic() + 0.2
        while True:
            s = self.check_stream()  # a stream that stopped advancing ends here as frozen
            if not s.ready or not s.program_running:
                break
            if time.monotonic() > deadline and s.still_for <= STOP_STALE_S:
                break
            time.sleep(POLL_S)
        s = self.snap
        if not s.connected or not self._cxx("connection state", self.rc.isConnected):
            raise Refused(
                "ConnectionLost", f"{what}: lost the connection to {self.host}; rerun with --resume"
            )
        safety = _name(SafetyMode, s.safety_mode)
        if s.safety_mode in (SafetyMode.PROTECTIVE_STOP, SafetyMode.SAFEGUARD_STOP):
            raise Refused(
                "ProtectiveStop", f"{what}: {safety.lower().replace('_', ' ')}; {RECOVERY_HINT}"
            )
        if s.safety_mode not in (SafetyMode.NORMAL, SafetyMode.REDUCED):
            raise Refused("ProtectiveStop", f"{what}: safety mode {safety}; {RECOVERY_HINT}")
        if s.robot_mode != RobotMode.RUNNING:
            mode = _name(RobotMode, s.robot_mode)
            why = {
                RobotMode.POWER_OFF: "the arm is powered off",
                RobotMode.IDLE: "the brakes are on",
                RobotMode.BOOTING: "the arm is still booting",
                RobotMode.POWER_ON: "the arm is still powering on",
            }.get(s.robot_mode, "the arm cannot move")
            raise Refused(
                "HardwareError",
                f"{what}: robot mode {mode} ({why}); power on and release the brakes "
                "(pendant or dashboard), then rerun with --resume",
            )
        if s.runtime_state == RuntimeState.PAUSED:
            raise Refused(
                "ProgramStopped",
                f"{what}: the control program was paused (pause on the pendant or the "
                "dashboard); rerun with --resume",
            )
        if not s.program_running:
            raise Refused(
                "ProgramStopped",
                f"{what}: the control program stopped (stop pressed on the pendant, or a "
                "program error on the controller: see its log); rerun with --resume",
            )
        raise Refused("HardwareError", f"{what}: the controller reports no cause")

    def stop(self) -> str:
        """Stop the arm over RTDE and say how it was confirmed; :class:`Refused` when it cannot
        be confirmed (the parent then stops the program through the dashboard server)."""
        s = self.snap
        if not s.connected or not self._cxx("connection state", self.rc.isConnected):
            raise Refused(
                "ConnectionLost",
                f"the stop could not be sent: the RTDE link to {self.host} is down",
            )
        if s.still_for > STOP_STALE_S:
            raise Refused(
                "StreamFrozen",
                f"the stop cannot be confirmed over RTDE: no new data for {s.still_for:.2f} s",
            )
        if not s.program_running:
            return "the control program is not running: nothing drives the arm"
        self._cxx("stop", self.rc.stopJ, STOP_DECEL, False)  # returns nothing (ur-rtde 1.6)
        return self._confirm_still()

    def _confirm_still(self) -> str:
        """After stopJ: the stream must show the controller's target joints standing still
        (two successive packets alike), or the program no longer running."""
        deadline = time.monotonic() + STOP_CONFIRM_S
        ref = self.snap
        while True:
            time.sleep(POLL_S)
            s = self.snap
            if not s.connected:
                raise Refused("ConnectionLost", "the link dropped before the stop was confirmed")
            if not s.program_running:  # a protective stop or a program stop meanwhile
                return "the control program stopped: nothing drives the arm"
            if s.timestamp != ref.timestamp:
                if (
                    len(s.target_q) == len(ref.target_q) > 0
                    and max(abs(a - b) for a, b in zip(s.target_q, ref.target_q, strict=True))
                    < 1e-7
                ):
                    return "stopJ done: the controller's target joints stand still"
                ref = s
            if time.monotonic() > deadline:
                raise Refused(
                    "HardwareError",
                    f"stopJ was sent, but after {STOP_CONFIRM_S:.1f} s the stream does not show "
                    "the arm standing still",
                )

    def close_control(self) -> None:
        try:
            if self.snap.connected and self.rc.isConnected() and self.snap.program_running:
                self._cxx("stop script", self.rc.stopScript)
        except Refused:
            pass
        # Nothing more needs the stream: the receiver disconnects at the same time (each of
        # ur-rtde's disconnects takes 0.5 s, one after the other they made every close 1 s)
        self.closing.set()
        try:
            self.rc.disconnect()
        except RuntimeError:
            pass

    # -- main thread: requests -----------------------------------------------------------
    def _answer_if_not_acted(self, seq: int, rid: int, req: dict[str, Any]) -> None:
        """A stop the commander does not begin within ACT_WITHIN_S is answered now, as not
        confirmed: the commander is inside a C++ call, and the parent must not wait for it.
        The queued stop still runs (and cancels the move) when the commander is back."""
        with self.acted:
            if self.acted.wait_for(lambda: self.stop_acted >= seq, ACT_WITHIN_S):
                return
            req["answered"] = True
        busy, since = self._busy
        inside = f"inside {busy} for {time.monotonic() - since:.2f} s" if busy else "busy"
        self.reply(
            rid,
            error=Refused(
                "HardwareError",
                f"the stop could not be sent within {ACT_WITHIN_S * 1000:.0f} ms: the control "
                f"interface is {inside}",
            ),
        )

    def serve(self, stdin: Any) -> int:
        seq = itertools.count()
        for line in stdin:
            try:
                req = json.loads(line)
                rid, op = int(req["id"]), str(req["op"])
            except (ValueError, KeyError, TypeError):
                continue  # only the parent writes here; a garbled line is ignored
            n = next(seq)
            if op == "state":
                self.reply(rid, asdict(self.snap))
            elif op == "stop":
                self.stop_seq = n
                self.jobs.put(_Job(0, n, req))
                self._answer_if_not_acted(n, rid, req)
            elif op == "close":
                self.io_jobs.put({"op": "close", "id": -1})
                self.jobs.put(_Job(2, n, req))
                return 0
            elif op == "pulse":
                self.io_jobs.put(req)  # the io thread's queue: pulses never wait for a move
            else:
                self.jobs.put(_Job(1, n, req))
        self.io_jobs.put({"op": "close", "id": -1})
        self.jobs.put(_Job(2, next(seq), {"op": "close", "id": -1}))  # the parent is gone
        return 0


def _name(cls: Any, v: int) -> str:
    try:
        return str(cls(int(v)).name)
    except ValueError:
        return f"UNKNOWN ({v})"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m quickhealth.station.hardware.ur_client")
    p.add_argument("host")
    p.add_argument("--frequency", type=float, default=125.0)
    p.add_argument("--stale-after", type=float, default=0.5)
    p.add_argument("--move-timeout", type=float, default=120.0)
    a = p.parse_args(argv)
    if not (math.isfinite(a.frequency) and 1.0 <= a.frequency <= 500.0):
        sys.stderr.write("ur_client: --frequency must be in 1..500 Hz\n")
        return 2
    c = Client(a.host, a.frequency, a.stale_after, a.move_timeout)
    # The pybind11 constructors hold the GIL: build one after the other, each in its owner.
    rx = threading.Thread(target=c.receiver, name="ur-rtde-receive", daemon=True)
    rx.start()
    c.rr_ready.wait()
    started = threading.Event()
    cx = threading.Thread(target=c.commander, args=(started,), name="ur-rtde-control", daemon=True)
    if c.rr_error is None:
        cx.start()
        started.wait()
    if c.rr_error is not None:
        c.reply(0, error=Refused("ConnectionLost", c.rr_error))
        c.closing.set()
        rx.join(2.0)
        return 3
    io = threading.Thread(target=IoOwner(c).run, name="ur-rtde-io", daemon=True)
    io.start()
    c.reply(0, {"pid": _pid()})
    c.serve(sys.stdin)
    cx.join(5.0)  # a commander stuck inside the client is not waited for: the process ends
    io.join(2.0)
    c.closing.set()
    rx.join(2.0)
    # Last words: which threads are still alive (inside a client) as the process ends.
    alive = [t.name for t in threading.enumerate() if t is not threading.main_thread()]
    try:
        c.reply(FAREWELL_ID, {"threads": alive})
    except OSError:
        pass  # the parent is gone
    os._exit(0)


def _pid() -> int:
    return os.getpid()


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
