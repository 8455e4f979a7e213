"""One owner per device: a worker thread and a queue in front of a driver that is not thread-safe.

The run loop, the TUI's status polls and the pre-flight all use the pan motor and the
cameras; a serial transaction or a capture entered from two threads at once would interleave
bytes on the line or frames in the grabber.  :class:`DeviceOwner` gives the device one
thread that alone calls it: every method call becomes a job in a priority queue, the caller
waits for the result (or the exception) of its own job.  Calls named in ``urgent`` (``stop``)
jump ahead of anything queued.  Plain attributes (a camera's ``rig``) are read directly:
they are immutable data, not calls into the device.

The robot has its own owner: :class:`~quickhealth.station.hardware.robot.UrRobot` keeps the
ur-rtde client in a child process (:mod:`.ur_client`).
"""

from __future__ import annotations

import itertools
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from quickhealth.identify.errors import HardwareError


class DeviceOwner:
    """Owns ``device``: its methods run on one worker thread, one call at a time.

    Parameters
    ----------
    device : object
        The driver (pan motor, stereo camera).
    name : str
        For the thread's name and messages.
    urgent : tuple of str
        Methods that jump the queue.
    close_method : str
        The call after which the worker ends.
    """

    def __init__(
        self,
        device: Any,
        name: str,
        *,
        urgent: tuple[str, ...] = ("stop",),
        close_method: str = "close",
    ) -> None:
        self._device = device
        self._name = name
        self._urgent = frozenset(urgent)
        self._close = close_method
        self._jobs: queue.PriorityQueue[tuple[int, int, Callable[[], None] | None]] = (
            queue.PriorityQueue()
        )
        self._seq = itertools.count()
        self._closed = False
        self._thread = threading.Thread(target=self._work, name=f"owner-{name}", daemon=True)
        self._thread.start()

    @property
    def device(self) -> Any:
        """The owned driver (for tests and introspection; do not call it directly)."""
        return self._device

    def _work(self) -> None:
        while True:
            _, _, job = self._jobs.get()
            if job is None:
                return
            job()

    def call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        """Run ``device.method(*args, **kwargs)`` on the owner thread and return its result."""
        if threading.current_thread() is self._thread:  # a device method calling another one
            return getattr(self._device, method)(*args, **kwargs)
        if self._closed:
            if method == self._close:
                return None
            raise HardwareError(f"{self._name} is closed")
        fut: Future[Any] = Future()
        fn = getattr(self._device, method)

        def job() -> None:
            if not fut.set_running_or_notify_cancel():
                return
            try:
                fut.set_result(fn(*args, **kwargs))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)

        prio = 0 if method in self._urgent else 1
        if method == self._close:
            self._closed = True
        self._jobs.put((prio, next(self._seq), job))
        if method == self._close:
            self._jobs.put((2, next(self._seq), None))
        return fut.result()

    def shutdown(self, timeout: float = 5.0) -> None:
        """End the worker after the jobs already queued, without closing the device."""
        if not self._closed:
            self._closed = True
            self._jobs.put((2, next(self._seq), None))
        self._thread.join(timeout)

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._device, name)
        if not callable(value):
            return value
        return lambda *a, **k: self.call(name, *a, **k)

    def __enter__(self) -> DeviceOwner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.call(self._close)


def owned(device: Any, name: str) -> Any:
    """``device`` behind a :class:`DeviceOwner` (unchanged when it already has one)."""
    if device is None or isinstance(device, DeviceOwner):
        return device
    return DeviceOwner(device, name)
