"""Pan-motor emulator on a pseudo-terminal: the device side of the protocol in
:mod:`quickhealth.station.hardware.motor`.

``MotorEmulator().start()`` opens a pseudo-terminal (``os.openpty``) and serves the protocol
from a thread; give :attr:`MotorEmulator.port` to
:class:`~quickhealth.station.hardware.motor.SerialPanMotor`.  The motor
turns at ``speed_deg_s`` with 0.01° resolution within ±``limit_deg``.

Faults for tests (:meth:`MotorEmulator.inject`): ``garbage`` (noise bytes before each reply),
``corrupt`` (wrong checksum on replies), ``silent`` (no replies), each for ``count`` replies
(``-1``: until cleared), and ``stall`` (the motor stops turning and reports a fault).
"""

from __future__ import annotations

import os
import select
import struct
import threading
import time
import tty

from ..hardware.motor import (
    CMD_MOVE_TO,
    CMD_PING,
    CMD_READ,
    CMD_STOP,
    MODEL_PAN,
    REPLY,
    UNIT,
    FrameDecoder,
    encode_frame,
)


class MotorEmulator:
    """A pan motor behind a pseudo-terminal."""

    def __init__(
        self,
        *,
        dev_id: int = 1,
        speed_deg_s: float = 360.0,
        limit_deg: float = 170.0,
        reply_delay: float = 0.0005,
    ) -> None:
        self.dev_id = dev_id
        self.speed = speed_deg_s
        self.limit = limit_deg
        self.reply_delay = reply_delay
        self._lock = threading.Lock()
        self._pos0 = 0.0  # deg at t0
        self._target = 0.0
        self._t0 = time.monotonic()
        self._faults: dict[str, int] = {}
        self.stalled = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.master = -1
        self.slave = -1
        self.port = ""
        self.requests = 0

    # -- motion model --------------------------------------------------------------------
    def position_deg(self) -> float:
        """True shaft angle now, degrees."""
        with self._lock:
            return self._pos_locked()

    def _pos_locked(self) -> float:
        if self.stalled:
            return self._pos0
        dt = time.monotonic() - self._t0
        d = self._target - self._pos0
        step = self.speed * dt
        if abs(d) <= step:
            return self._target
        return self._pos0 + step * (1 if d > 0 else -1)

    def _moving(self) -> bool:
        return not self.stalled and abs(self._pos_locked() - self._target) > 1e-9

    def _set_target(self, deg: float) -> None:
        self._pos0 = self._pos_locked()
        self._t0 = time.monotonic()
        self._target = deg

    # -- faults -----------------------------------------------------------------------------
    def inject(self, kind: str, count: int = -1) -> None:
        """Fault on the next ``count`` replies (``-1``: until :meth:`clear`)."""
        if kind == "stall":
            with self._lock:
                self._pos0 = self._pos_locked()
                self.stalled = True
            return
        if kind not in ("garbage", "corrupt", "silent"):
            raise ValueError(f"unknown motor fault {kind!r}")
        self._faults[kind] = count

    def clear(self) -> None:
        """Remove every fault."""
        self._faults.clear()
        with self._lock:
            self.stalled = False
            self._t0 = time.monotonic()

    def _take(self, kind: str) -> bool:
        n = self._faults.get(kind, 0)
        if n == 0:
            return False
        if n > 0:
            self._faults[kind] = n - 1
        return True

    # -- serving ----------------------------------------------------------------------------
    def start(self) -> MotorEmulator:
        """Open the pseudo-terminal and serve in a daemon thread."""
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self._thread = threading.Thread(target=self._serve, daemon=True, name="pan-motor-emulator")
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pseudo-terminal."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        for fd in (self.master, self.slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self.slave = -1

    def __enter__(self) -> MotorEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        dec = FrameDecoder()
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            n_bad = dec.n_bad
            frames = dec.feed(data)
            if dec.n_bad > n_bad and not frames:
                self._send(encode_frame(self.dev_id, REPLY, bytes([1])))
            for f in frames:
                if f.dev_id != self.dev_id:
                    continue
                self.requests += 1
                self._reply(f.cmd, f.payload)

    def _reply(self, cmd: int, payload: bytes) -> None:
        with self._lock:
            if cmd == CMD_PING:
                body = bytes([0]) + struct.pack(">HB", MODEL_PAN, 3)
            elif cmd == CMD_MOVE_TO and len(payload) == 4:
                (counts,) = struct.unpack(">i", payload)
                deg = counts * UNIT
                if abs(deg) > self.limit:
                    body = bytes([3])
                elif self.stalled:
                    body = bytes([4])
                else:
                    self._set_target(deg)
                    body = bytes([0])
            elif cmd == CMD_READ:
                pos = self._pos_locked()
                flags = (1 if self._moving() else 0) | (2 if self.stalled else 0)
                body = bytes([0]) + struct.pack(">iB", round(pos / UNIT), flags)
            elif cmd == CMD_STOP:
                self._set_target(self._pos_locked())
                body = bytes([0])
            else:
                body = bytes([2])
        frame = encode_frame(self.dev_id, cmd | REPLY, body)
        if self._take("silent"):
            return
        if self._take("corrupt"):
            frame = frame[:-1] + bytes([frame[-1] ^ 0x5A])
        if self._take("garbage"):
            frame = b"\x13\xaa\x00\xff\x55garbage\xaa" + frame
        time.sleep(self.reply_delay)
        self._send(frame)

    def _send(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            pass
