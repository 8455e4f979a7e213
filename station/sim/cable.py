"""The simulated cell's trigger cable: the controller's digital output to both cameras' line.

On the real cell a cable joins the robot controller's standard digital output to the trigger
input (``Line1``) of both cameras, and a rising edge exposes them.  pypylon's emulated cameras
have no line a voltage can reach, so in the simulated cell the cable is the fake at the
hardware boundary:

- :class:`Cable` listens to the simulated controller's output terminal
  (:class:`OutputWatch` on its control port: every change of
  ``actual_digital_output_bits`` with the controller cycle it took effect) and, on each
  *rising* edge of its output, puts an edge on the line input of every camera plugged into it.
  A cut cable (:meth:`Cable.cut`) carries nothing: the cameras see no edge and time out as a
  camera with a loose trigger cable does.  A bouncing line (:meth:`Cable.bounce`) brings the
  next edge to one camera twice (contact bounce or ringing on a long unterminated run that
  the camera's debouncer does not filter): that camera exposes twice, the pair is out of step.
- :class:`LineInput` is a camera's trigger input: it wraps the backend's device adapter and
  latches the edges the cable brings.  The camera is exposed (the emulator's trigger command,
  which exposes whatever its trigger source) by the thread that owns the camera, at its next
  call (``retrieve``, ``pending``), never by the cable's thread: the device keeps its one owner.
  ``retrieve`` waits for an edge within the time-out; with none, the frame times out.

What is emulated and what is real: the controller's output terminal (the RTDE input masks,
each change at a controller cycle) and the real ur-rtde client's pulse are real code; the
cable and the camera's opto-isolated input are this module.  pypylon's emulated cameras are
configured exactly as real ones (``TriggerSelector=FrameStart``, ``TriggerMode=On``,
``TriggerSource=Line1``, ``TriggerActivation=RisingEdge``): without an edge they deliver
nothing.  The edge is delivered through the emulator's ``TriggerSoftware`` command, which the
emulator obeys whatever the trigger source (a real camera ignores it with ``Line1`` selected),
and at the owner's next call rather than at the instant of the edge: the scene in front of
the emulated cameras is still between the edge and that call, so the image is the same.

Everything else (the image shown, the faults of :class:`~.cameras.EmulatorFeed`) passes
through to the wrapped device.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..hardware.cameras.config import CameraSpec
from ..hardware.cameras.genicam import FrameTimeout, GenICamDevice, RawFrame
from .controller import close_socket
from .process import SimControllerHandle

#: Longest wait for a frame the emulator owes after an edge seen by ``pending`` (s).
EXPOSE_WAIT_S = 1.0


@dataclass(frozen=True)
class Edge:
    """A rising edge at the cable: controller time (s) and this host's monotonic clock (s)."""

    t: float
    at_monotonic: float


class OutputWatch:
    """A control connection that carries the simulated controller's digital output changes
    (:func:`~.servers.watch_outputs`) to ``on_change(t, bits, at_monotonic)``, from its own
    thread: controller time of the cycle the change took effect, ``actual_digital_output_bits``,
    the same moment on this host's monotonic clock.  :meth:`close` before the simulator stops.

    ``bits`` and ``t`` are the outputs and the controller time as of the last change seen."""

    def __init__(
        self, host: str, port: int, on_change: Callable[[float, int, float], None]
    ) -> None:
        self._sock = socket.create_connection((host, port), timeout=5.0)
        self._file = self._sock.makefile("rwb", buffering=0)
        self._file.write(b'{"cmd": "watch_outputs"}\n')
        first = json.loads(self._file.readline() or b"{}")
        if not first.get("ok"):
            close_socket(self._sock)
            raise ConnectionError("the simulator does not stream its digital outputs")
        self.bits, self.t = int(first["bits"]), float(first["t"])
        self._sock.settimeout(None)  # the thread waits for changes as long as it takes
        self._on_change = on_change
        self._thread = threading.Thread(target=self._read, name="sim-outputs", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for line in self._file:
                msg = json.loads(line)
                self.bits, self.t = int(msg["bits"]), float(msg["t"])
                self._on_change(self.t, self.bits, float(msg["at_monotonic"]))
        except (OSError, ValueError):
            pass  # closed: by us, or the simulator stopped

    def close(self) -> None:
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        close_socket(self._sock)
        self._thread.join(2.0)


class Cable:
    """The trigger cable from the controller's standard digital output ``output`` (see the
    module docstring).  ``edges`` lists every rising edge seen at the controller's end,
    carried or not; :meth:`close` before the simulator stops."""

    def __init__(self, controller: SimControllerHandle, output: int) -> None:
        self.output = int(output)
        self.edges: list[Edge] = []
        self.carried = 0  # edges that reached the cameras
        self._bit = 1 << self.output
        self._lock = threading.Lock()
        self._inputs: list[LineInput] = []
        self._cut = False
        self._bounce: set[str] = set()  # sides whose next edge arrives twice
        self._watch = OutputWatch(controller.host, controller.control_port, self._changed)
        self._high = bool(self._watch.bits & self._bit)

    def _changed(self, t: float, bits: int, at_monotonic: float) -> None:
        high = bool(bits & self._bit)
        rising = high and not self._high
        self._high = high
        if not rising:
            return
        with self._lock:
            self.edges.append(Edge(t, at_monotonic))
            if self._cut:
                return
            self.carried += 1
            inputs = list(self._inputs)
            bounce, self._bounce = self._bounce, set()
        for line in inputs:
            line.edge()
            if line.side in bounce:
                line.edge()

    def cut(self) -> None:
        """The cable cut (or unplugged): no edge reaches the cameras until :meth:`mend`."""
        with self._lock:
            self._cut = True

    def mend(self) -> None:
        with self._lock:
            self._cut = False

    def bounce(self, side: str) -> None:
        """The next edge the cable carries reaches the ``side`` camera twice."""
        with self._lock:
            self._bounce.add(side)

    @property
    def is_cut(self) -> bool:
        return self._cut

    def plug(
        self, opener: Callable[[CameraSpec], GenICamDevice]
    ) -> Callable[[CameraSpec], GenICamDevice]:
        """A device opener whose cameras have their trigger input on this cable."""

        def open_(spec: CameraSpec) -> GenICamDevice:
            line = LineInput(opener(spec), self, spec.side)
            with self._lock:
                self._inputs.append(line)
            return line

        return open_

    def unplug(self, line: LineInput) -> None:
        with self._lock:
            if line in self._inputs:
                self._inputs.remove(line)

    def close(self) -> None:
        self._watch.close()


class LineInput:
    """A camera's trigger input on the :class:`Cable` (see the module docstring); every other
    attribute is the wrapped device's."""

    def __init__(self, device: GenICamDevice, cable: Cable, side: str) -> None:
        self._dev = device
        self._cable = cable
        self.side = side
        self._cond = threading.Condition()
        self._latched = 0  # edges the cable brought that the camera has not acted on
        self._owed = 0  # exposures made that no retrieve has collected yet

    def __getattr__(self, name: str) -> Any:
        return getattr(self._dev, name)

    # -- the cable's side ----------------------------------------------------------------
    def edge(self) -> None:
        """A rising edge on the line (called from the cable's thread: only latched here)."""
        with self._cond:
            self._latched += 1
            self._cond.notify_all()

    # -- the owner's side ----------------------------------------------------------------
    def _expose(self) -> int:
        """Act on the latched edges: one exposure each (the emulator's trigger command)."""
        with self._cond:
            n, self._latched = self._latched, 0
        for _ in range(n):
            self.trigger()
        self._owed += n
        return n

    def trigger(self) -> None:
        """The device's own (software) trigger; what an edge on the line does."""
        self._dev.trigger()

    def show(self, image: Any) -> None:
        """The emulated camera's new scene (:class:`~.cameras.EmulatorFeed`): showing restarts
        its acquisition, so frames not collected are gone."""
        self._owed = 0
        self._dev.show(image)

    def pending(self) -> bool:
        self._expose()
        if self._owed:  # an exposure made and not collected: its frame is on its way
            t0 = time.monotonic()
            while not self._dev.pending() and time.monotonic() - t0 < EXPOSE_WAIT_S:
                time.sleep(0.002)
        return self._dev.pending()

    def retrieve(self, timeout_s: float) -> RawFrame:
        deadline = time.monotonic() + timeout_s
        self._expose()
        if not self._owed and not self._dev.pending():
            with self._cond:  # no edge yet: wait for the cable within the time-out
                self._cond.wait_for(
                    lambda: self._latched > 0, max(0.0, deadline - time.monotonic())
                )
            if not self._expose() and not self._dev.pending():
                raise FrameTimeout.after(self.side, timeout_s)  # no edge, no frame
        try:
            return self._dev.retrieve(max(deadline - time.monotonic(), 0.05))
        except FrameTimeout:  # an edge came, the camera did not expose (its trigger lost)
            raise FrameTimeout.after(self.side, timeout_s) from None
        finally:
            self._owed = max(0, self._owed - 1)

    def close(self) -> None:
        self._cable.unplug(self)
        self._dev.close()
