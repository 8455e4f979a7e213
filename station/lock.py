"""The single-run lock (one run drives the cell at a time) and the output locks (one writer
per output at a time: :class:`OutputLock`).

An advisory ``flock`` on ``LOCK_DIR/run.lock`` (``$QUICKHEALTH_LOCK_DIR``, default
``/tmp/quickhealth-<uid>``).  The kernel drops it when the holder exits, however it exits
(``kill -9``, power cut), so a crash never leaves a stale lock behind.  The file holds the
holder's pid, run folder and start time for the refusal message.

SYNOPSIS
    >>> with RunLock.acquire(run_dir):        # doctest: +SKIP
    ...     run()
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable
from contextlib import ExitStack
from pathlib import Path
from typing import Any, TypeVar

from ..identify.errors import HardwareError

ENV_VAR = "QUICKHEALTH_LOCK_DIR"
F = TypeVar("F", bound=Callable[..., Any])


def lock_dir() -> Path:
    """Where the lock lives."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path(f"/tmp/quickhealth-{os.getuid()}")


class RunBusy(HardwareError):
    """Another run holds the lock."""


class RunLock:
    """A held run lock; release with :meth:`release` or a ``with`` block."""

    def __init__(self, fd: int, path: Path) -> None:
        self._fd = fd
        self.path = path

    @classmethod
    def acquire(cls, run_dir: Path | str, *, directory: Path | None = None) -> RunLock:
        """Take the lock at once or raise :class:`RunBusy` naming the holder (never waits)."""
        d = directory or lock_dir()
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
        path = d / "run.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise RunBusy(
                f"another quickhealth run holds the cell ({holder}); not starting — "
                f"wait for it to finish (lock {path})"
            ) from None
        info = {
            "pid": os.getpid(),
            "run_dir": str(run_dir),
            "since": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        return cls(fd, path)

    def release(self) -> None:
        """Release the lock."""
        if self._fd >= 0:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8") or "{}")
        return f"pid {int(info['pid'])}, run {str(info['run_dir'])[:200]}, since {info['since']}"
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return "holder unknown"


# ------------------------------------------------------------------ one writer per output


class OutputBusy(HardwareError):
    """Another quickhealth process is writing the same output."""


_held: dict[tuple[int, str], int] = {}  # (pid, output) locks held (re-entrant: run → fit)


class OutputLock:
    """One writer per output path at a time: an advisory ``flock`` on
    ``LOCK_DIR/out-<hash of the resolved path>.lock``, held for the whole command (from the
    check of what the folder holds to the last rename), so two commands writing one ``--out``
    cannot both pass the check and then replace each other's files.  The second is refused
    at once with one line naming the holder (exit 3).  Re-entrant within a process (``run
    --archive`` fits into its own run folder).  Covers the processes of one user on one
    machine, like :class:`RunLock`."""

    def __init__(self, key: str, fd: int, path: Path) -> None:
        self.key, self._fd, self.path = key, fd, path

    @classmethod
    def acquire(
        cls, output: str | os.PathLike[str], command: str, *, directory: Path | None = None
    ) -> OutputLock:
        target = Path(output).resolve()
        key = str(target)
        mine = (os.getpid(), key)  # a forked child does not hold its parent's locks
        d = directory or lock_dir()
        path = d / f"out-{hashlib.sha256(key.encode()).hexdigest()[:32]}.lock"
        if mine in _held:
            _held[mine] += 1
            return cls(key, -1, path)
        try:
            d.mkdir(parents=True, exist_ok=True, mode=0o700)
        except OSError as exc:
            raise HardwareError(f"{d}: cannot make the lock folder: {exc.strerror}") from None
        while True:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder_of_output(fd)
                os.close(fd)
                raise OutputBusy(
                    f"{output}: another quickhealth command is writing there ({holder}); "
                    "wait for it to finish, or choose another output"
                ) from None
            try:  # the previous holder may have removed the file between our open and lock
                same = os.fstat(fd).st_ino == os.stat(path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        info = {
            "pid": os.getpid(),
            "command": command,
            "output": key[:300],
            "since": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        _held[mine] = 1
        return cls(key, fd, path)

    def release(self) -> None:
        """Release the lock (and remove its file: nothing is left behind)."""
        mine = (os.getpid(), self.key)
        if mine not in _held:
            return
        _held[mine] -= 1
        if _held[mine] > 0 or self._fd < 0:
            return
        del _held[mine]
        try:
            self.path.unlink(missing_ok=True)
        except OSError:
            pass
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)
        self._fd = -1

    def __enter__(self) -> OutputLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder_of_output(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8") or "{}")
        return f"pid {int(info['pid'])}, {str(info['command'])[:40]}, since {info['since']}"
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return "holder unknown"


def holds_outputs(
    command: str, outputs: Callable[[Any], Iterable[str | os.PathLike[str] | None]]
) -> Callable[[F], F]:
    """Decorate a command function ``f(args)``: it runs holding :class:`OutputLock` on every
    path ``outputs(args)`` names (None skipped), taken in a fixed order."""

    def deco(func: F) -> F:
        @functools.wraps(func)
        def wrapper(args: Any, *rest: Any, **kw: Any) -> Any:
            paths = sorted({str(Path(p).resolve()) for p in outputs(args) if p is not None})
            with ExitStack() as stack:
                for p in paths:
                    stack.enter_context(OutputLock.acquire(p, command))
                return func(args, *rest, **kw)

        return wrapper  # type: ignore[return-value]

    return deco
