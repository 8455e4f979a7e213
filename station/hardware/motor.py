"""The smart target's pan motor over a serial line: protocol, and a driver on pyserial.

Protocol (quickhealth pan-motor protocol v1, documented in docs/station.md)
--------------------------------------------------------------------------
Every frame, both directions::

    0xAA 0x55 | id (u8) | cmd (u8) | len (u8) | payload (len bytes) | crc (u16, big-endian)

``crc`` is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over ``id, cmd, len, payload``.
Integers are big-endian.  A reply echoes ``id`` and sets bit 7 of ``cmd``; its payload starts
with a status byte (0 ok, 1 bad checksum, 2 unknown command, 3 out of range, 4 motor fault).

=====  ==========  ===============================  ==========================================
cmd    name        request payload                  reply payload after the status byte
=====  ==========  ===============================  ==========================================
0x01   PING        —                                model u16, firmware u8
0x02   MOVE_TO     target i32, 0.01° units          —
0x03   READ        —                                position i32 (0.01°), flags u8
                                                    (bit 0 moving, bit 1 fault)
0x04   STOP        —                                —
=====  ==========  ===============================  ==========================================

The driver resynchronises on the header after line noise, checks length and checksum, and
retries a transaction (``retries`` times, ``timeout`` seconds each) before it gives up with a
:class:`~quickhealth.identify.errors.HardwareError` naming the port and what to check.
"""

from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from ...identify.errors import HardwareError

HEADER = b"\xaa\x55"
CMD_PING = 0x01
CMD_MOVE_TO = 0x02
CMD_READ = 0x03
CMD_STOP = 0x04
REPLY = 0x80
STATUS_OK = 0
STATUS_TEXT = {
    0: "ok",
    1: "bad checksum",
    2: "unknown command",
    3: "target out of range",
    4: "motor fault",
}
MODEL_PAN = 0x5154  # "QT"
UNIT = 0.01  # degrees per count
MAX_PAYLOAD = 32


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def encode_frame(dev_id: int, cmd: int, payload: bytes = b"") -> bytes:
    """One frame with header and checksum."""
    if not (0 <= dev_id < 256 and 0 <= cmd < 256 and len(payload) <= MAX_PAYLOAD):
        raise ValueError("frame field out of range")
    body = bytes([dev_id, cmd, len(payload)]) + payload
    return HEADER + body + struct.pack(">H", crc16(body))


@dataclass(frozen=True)
class Frame:
    """A decoded frame."""

    dev_id: int
    cmd: int
    payload: bytes


class FrameDecoder:
    """Incremental decoder: feed bytes, get frames; skips noise and bad checksums."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.n_bad = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Add received bytes and return every complete, valid frame."""
        self.buf += data
        out: list[Frame] = []
        while True:
            i = self.buf.find(HEADER)
            if i < 0:
                # Keep a trailing 0xAA: it may start the next header.
                del self.buf[: max(0, len(self.buf) - 1)]
                return out
            del self.buf[:i]
            if len(self.buf) < 5:
                return out
            n = self.buf[4]
            if n > MAX_PAYLOAD:
                self.n_bad += 1
                del self.buf[:2]
                continue
            end = 5 + n + 2
            if len(self.buf) < end:
                return out
            body = bytes(self.buf[2 : 5 + n])
            (crc,) = struct.unpack(">H", self.buf[5 + n : end])
            if crc != crc16(body):
                self.n_bad += 1
                del self.buf[:2]
                continue
            out.append(Frame(body[0], body[1], body[3:]))
            del self.buf[:end]


@runtime_checkable
class PanMotor(Protocol):
    """A pan motor: absolute position in rad."""

    def ping(self) -> None:
        """Raise HardwareError unless the motor answers."""
        ...

    def move_to(self, pan: float, *, wait: bool = True) -> float:
        """Turn to ``pan`` (rad); with ``wait`` return the reached position (rad)."""
        ...

    def position(self) -> float:
        """Current position, rad."""
        ...

    def close(self) -> None:
        """Release the port."""
        ...


@dataclass(frozen=True)
class MotorStats:
    """Transport counters (for the run log)."""

    transactions: int
    retries: int
    bad_frames: int


class SerialPanMotor:
    """Pan motor driver on pyserial.

    Parameters
    ----------
    port : str
        Serial device (``/dev/ttyUSB0``, a pseudo-terminal of the emulator, …).
    dev_id : int
        Bus address of the motor.
    timeout : float
        s to wait for each reply.
    retries : int
        Extra attempts after a timeout or a corrupted reply.
    limit_deg : float
        Software limit of the pan angle, ±deg.
    """

    def __init__(
        self,
        port: str,
        *,
        dev_id: int = 1,
        baudrate: int = 115200,
        timeout: float = 0.2,
        retries: int = 3,
        limit_deg: float = 170.0,
        move_timeout: float = 5.0,
    ) -> None:
        try:
            import serial  # pyserial only on a real station: the simulator needs none
        except ImportError as exc:  # pragma: no cover - pyserial is a dependency
            raise HardwareError(f"pyserial is not installed ({exc})") from None
        self.port = port
        self.dev_id = dev_id
        self.timeout = timeout
        self.retries = retries
        self.limit = math.radians(limit_deg)
        self.move_timeout = move_timeout
        self._decoder = FrameDecoder()
        self._n = 0
        self._n_retries = 0
        try:
            self._ser: Any = serial.Serial(port, baudrate=baudrate, timeout=timeout)
        except (serial.SerialException, OSError) as exc:
            raise HardwareError(f"cannot open the pan motor port {port}: {exc}") from None

    @property
    def stats(self) -> MotorStats:
        """Transactions, retries and bad frames so far."""
        return MotorStats(self._n, self._n_retries, self._decoder.n_bad)

    def _transact(self, cmd: int, payload: bytes = b"") -> bytes:
        frame = encode_frame(self.dev_id, cmd, payload)
        why = "no reply"
        for attempt in range(self.retries + 1):
            if attempt:
                self._n_retries += 1
            self._ser.reset_input_buffer()
            self._decoder.buf.clear()
            bad_before = self._decoder.n_bad
            self._ser.write(frame)
            self._ser.flush()
            reply, why = self._await_reply(cmd)
            if reply is not None:
                self._n += 1
                return reply
            if why == "timeout" and self._decoder.n_bad > bad_before:
                why = "corrupted reply"
        raise HardwareError(
            f"pan motor on {self.port} does not answer ({why} after {self.retries + 1} tries "
            f"of {self.timeout * 1000:.0f} ms): check its power and cable"
        )

    def _await_reply(self, cmd: int) -> tuple[bytes | None, str]:
        """The reply payload (after the status byte), or None and why not."""
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            data = self._ser.read(max(1, self._ser.in_waiting))
            for f in self._decoder.feed(data):
                if f.dev_id != self.dev_id or f.cmd != (cmd | REPLY) or not f.payload:
                    continue  # another device's or a stale reply
                status = f.payload[0]
                if status == 1:  # the motor saw a corrupted request: send it again
                    return None, "motor reported a bad checksum"
                if status != STATUS_OK:
                    raise HardwareError(
                        f"pan motor on {self.port}: {STATUS_TEXT.get(status, status)}"
                    )
                return f.payload[1:], "ok"
        return None, "timeout"

    def ping(self) -> None:
        data = self._transact(CMD_PING)
        if len(data) != 3 or struct.unpack(">H", data[:2])[0] != MODEL_PAN:
            raise HardwareError(f"the device on {self.port} is not a quickhealth pan motor")

    def _read(self) -> tuple[float, int]:
        data = self._transact(CMD_READ)
        if len(data) != 5:
            raise HardwareError(f"pan motor on {self.port}: malformed position reply")
        counts, flags = struct.unpack(">iB", data)
        return math.radians(counts * UNIT), flags

    def position(self) -> float:
        return self._read()[0]

    def move_to(self, pan: float, *, wait: bool = True) -> float:
        pan = float(pan)
        if not math.isfinite(pan) or abs(pan) > self.limit:
            raise HardwareError(
                f"pan angle {math.degrees(pan):.2f}° outside ±{math.degrees(self.limit):.0f}°"
            )
        counts = round(math.degrees(pan) / UNIT)
        self._transact(CMD_MOVE_TO, struct.pack(">i", counts))
        if not wait:
            return pan
        deadline = time.monotonic() + self.move_timeout
        while True:
            pos, flags = self._read()
            if flags & 2:
                raise HardwareError(f"pan motor on {self.port} reports a fault")
            if not flags & 1:
                if abs(pos - math.radians(counts * UNIT)) > math.radians(2 * UNIT):
                    raise HardwareError(
                        f"pan motor on {self.port} stopped at {math.degrees(pos):.2f}°, "
                        f"not {math.degrees(pan):.2f}°"
                    )
                return pos
            if time.monotonic() > deadline:
                raise HardwareError(
                    f"pan motor on {self.port} did not arrive within {self.move_timeout:.0f} s"
                )
            time.sleep(0.005)

    def stop(self) -> None:
        """Stop turning."""
        self._transact(CMD_STOP)

    def close(self) -> None:
        try:
            self._ser.close()
        except OSError:
            pass

    def __enter__(self) -> SerialPanMotor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
