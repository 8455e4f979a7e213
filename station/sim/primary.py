"""The primary (30001), secondary (30002) and realtime (30003) interfaces: programs in,
robot messages out.

Each accepts URScript programs as raw text, as UR's client interfaces do: a program is
complete at a trailing unindented ``end``, a 100 ms idle gap or the socket closing, and is
handed to :meth:`Controller.run_script`.  A new program replaces the running one.

The primary and secondary interfaces also send, as a controller does, robot messages
(message type 20) to every connected client: a ``VERSION`` message on connection, ``TEXT``
for ``textmsg``, ``POPUP`` for ``popup``, and ``RUNTIME_EXCEPTION`` (line, column, text) for
a compile or runtime error of a program, in UR's primary-interface framing (int32 length
including the header, uint8 type, then the robot message header: uint64 timestamp, int8
source, uint8 robot message type).  The robot state packages (type 16) that a controller
also streams there are not sent.  The realtime interface sends nothing (ur-rtde keeps it
open and never reads it).
"""

from __future__ import annotations

import socket
import struct
import threading
from typing import TYPE_CHECKING, Any

from . import urscript_program
from .controller import close_socket

if TYPE_CHECKING:
    from .controller import Controller

MESSAGE_TYPE_ROBOT_MESSAGE = 20
ROBOT_MESSAGE_TEXT = 0
ROBOT_MESSAGE_POPUP = 2
ROBOT_MESSAGE_VERSION = 3
ROBOT_MESSAGE_RUNTIME_EXCEPTION = 10
SOURCE_CONTROLLER = -1
PRIMARY_PORT = 30001
SECONDARY_PORT = 30002
PROGRAM_LIMIT = 1_000_000  # bytes a program may have


def _robot_message(kind: int, body: bytes, t: float) -> bytes:
    payload = struct.pack(">QbB", int(t * 1e6), SOURCE_CONTROLLER, kind) + body
    return struct.pack(">iB", len(payload) + 5, MESSAGE_TYPE_ROBOT_MESSAGE) + payload


def version_message(version: tuple[int, ...], t: float) -> bytes:
    """``VERSION``: project name, major, minor, bugfix, build, build date."""
    name = b"URControl"
    body = struct.pack(">b", len(name)) + name
    body += struct.pack(">BBii", version[0], version[1], version[2], version[3])
    body += b"quickhealth simulator"
    return _robot_message(ROBOT_MESSAGE_VERSION, body, t)


def encode(msg: dict[str, Any]) -> bytes:
    """The primary-interface bytes of one controller message (:meth:`Controller.message`)."""
    text = str(msg["text"]).encode("utf-8", "replace")[:4000]
    kind = msg["kind"]
    if kind == "runtime_exception":
        body = struct.pack(">ii", int(msg.get("line", 0)), int(msg.get("col", 0))) + text
        return _robot_message(ROBOT_MESSAGE_RUNTIME_EXCEPTION, body, msg["t"])
    if kind == "popup":
        title, _, rest = str(msg["text"]).partition(": ")
        tb = title.encode("utf-8", "replace")[:255]
        body = struct.pack(">IB???B", 0, 0, False, False, False, len(tb)) + tb
        body += rest.encode("utf-8", "replace")[:4000]
        return _robot_message(ROBOT_MESSAGE_POPUP, body, msg["t"])
    return _robot_message(ROBOT_MESSAGE_TEXT, text, msg["t"])


class Clients:
    """The connected primary and secondary clients; messages go to all, never blocking."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.socks: list[socket.socket] = []

    def add(self, s: socket.socket) -> None:
        with self.lock:
            self.socks.append(s)

    def remove(self, s: socket.socket) -> None:
        with self.lock:
            if s in self.socks:
                self.socks.remove(s)

    def send(self, data: bytes) -> None:
        with self.lock:
            socks = list(self.socks)
        for s in socks:
            try:
                s.send(data, socket.MSG_DONTWAIT)
            except OSError:  # full or gone: a client that does not read loses messages
                pass


def interface(ctrl: Controller, conn: socket.socket, name: str, clients: Clients | None) -> None:
    """Serve one connection of the ``name`` interface (primary, secondary or realtime)."""
    if clients is not None:
        try:
            conn.sendall(version_message(ctrl.version, ctrl.now()))
        except OSError:
            close_socket(conn)
            return
        clients.add(conn)
    conn.settimeout(0.1)
    buf = b""
    closed = False
    try:
        while not closed and not ctrl.stop_event.is_set():
            complete = False
            try:
                chunk = conn.recv(65536)
                if not chunk:
                    closed = complete = True
                else:
                    buf += chunk
                    tail = buf.rstrip()
                    complete = tail.endswith(b"\nend") or tail == b"end" or len(buf) > PROGRAM_LIMIT
            except TimeoutError:
                complete = bool(buf)
            except OSError:
                closed = complete = True
            if complete and buf.strip():
                text = buf.decode("utf-8", "replace")
                first = text.strip().splitlines()[0][:60]
                ctrl.say(f"script received on the {name} interface: {len(buf)} bytes, {first!r}")
                urscript_program.run(ctrl, text, name)
                buf = b""
            elif complete:
                buf = b""
    finally:
        if clients is not None:
            clients.remove(conn)
        close_socket(conn)
