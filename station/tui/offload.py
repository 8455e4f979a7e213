"""Run a CPU-heavy pure function in a child process, so the terminal UI stays live.

A thread worker alone is not enough for the fits: they are long stretches of Python and numpy
that hold the interpreter lock, and the UI thread then waits milliseconds for every small
step of handling a key (seconds per key press, measured).  :func:`offload` runs the function
in a process forked from a *forkserver* that has already imported the identification
modules (tens of milliseconds per call), passes arguments and result by pickle (frozen
dataclasses and arrays), and forwards progress lines over a pipe.  The calling thread only
waits on the pipe, which releases the lock.

The function must be importable (module level) and accept a ``progress`` keyword.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
from collections.abc import Callable
from multiprocessing import forkserver
from multiprocessing.connection import Connection
from multiprocessing.context import ForkServerContext
from typing import Any, TypeVar

from ...identify.errors import HardwareError

PRELOAD = [
    "numpy",
    "scipy.linalg",
    "quickhealth.identify.fit",
    "quickhealth.identify.select",
    "quickhealth.identify.diagnose",
    "quickhealth.identify.compare",
    "quickhealth.identify.workspace",
    "quickhealth.station.tui.jobs",  # and the application layer it calls (fit, report, archive)
    "quickhealth.station.tui.figures",
]

BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_ctx_lock = threading.Lock()
_ctx: ForkServerContext | None = None
T = TypeVar("T")


def _context() -> ForkServerContext:
    global _ctx
    with _ctx_lock:
        if _ctx is None:
            ctx = mp.get_context("forkserver")
            ctx.set_forkserver_preload(PRELOAD)
            _ctx = ctx
        return _ctx


def warm_up() -> None:
    """Start the forkserver (and the resource tracker) now, from the main thread.

    Call before the App takes over the terminal: both pass the process's stderr to the
    server they start, and a terminal UI (or its test driver) replaces stderr with an object
    that has no file descriptor.
    """
    _context()
    # The server (and every fit forked from it) loads OpenBLAS with one thread: the UI and
    # the fit share the machine, and threaded BLAS on small matrices only adds contention.
    saved = {k: os.environ.get(k) for k in BLAS_THREADS}
    os.environ.update(dict.fromkeys(BLAS_THREADS, "1"))
    try:
        forkserver.ensure_running()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _child(conn: Connection, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    def progress(line: str) -> None:
        conn.send(("progress", line))

    try:
        result = fn(*args, progress=progress)
    except BaseException as exc:  # sent back and raised in the parent
        try:
            conn.send(("error", exc))
        except Exception:  # an exception that does not pickle
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
    else:
        conn.send(("ok", result))
    finally:
        conn.close()


def offload(fn: Callable[..., T], *args: Any, progress: Callable[[str], None] | None = None) -> T:
    """``fn(*args, progress=…)`` in a child process; its result, or its exception re-raised."""
    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(send, fn, args), daemon=True)
    proc.start()
    send.close()
    try:
        while True:
            try:
                kind, payload = recv.recv()
            except EOFError:
                raise HardwareError(
                    f"the computation process ended without an answer (exit code {proc.exitcode})"
                ) from None
            if kind == "progress":
                if progress is not None:
                    progress(payload)
            elif kind == "ok":
                return payload
            else:
                raise payload
    finally:
        recv.close()
        proc.join(timeout=10)
        if proc.is_alive():
            proc.kill()
