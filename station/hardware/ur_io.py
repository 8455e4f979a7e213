"""The robot's digital outputs, in the ur-rtde client process: the io thread and its pulses.

Part of the client process (:mod:`.ur_client`).  The *io* thread is the one owner of
``RTDEIOInterface`` (ur-rtde's interface for the controller's outputs, its own RTDE
connection): it constructs it at the first ``pulse`` request and executes the pulses from its
queue, one at a time; nothing else calls into it.  A pulse on standard digital output ``n``
(:meth:`IoOwner.pulse`) is the camera trigger of the line-triggered stereo pair:

1. **the arm at rest**: no move under way (the commander watches none; else refused at
   once) and the receive stream's actual joints within ``rest_tol`` peak to peak over the
   last ``rest_window`` s of controller time (the settle criterion of the run).  After a
   move the pulse waits for that, at most ``rest_wait`` s; an arm still moving then is
   refused in one line and nothing is set;
2. **rise**: ``setStandardDigitalOut(n, True)``; the receive stream must show the output high
   (``actual_digital_output_bits``) within :data:`LEVEL_CONFIRM_S`.  The controller applies
   an RTDE input at its next cycle; the receiver keeps only the latest packet and polls every
   4 ms (later on a busy computer), so the edge is known as a bracket of controller time:
   after the last packet seen low, at or before the first packet seen high;
3. **hold** until the stream's controller clock is one stream period short of ``width`` s
   past the rise (the fall then lands no sooner than ``width``; at least two controller
   cycles: a shorter pulse could begin and end inside one cycle and never reach the
   terminal);
4. **fall**: ``setStandardDigitalOut(n, False)``, confirmed on the stream the same way.

An output found high before a pulse (a pulse cut short by a lost link) is driven low first,
so every pulse has its rising edge.  The reply gives both edges' brackets of controller time,
the time from sending the rise to seeing it, and the joints' peak-to-peak motion from the
start of the rest window to the fall.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .ur_client import Client, Snapshot

LEVEL_CONFIRM_S = 0.25  # s for the stream to show an output at the level just set
IO_POLL_S = 0.001  # s between looks at the latest snapshot while an edge is awaited


class Refused(Exception):
    """A command of the client process ended without success; ``kind`` names the driver's
    exception class (:mod:`.robot`).  Defined here, not in :mod:`.ur_client`, which runs as
    ``__main__``: one class for every thread of the process."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class IoOwner:
    """The io thread of one client process (see the module docstring)."""

    def __init__(self, client: Client) -> None:
        self.c = client
        self.io: Any = None

    def run(self) -> None:
        """The thread: pulses from the queue until ``close``."""
        c = self.c
        while True:
            req = c.io_jobs.get()
            op, rid = req["op"], int(req["id"])
            if op == "close":
                self.close()
                return
            try:
                c.reply(rid, self.pulse(req))
            except Exception as exc:  # noqa: BLE001 - Refused, or a bug: answer either way
                if not isinstance(exc, Refused):
                    exc = Refused("HardwareError", f"pulse: {type(exc).__name__}: {exc}")
                c.reply(rid, error=exc)

    def _interface(self) -> Any:
        if self.io is None:
            import rtde_io  # the C++ client, in this thread only: its one owner

            try:
                self.io = rtde_io.RTDEIOInterface(self.c.host)
            except RuntimeError as exc:
                raise Refused(
                    "ConnectionLost",
                    f"cannot open the robot's I/O interface at {self.c.host}: {exc}",
                ) from None
        return self.io

    def _set(self, n: int, level: bool) -> None:
        try:
            ok = self._interface().setStandardDigitalOut(n, level)
        except RuntimeError as exc:
            ok, why = False, str(exc)
        else:
            why = "the I/O interface refused it"
        if not ok:
            raise Refused(
                "ConnectionLost",
                f"digital output {n} could not be set {'high' if level else 'low'} ({why}); "
                "check the link to the controller, then rerun with --resume",
            )

    def _level(self, n: int, level: bool, since: float, before: Snapshot) -> tuple[Snapshot, float]:
        """The first snapshot that shows output ``n`` at ``level``, and the controller time
        of the last one seen at the other level (``before``: read before the change was
        sent): the edge lies after that and at or before the first."""
        bit = 1 << n
        last = before.timestamp
        while True:
            s = self.c.check_stream()
            if bool(s.digital_out & bit) == level:
                return s, last
            last = s.timestamp
            if time.monotonic() - since > LEVEL_CONFIRM_S:
                raise Refused(
                    "HardwareError",
                    f"digital output {n} did not go {'high' if level else 'low'} within "
                    f"{LEVEL_CONFIRM_S * 1e3:.0f} ms (the controller's actual_digital_output_bits "
                    "did not follow): check the controller's I/O, then rerun with --resume",
                )
            time.sleep(IO_POLL_S)

    def pulse(self, req: dict[str, Any]) -> dict[str, Any]:
        n, width = int(req["output"]), float(req["width"])
        window, tol = float(req["rest_window"]), float(req["rest_tol"])
        wait = float(req["rest_wait"])
        if not (0 <= n <= 7 and 0.0 < width <= 1.0 and 0.0 < window <= 1.0 and tol > 0.0):
            raise Refused("HardwareError", f"pulse: bad request {req!r}")
        c = self.c
        t_req = time.monotonic()
        c.check_stream()
        self._interface()
        p2p = self.at_rest(window, tol, wait)
        s = c.check_stream()
        if s.digital_out & (1 << n):  # left high (a pulse cut short): low first, then the edge
            self._set(n, False)
            s, _ = self._level(n, False, time.monotonic(), s)
        t_sent = time.monotonic()
        self._set(n, True)
        rise, rise_after = self._level(n, True, t_sent, s)
        t_seen = time.monotonic()
        # The fall takes effect at the cycle after the one it is sent in: sent once the
        # stream is one period short of the width past the rise seen (at or after the real
        # one), it ends the pulse no sooner than ``width``.
        hold = width - 1.0 / c.frequency
        while (s := c.check_stream()).timestamp < rise.timestamp + hold - 1e-9:
            time.sleep(IO_POLL_S)
        self._set(n, False)
        fall, fall_after = self._level(n, False, time.monotonic(), s)
        moved = self.spread(rise.timestamp - window, fall.timestamp)
        return {
            "output": n,
            "rise_t": rise.timestamp,
            "rise_after_t": rise_after,
            "fall_t": fall.timestamp,
            "fall_after_t": fall_after,
            "latency_s": t_seen - t_sent,
            "request_s": t_seen - t_req,
            "rest_p2p_rad": max(p2p, moved),
        }

    def at_rest(self, window: float, tol: float, wait: float) -> float:
        """The joints' peak-to-peak motion over the last ``window`` s of the stream (rad),
        once it is at most ``tol``; :class:`Refused` at once when a move is under way, and
        when the arm is not at rest within ``wait`` s."""
        c = self.c
        deadline = time.monotonic() + wait
        p2p = math.inf
        while True:
            if c.moving_seq >= 0:
                raise Refused(
                    "HardwareError",
                    "the trigger pulse was not sent: a move is under way (the cameras are "
                    "triggered only with the arm at rest)",
                )
            with c._history_lock:
                hist = list(c._history)
            if hist and hist[0][0] <= hist[-1][0] - window:  # the stream covers the window
                p2p = self.spread(hist[-1][0] - window, hist[-1][0], hist)
                if p2p <= tol:
                    return p2p
            if time.monotonic() > deadline:
                moved = (
                    f"its joints moved {p2p * 1e6:.0f} µrad in the last {window * 1e3:.0f} ms"
                    if math.isfinite(p2p)
                    else f"the joint stream does not cover {window * 1e3:.0f} ms"
                )
                raise Refused(
                    "HardwareError",
                    f"the trigger pulse was not sent: the arm is not at rest after {wait:.1f} s "
                    f"({moved}; at most {tol * 1e6:.0f}): check the robot, then rerun with "
                    "--resume",
                )
            time.sleep(0.004)

    def spread(
        self,
        t0: float,
        t1: float,
        hist: list[tuple[float, tuple[float, ...]]] | None = None,
    ) -> float:
        """Largest peak-to-peak joint motion (rad) over the samples in ``[t0, t1]``."""
        if hist is None:
            with self.c._history_lock:
                hist = list(self.c._history)
        qs = [q for t, q in hist if t0 - 1e-9 <= t <= t1 + 1e-9 and q]
        if len(qs) < 2:
            return 0.0
        return max(max(col) - min(col) for col in zip(*qs, strict=True))

    def close(self) -> None:
        if self.io is not None:
            try:
                self.io.disconnect()
            except RuntimeError:
                pass
