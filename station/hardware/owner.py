"""One owner per device: a worker thread and a queue in front of a driver that is not thread-safe.

The run loop, the TUI's status polls and the pre-flight all use the pan motor and the
cameras; a serial transaction or a capture entered from two threads at once would interleave
bytes on the line or frames in the grabber.  :class:`DeviceOwner` gives the device one
thread that alone calls it: every method call becomes a job in a priority queue, the caller
waits for the result (or the exception) of its own job.  Plain attributes (a camera's
``rig``) are read directly: they are immutable data, not calls into the device.

- Calls named in ``urgent`` (``stop``) jump ahead of anything queued.  The worker must
  begin one within ``act_within`` s (100 ms) and finish it within ``urgent_timeout`` s;
  otherwise the caller gets a :class:`~quickhealth.identify.errors.HardwareError` naming the
  call the device is stuck in, instead of waiting behind it (the urgent job stays first in
  the queue and runs as soon as the device returns).  Nothing but the worker ever enters
  the device, not even a stop.
- :meth:`DeviceOwner.close` closes the device on the worker after the jobs already queued,
  then ends the worker; it returns False when the device does not finish within the timeout
  (a stuck call): the device is then left alone, never closed from another thread.
- Calls after close are refused with a HardwareError; a call racing with close is refused
  too, never left waiting for a worker that has ended.

The robot has its own owner: :class:`~quickhealth.station.hardware.robot.UrRobot` keeps the
ur-rtde client in a child process (:mod:`.ur_client`).
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Generic, TypeVar, cast

from ...identify.errors import HardwareError


class _Job:
    """One call into the device, run by the worker; its caller waits on ``fut``."""

    def __init__(self, method: str, fn: Callable[..., Any], args: Any, kwargs: Any) -> None:
        self.method = method
        self.fn = fn
        self.args = args
        self.kwargs = kwargs
        self.fut: Future[Any] = Future()
        self.started = threading.Event()


D = TypeVar("D")


class DeviceOwner(Generic[D]):
    """Owns ``device``: its methods run on one worker thread, one call at a time.

    Parameters
    ----------
    device : object
        The driver (pan motor, stereo camera).
    name : str
        For the thread's name and messages ("pan motor").
    urgent : tuple of str
        Methods that jump the queue.
    close_method : str
        The call after which the worker ends.
    act_within : float
        s an urgent call may wait for the worker to begin it.
    urgent_timeout : float
        s an urgent call may take in all.
    """

    def __init__(
        self,
        device: D,
        name: str,
        *,
        urgent: tuple[str, ...] = ("stop",),
        close_method: str = "close",
        act_within: float = 0.1,
        urgent_timeout: float = 2.0,
    ) -> None:
        self._device = device
        self.name = name
        self._urgent = frozenset(urgent)
        self._close = close_method
        self.act_within = float(act_within)
        self.urgent_timeout = float(urgent_timeout)
        self._jobs: queue.PriorityQueue[tuple[int, int, _Job | None]] = queue.PriorityQueue()
        self._seq = itertools.count()
        self._lock = threading.Lock()  # the closed flag and every put into the queue
        self._closed = False
        self._inside: tuple[str, float] | None = None  # the call the worker is in, since when
        self._thread = threading.Thread(
            target=self._work, name=f"owner-{name.replace(' ', '-')}", daemon=True
        )
        self._thread.start()

    @property
    def device(self) -> D:
        """The owned driver (for tests and introspection; do not call it directly)."""
        return self._device

    @property
    def closed(self) -> bool:
        return self._closed

    def busy(self) -> tuple[str, float] | None:
        """The device method the worker is inside and for how many seconds, or None."""
        inside = self._inside
        return None if inside is None else (inside[0], time.monotonic() - inside[1])

    # -- the worker -----------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            _, _, job = self._jobs.get()
            if job is None:
                break
            self._run(job)
        # Whatever is still queued (a call that raced with close) is refused, not left waiting.
        while True:
            try:
                _, _, job = self._jobs.get_nowait()
            except queue.Empty:
                return
            if job is not None and job.fut.set_running_or_notify_cancel():
                job.fut.set_exception(self._closed_error(job.method))

    def _run(self, job: _Job) -> None:
        if not job.fut.set_running_or_notify_cancel():
            return
        self._inside = (job.method, time.monotonic())
        job.started.set()
        try:
            job.fut.set_result(job.fn(*job.args, **job.kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            job.fut.set_exception(exc)
        finally:
            self._inside = None

    def _closed_error(self, method: str) -> HardwareError:
        return HardwareError(
            f"the {self.name} is closed: {method}() refused (the station was shut down)"
        )

    # -- callers --------------------------------------------------------------------------
    def call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        """Run ``device.method(*args, **kwargs)`` on the owner thread and return its result."""
        if threading.current_thread() is self._thread:  # a device method calling another one
            return getattr(self._device, method)(*args, **kwargs)
        if method == self._close:
            self.close()
            return None
        job = _Job(method, getattr(self._device, method), args, kwargs)
        urgent = method in self._urgent
        with self._lock:
            if self._closed:
                raise self._closed_error(method)
            self._jobs.put((0 if urgent else 1, next(self._seq), job))
        if not urgent:
            return job.fut.result()
        return self._wait_urgent(job)

    def _wait_urgent(self, job: _Job) -> Any:
        t0 = time.monotonic()
        if not job.started.wait(self.act_within):
            inside = self.busy()
            where = f"inside {inside[0]}() for {inside[1]:.1f} s" if inside else "busy"
            raise HardwareError(
                f"the {self.name} did not begin {job.method}() within "
                f"{self.act_within * 1000:.0f} ms: it is {where}; {job.method}() runs as soon as "
                "it returns"
            )
        try:
            return job.fut.result(timeout=max(0.0, self.urgent_timeout - (time.monotonic() - t0)))
        except FutureTimeout:
            raise HardwareError(
                f"the {self.name} did not finish {job.method}() within {self.urgent_timeout:.0f} s"
            ) from None

    def close(self, timeout: float = 5.0) -> bool:
        """Close the device on its worker (after the jobs already queued), then end the worker.

        Returns False when the device did not finish within ``timeout`` s (the worker is
        stuck inside a call): the device is then left as it is, never closed from here.
        Raises what the device's close raised.
        """
        job = _Job(self._close, getattr(self._device, self._close), (), {})
        with self._lock:
            if self._closed:
                self._thread.join(timeout)
                return not self._thread.is_alive()
            self._closed = True
            self._jobs.put((2, next(self._seq), job))
            self._jobs.put((3, next(self._seq), None))
        try:
            job.fut.result(timeout=timeout)
        except FutureTimeout:
            return False
        self._thread.join(timeout)
        return True

    def shutdown(self, timeout: float = 5.0) -> bool:
        """End the worker after the jobs already queued, without closing the device.

        Returns False when the worker is still inside a call after ``timeout`` s."""
        with self._lock:
            if not self._closed:
                self._closed = True
                self._jobs.put((3, next(self._seq), None))
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._device, name)
        if not callable(value):
            return value
        return lambda *a, **k: self.call(name, *a, **k)

    def __enter__(self) -> DeviceOwner[D]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def owned(device: D, name: str) -> D:
    """``device`` behind a :class:`DeviceOwner` (unchanged when it already has one).

    Typed as the device: the owner answers every method of the device's interface (each
    call runs in the owner's thread), so callers keep the device's protocol type."""
    if device is None or isinstance(device, DeviceOwner):
        return device
    return cast(D, DeviceOwner(device, name))
