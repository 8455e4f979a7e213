"""The simulated controller's socket servers, all on 127.0.0.1 only.

- 30004 RTDE (:class:`RtdeSession`): protocol versions 1 and 2 of UR's RTDE guide, each
  with its own framing; output recipes streamed at the requested rate (at most 125 Hz for a
  CB3 version, 500 Hz for e-Series); input recipes merged into the controller's register
  bank, each input field owned by one client (another gets ``IN_USE``).
- 29999 dashboard (:mod:`.dashboard`): the command set of the reported version.
- 30001 primary, 30002 secondary, 30003 realtime (:mod:`.primary`): URScript programs
  (``rtde_control`` emulated, anything else interpreted: :mod:`.urscript_program`); robot
  messages to the primary and secondary clients.
- the control port (default 30090): JSON lines for tests and the simulated cell (fault
  injection, true target pose, state, shutdown, the digital output terminal as a stream of
  changes: ``watch_outputs``); see :class:`~.process.SimControllerHandle`.

The stream
----------
One thread, the controller cycle (:class:`Streamer`), feeds every RTDE session, as a real
controller's RTDE samples its one control loop: absolute deadlines ``t0 + k/f`` at 125 Hz
(CB3) or 500 Hz (e-Series), no drift, missed cycles skipped rather than sent in a burst;
each session gets every n-th cycle for its requested rate.  Per cycle it holds the
controller lock only to copy the state (:meth:`Controller.snapshot`); forward kinematics,
packing and sending happen outside it, sends never block (a client that stops reading is
dropped after 1 MB of backlog), and nothing it waits on ever plans a path.
"""

from __future__ import annotations

import json
import math
import os
import queue
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from . import dashboard as dashboard_server
from .controller import Controller, close_socket
from .primary import PRIMARY_PORT, SECONDARY_PORT, Clients, encode, interface
from .wire import (
    DASHBOARD_PORT,
    P_DATA,
    P_GET_URCONTROL_VERSION,
    P_PAUSE,
    P_REQUEST_PROTOCOL_VERSION,
    P_SETUP_INPUTS,
    P_SETUP_OUTPUTS,
    P_START,
    P_TEXT_MESSAGE,
    PROTOCOL_VERSIONS,
    RTDE_PORT,
    SCRIPT_PORT,
    Recipe,
    check_loopback,
    dashboard_model,
    packet,
    recv_exact,
    rtde_type,
)

SEND_BACKLOG = 1 << 20  # bytes a client may leave unread before its session is closed


class RtdeSession:
    """One RTDE client connection: its recipes, its requested rate, its unsent bytes.

    The handshake runs in the connection's own thread; data packets are pushed by the
    controller's single :class:`Streamer` thread without ever blocking on this client.
    """

    def __init__(self, ctrl: Controller, conn: socket.socket) -> None:
        self.ctrl = ctrl
        self.conn = conn
        self.outputs: list[Recipe] = []
        self.inputs: dict[int, Recipe] = {}
        self.next_output_id = 1  # output and input recipes are numbered separately:
        self.next_input_id = 1  # the client hard-codes input recipe ids 1, 2, 3 …
        self.freq = 125.0
        self.protocol = 1  # until the client asks for another (guide: version 1 by default)
        self.streaming = False
        self.send_lock = threading.Lock()
        self.pending = b""  # stream bytes the socket did not take yet
        self.closed = False
        self.packets = 0  # data packets streamed
        self.max_lag = 0.0  # s, the latest a packet went out after its cycle's deadline

    def send(self, ptype: int, payload: bytes) -> None:
        """A handshake reply, after any stream bytes still pending (blocking)."""
        with self.send_lock:
            data, self.pending = self.pending + packet(ptype, payload), b""
            self.conn.sendall(data)

    def push(self, data: bytes) -> None:
        """Stream bytes: sent without blocking; a client that stops reading is dropped.

        If a handshake reply is being sent right now, this cycle's packet is skipped.
        """
        if not self.send_lock.acquire(blocking=False):
            return
        try:
            buf = self.pending + data
            try:
                n = self.conn.send(buf, socket.MSG_DONTWAIT)
            except BlockingIOError:
                n = 0
            except OSError:
                self.closed = True
                return
            self.pending = buf[n:]
        finally:
            self.send_lock.release()
        if len(self.pending) > SEND_BACKLOG:
            self.ctrl.say("RTDE client stopped reading: connection closed")
            self.closed = True
            close_socket(self.conn)

    def divider(self) -> int:
        """Send every n-th controller cycle: the requested rate, at most the cycle rate."""
        return max(1, round(self.ctrl.stream_hz / max(min(self.freq, self.ctrl.stream_hz), 1.0)))

    def hz(self) -> float:
        return self.ctrl.stream_hz / self.divider()

    def serve(self) -> None:
        with self.ctrl.lock:
            self.ctrl.sessions.append(self)
        try:
            while not self.ctrl.stop_event.is_set() and not self.closed:
                size, ptype = struct.unpack(">HB", recv_exact(self.conn, 3))
                payload = recv_exact(self.conn, size - 3) if size > 3 else b""
                self._handle(ptype, payload)
        except (ConnectionError, OSError):
            pass
        finally:
            self.closed = True
            with self.ctrl.lock:
                if self in self.ctrl.sessions:
                    self.ctrl.sessions.remove(self)
            self.release()
            close_socket(self.conn)

    def _handle(self, ptype: int, payload: bytes) -> None:
        """One client packet (UR's RTDE guide, "Protocol" section: each package type)."""
        if ptype == P_REQUEST_PROTOCOL_VERSION:
            version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0
            ok = version in PROTOCOL_VERSIONS and not self.streaming
            if ok:
                self.protocol = version
            self.send(ptype, b"\x01" if ok else b"\x00")
        elif ptype == P_GET_URCONTROL_VERSION:
            self.send(ptype, struct.pack(">4I", *self.ctrl.version))
        elif ptype == P_SETUP_OUTPUTS:
            if self.protocol >= 2:
                if len(payload) < 8:
                    self.send(ptype, b"\x00")
                    return
                (freq,) = struct.unpack(">d", payload[:8])
                names_raw = payload[8:]
            else:  # version 1: no frequency, the controller's own rate
                freq, names_raw = self.ctrl.stream_hz, payload
            names = [n for n in names_raw.decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n, "output") or "NOT_FOUND" for n in names]
            ok = bool(names) and "NOT_FOUND" not in types and not self.streaming
            if ok and not (1.0 <= freq <= max(self.ctrl.stream_hz, 500.0)):
                ok = False
            rid = 0
            if ok:
                self.freq = freq
                if self.protocol < 2:
                    self.outputs = []  # one output recipe in version 1
                rid = self.next_output_id
                self.next_output_id += 1
                self.outputs.append(Recipe(rid, names, types))
            else:
                unknown = [n for n, t in zip(names, types, strict=True) if t == "NOT_FOUND"]
                self.ctrl.say(f"output setup refused: unknown field(s) {unknown}")
            body = ",".join(types).encode()
            self.send(ptype, (bytes([rid]) + body) if self.protocol >= 2 else body)
        elif ptype == P_SETUP_INPUTS:
            names = [n for n in payload.decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n, "input") or "NOT_FOUND" for n in names]
            with self.ctrl.lock:
                owners = self.ctrl.input_owners
                for i, n in enumerate(names):
                    if types[i] != "NOT_FOUND" and owners.get(n, self) is not self:
                        types[i] = "IN_USE"  # another client writes this field
                ok = bool(names) and not ({"NOT_FOUND", "IN_USE"} & set(types))
                if ok:
                    for n in names:
                        owners[n] = self
            rid = 0
            if ok:
                rid = self.next_input_id
                self.next_input_id += 1
                self.inputs[rid] = Recipe(rid, names, types)
            else:
                bad = [
                    f"{n} {t}"
                    for n, t in zip(names, types, strict=True)
                    if t in ("NOT_FOUND", "IN_USE")
                ]
                self.ctrl.say(f"input setup refused: {bad}")
            self.send(ptype, bytes([rid]) + ",".join(types).encode())
        elif ptype == P_START:
            ok = bool(self.outputs) or bool(self.inputs)
            self.send(ptype, b"\x01" if ok else b"\x00")
            self.streaming = ok
        elif ptype == P_PAUSE:
            self.streaming = False
            self.send(ptype, b"\x01")
        elif ptype == P_DATA and payload:
            recipe = self.inputs.get(payload[0])
            if recipe is not None and len(payload) >= recipe.struct.size:
                self.ctrl.set_inputs(recipe.unpack(payload))
        elif ptype == P_TEXT_MESSAGE:
            pass

    def release(self) -> None:
        """Give up the input fields this client wrote (it disconnected)."""
        with self.ctrl.lock:
            owners = self.ctrl.input_owners
            for n in [n for n, o in owners.items() if o is self]:
                del owners[n]


class Streamer:
    """The controller cycle: one thread that feeds every RTDE session.

    Runs at the controller's cycle rate (125 Hz CB3, 500 Hz e-Series) on absolute deadlines
    ``t0 + k/f`` (no drift; after a late wake-up the missed cycles are skipped, never
    sent in a burst).  Each cycle with a session due takes one snapshot (the controller
    lock only while copying state) and pushes each due session its packets without
    blocking, so one stalled client never delays another.
    """

    def __init__(self, ctrl: Controller) -> None:
        self.ctrl = ctrl
        self.cycles = 0
        self.missed = 0  # cycles skipped because the thread woke too late
        self.thread = threading.Thread(target=self.run, name="rtde-stream", daemon=True)

    def start(self) -> Streamer:
        self.thread.start()
        return self

    def run(self) -> None:
        ctrl = self.ctrl
        period = 1.0 / ctrl.stream_hz
        # The grid of the controller's cycles since it started: each packet carries the time
        # of its cycle (a whole number of steps), as a real controller's timestamp does.
        n0 = math.ceil((time.monotonic() - ctrl.t_start) / period)
        k = 0
        while not ctrl.stop_event.is_set():
            deadline = ctrl.t_start + (n0 + k) * period  # no drift: from the cycle number
            with ctrl.lock:
                sessions = list(ctrl.sessions)
            due = [
                r
                for r in sessions
                if r.streaming and r.outputs and not r.closed and k % r.divider() == 0
            ]
            if due:
                lag = time.monotonic() - deadline
                state = ctrl.snapshot((n0 + k) * period)  # the lock only while copying
                for r in due:
                    r.push(
                        b"".join(packet(P_DATA, rec.pack(state, r.protocol)) for rec in r.outputs)
                    )
                    r.packets += 1
                    r.max_lag = max(r.max_lag, lag)
            elif k % 4 == 0:  # no client: the controller still runs (heat, faults, programs)
                ctrl.snapshot((n0 + k) * period)
            k += 1
            self.cycles += 1
            delay = ctrl.t_start + (n0 + k) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:  # late: skip the missed cycles, keep the grid
                missed = int(-delay / period)
                self.missed += missed
                k += missed


def control(ctrl: Controller, conn: socket.socket) -> None:
    """JSON-lines control channel for tests and the simulated cell (loopback only)."""
    f = conn.makefile("rwb", buffering=0)
    try:
        for raw in f:
            if len(raw) > 65536:
                f.write(b'{"ok": false, "error": "request too long"}\n')
                continue
            req: Any = None
            try:
                req = json.loads(raw)
                if isinstance(req, dict) and req.get("cmd") == "watch_outputs":
                    watch_outputs(ctrl, f)  # this connection now carries the terminal's changes
                    break
                out = control_request(ctrl, req)
                out["ok"] = True
            except (ValueError, KeyError, TypeError) as exc:
                out = {"ok": False, "error": str(exc)}
            f.write((json.dumps(out) + "\n").encode())
            if isinstance(req, dict) and req.get("cmd") == "shutdown":
                break
    except OSError:
        pass
    finally:
        close_socket(conn)


def watch_outputs(ctrl: Controller, f: Any) -> None:
    """Stream the digital output terminal's changes on a control connection: first the
    outputs now, then one line per change, ``{"t": controller time of the cycle it took effect
    (s), "bits": actual_digital_output_bits, "at_monotonic": the same moment on the host's
    CLOCK_MONOTONIC}``, until the simulator stops or the other end goes away.  The simulated
    cell's trigger cable listens here (:mod:`.cable`)."""
    with ctrl.lock:
        w = ctrl.io.watch()
        t = ctrl.cycle_time(ctrl.now())
        bits = ctrl.io.bits
    try:
        f.write((json.dumps({"ok": True, "t": t, "bits": bits}) + "\n").encode())
        while not ctrl.stop_event.is_set():
            try:
                change = w.get(timeout=0.2)
            except queue.Empty:
                continue
            if change is None:
                return
            te, bits = change
            line = {"t": te, "bits": bits, "at_monotonic": ctrl.t_start + te}
            f.write((json.dumps(line) + "\n").encode())
    finally:
        with ctrl.lock:
            ctrl.io.unwatch(w)


def control_request(ctrl: Controller, req: dict[str, Any]) -> dict[str, Any]:
    """Answer one control-channel request (raises ValueError/KeyError/TypeError on bad ones)."""
    cmd = req["cmd"]
    if cmd == "ping":
        return {"pid": os.getpid()}
    if cmd == "fault":
        ctrl.add_fault(req)
        return {}
    if cmd == "state":
        with ctrl.lock:
            t = ctrl.now()
            ctrl.io.advance(ctrl.cycle_time(t))  # the cycles passed since the last one
            q = ctrl.arm.actual(t)
            return {
                "t": t,
                "q": list(map(float, q)),
                "moving": ctrl.arm.moving(t),
                "planning": ctrl.planning is not None,
                "robot_mode": int(ctrl.robot_mode),
                "safety_mode": int(ctrl.safety_mode),
                "runtime_state": int(ctrl.runtime_state),
                "program": ctrl.program_name if ctrl.program_kind else None,
                "program_error": ctrl.program_error,
                "loaded": ctrl.loaded,
                "digital_out": ctrl.io.bits,
                "digital_out_changes": ctrl.io.changes,
                "messages": ctrl.messages[-20:],
                "n_moves": ctrl.n_moves,
                "n_restarts": ctrl.n_restarts,
                "stops": [{"at_monotonic": t, "via": how} for t, how in ctrl.stops[-20:]],
                "frozen": ctrl.frozen is not None,
                "accepting": ctrl.accepting(),
                "version": list(ctrl.version),
                "robot": robot_facts(ctrl.arm.ik_model or ctrl.arm.robot),
                "streams": [
                    {"hz": r.hz(), "packets": r.packets, "max_lag_ms": r.max_lag * 1e3}
                    for r in ctrl.sessions
                    if r.streaming and r.outputs
                ],
            }
    if cmd == "truth":
        with ctrl.lock:
            t = ctrl.now()
            q = ctrl.arm.actual(t)
            approach = ctrl.arm.approach.copy()
            moving = ctrl.arm.moving(t)
        truth = ctrl.arm.truth
        cond = ctrl.joint_conditions(q)  # a warm joint, a carried part: the arm's true state
        T = truth(q, approach, **cond) if truth is not None else ctrl.arm.robot.fk(q)
        return {
            "t": t,
            "q": list(map(float, q)),
            "approach": list(map(float, approach)),
            "moving": moving,
            "T_instr_target0": np.asarray(T).tolist(),
            **{k: list(map(float, v)) for k, v in cond.items()},
        }
    if cmd == "twin":
        if ctrl.world is None:
            raise ValueError("this simulator has no digital twin")
        return {"truth": ctrl.world.twin.truth.to_dict()}
    if cmd == "set_q":
        q = np.asarray(req["q"], dtype=float)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise ValueError("set_q needs 6 finite joint angles (rad)")
        ctrl.set_q(q)
        return {}
    if cmd == "log":
        return {"log": ctrl.log[-200:]}
    if cmd == "shutdown":
        shutdown(ctrl)
        return {}
    raise ValueError(f"unknown control command {cmd!r}")


def robot_facts(robot: Any) -> dict[str, Any]:
    """The arm the simulated controller drives: its dashboard model, built-in name, joint
    limits (°) and joint speed limits (°/s)."""
    qd = robot.qd_max
    return {
        "model": dashboard_model(robot.name),
        "name": robot.name,
        "q_min_deg": np.degrees(robot.q_min).tolist(),
        "q_max_deg": np.degrees(robot.q_max).tolist(),
        "qd_max_deg_s": None if qd is None else np.degrees(qd).tolist(),
    }


def shutdown(ctrl: Controller) -> None:
    """Stop serving: listeners closed, :func:`serve` returns."""
    ctrl.stop_event.set()
    for s in ctrl.listeners:
        close_socket(s)


def _listen(host: str, port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((check_loopback(host), port))  # loopback only, always
    s.listen(8)
    return s


Handler = Callable[[Controller, socket.socket], None]


def serve(ctrl: Controller, *, rtde_port: int = RTDE_PORT) -> None:
    """Run all servers until a ``shutdown`` control request (blocks)."""
    clients = Clients()
    ctrl.on_message = lambda msg: clients.send(encode(msg))
    handlers: list[tuple[int, Handler, bool]] = [
        (rtde_port, lambda c, s: RtdeSession(c, s).serve(), True),
        (DASHBOARD_PORT, dashboard_server.session, True),
        (SCRIPT_PORT, lambda c, s: interface(c, s, "realtime", None), True),
        (PRIMARY_PORT, lambda c, s: interface(c, s, "primary", clients), True),
        (SECONDARY_PORT, lambda c, s: interface(c, s, "secondary", clients), True),
        (ctrl.control_port, control, False),  # the test harness: never faulted
    ]
    listeners = []
    for port, _, _ in handlers:
        try:
            listeners.append(_listen(ctrl.host, port))
        except OSError as exc:
            for s in listeners:
                close_socket(s)
            raise OSError(f"cannot listen on {ctrl.host}:{port}: {exc.strerror}") from exc
    ctrl.listeners = listeners

    def run(handler: Handler, conn: socket.socket, faultable: bool) -> None:
        try:
            handler(ctrl, conn)
        finally:
            if faultable:
                ctrl.untrack(conn)

    def accept_loop(sock: socket.socket, handler: Handler, faultable: bool) -> None:
        while not ctrl.stop_event.is_set():
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            if faultable and not ctrl.track(conn):
                continue  # refused: dropped link or a restarting controller
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=run, args=(handler, conn, faultable), daemon=True).start()

    threads = [
        threading.Thread(target=accept_loop, args=(s, h, f), daemon=True)
        for s, (_, h, f) in zip(listeners, handlers, strict=True)
    ]
    for t in threads:
        t.start()
    Streamer(ctrl).start()
    ctrl.say(f"listening on {ctrl.host}")
    ctrl.stop_event.wait()
    ctrl.close()
    for s in listeners:
        close_socket(s)
    ctrl.drop_connections()
