"""Worker processes that end with the command that started them.

A command that computes in parallel (``identify fit --plots``, ``vision measure --jobs``,
``reprocess``) starts its worker processes through :class:`Pool`, a
:class:`~concurrent.futures.ProcessPoolExecutor` whose workers never outlive it:

- **the command is stopped** (Ctrl-C, ``kill``, the terminal closing, systemd's stop): the
  command function carries :func:`owns_workers`, under which SIGTERM and SIGHUP raise
  :class:`Terminated` in the main thread as Ctrl-C raises ``KeyboardInterrupt``, so every
  ``finally`` runs (temporary folders removed, nothing half-written), and every pool the
  command started is stopped: what has not started is cancelled, the running workers are
  sent SIGTERM, then SIGKILL after a grace period;
- **the command dies without cleaning up** (``kill -9``, an out-of-memory kill): each worker
  asked the kernel to kill it when its parent dies (Linux ``PR_SET_PDEATHSIG``), and also
  watches its parent, so none is left re-parented to init;
- **Ctrl-C in a terminal** reaches the whole process group: the workers ignore it and the
  command stops them (a worker interrupted in the middle of a job would otherwise report the
  interruption as the job's result and go on to the next).

A pool shut down while an exception propagates (a ``finally`` block or ``with`` exit on
Ctrl-C, SIGTERM or an error) stops its workers at once instead of waiting for their jobs.

SYNOPSIS::

    @workers.owns_workers
    def _reprocess(args):
        with workers.Pool(max_workers=2) as ex:
            ...
"""

from __future__ import annotations

import ctypes
import functools
import os
import signal
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

#: how long stopped workers get to exit after SIGTERM before SIGKILL (s)
GRACE_S = 2.0
_PR_SET_PDEATHSIG = 1

_live: weakref.WeakSet[Any] = weakref.WeakSet()  # the Pools not shut down


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread like Ctrl-C's ``KeyboardInterrupt``."""


@contextmanager
def signals_stop_the_command() -> Iterator[None]:
    """In the main thread: SIGTERM and SIGHUP raise :class:`Terminated` (SIGINT already
    raises ``KeyboardInterrupt``); the previous handlers come back afterwards.  Elsewhere (a
    thread of the TUI) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, _frame: Any) -> None:
        raise Terminated(f"stopped by {signal.Signals(signum).name}")

    old = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        old[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def owns_workers(func: F) -> F:
    """Decorate a command function: SIGTERM and SIGHUP stop it like Ctrl-C, and every
    :class:`Pool` it started (and did not shut down) is stopped when it returns or raises."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        before = set(_live)
        with signals_stop_the_command():
            try:
                return func(*args, **kwargs)
            finally:
                for pool in list(_live):
                    if pool not in before:
                        pool.stop()

    return wrapper  # type: ignore[return-value]


def _watch_parent(parent_pid: int) -> None:
    """A worker's thread: end this process when the command that started it is gone."""
    ppid = os.getppid()
    while True:
        time.sleep(0.25)
        if os.getppid() != ppid:
            os._exit(1)
        try:
            os.kill(parent_pid, 0)
        except ProcessLookupError:
            os._exit(1)
        except PermissionError:
            pass


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_MAX = -1, -2, -4


def keep_freed_memory() -> bool:
    """Let a short batch command (``identify fit``, ``diagnose``) reuse the memory it frees.

    glibc serves every allocation above its mmap ceiling (32 MB at most) with fresh pages of
    its own and returns them to the kernel on ``free``: each new array of that size faults
    in and zeroes every page again.  A 20,000-pose fit makes hundreds of such arrays (its
    Jacobian is 60 MB), and its minor page faults grew 4x for 2x the poses (158,000 at
    10,000 poses, 643,000 at 20,000).  Served from the heap and kept there, they are reused:
    77,000 faults and 24.9 -> 21.0 s at 20,000 poses, 10.3 -> 9.8 s at 10,000; the peak
    grows by the heap's slack (657 -> 718 MB at 20,000, unchanged at 10,000).

    Only for commands that end when their work ends: a long-running process (the TUI, the
    simulator, a run) would keep its peak for ever.  Returns whether it took effect (glibc
    on Linux; elsewhere nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(
        mallopt(_M_MMAP_MAX, 0)
        and mallopt(_M_TRIM_THRESHOLD, 1 << 30)
        and mallopt(_M_TOP_PAD, 64 << 20)
    )


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux), and watch the
    command's process (the parent may be a fork server)."""
    if sys.platform.startswith("linux") and os.getppid() == parent_pid:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the watcher does it
            pass
        if os.getppid() != parent_pid:  # the parent died before prctl took effect
            os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()


def _init_worker(parent_pid: int, initializer: Callable[..., Any] | None, initargs: tuple) -> None:
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the command stops us (see the docstring)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


def __getattr__(name: str) -> Any:
    """:class:`Pool` is made on first use: ``concurrent.futures.process`` costs ~30 ms, which
    a command that starts no worker (and ``quickhealth --help``) should not pay."""
    if name != "Pool":
        raise AttributeError(name)
    from concurrent.futures import ProcessPoolExecutor

    class Pool(ProcessPoolExecutor):
        """A :class:`~concurrent.futures.ProcessPoolExecutor` whose workers end with the command
        (see the module's docstring); the same arguments."""

        def __init__(
            self,
            max_workers: int | None = None,
            mp_context: Any = None,
            initializer: Callable[..., Any] | None = None,
            initargs: tuple = (),
        ) -> None:
            super().__init__(
                max_workers,
                mp_context=mp_context,
                initializer=_init_worker,
                initargs=(os.getpid(), initializer, tuple(initargs)),
            )
            _live.add(self)

        def stop(self) -> None:
            """Cancel the jobs that have not started and end the workers now: SIGTERM, then
            SIGKILL for any still there after :data:`GRACE_S`."""
            procs = [p for p in (getattr(self, "_processes", None) or {}).values() if p is not None]
            super().shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.terminate()
            deadline = time.monotonic() + GRACE_S
            for p in procs:
                p.join(max(0.0, deadline - time.monotonic()))
                if p.is_alive():
                    p.kill()
                    p.join(1.0)
            _live.discard(self)

        def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
            """As the executor's, but while an exception propagates (Ctrl-C, SIGTERM, an error)
            :meth:`stop`: never wait for jobs whose results nobody will read."""
            if sys.exc_info()[0] is not None:
                self.stop()
                return
            super().shutdown(wait=wait, cancel_futures=cancel_futures)
            _live.discard(self)

        def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> bool:
            if exc_type is not None:
                self.stop()
                return False
            return bool(super().__exit__(exc_type, exc, tb))

    globals()["Pool"] = Pool
    return Pool
