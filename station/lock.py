"""The single-run lock: one run drives the cell at a time.

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
import json
import os
import time
from pathlib import Path

from quickhealth.identify.errors import HardwareError

ENV_VAR = "QUICKHEALTH_LOCK_DIR"


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
