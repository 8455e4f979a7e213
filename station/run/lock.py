"""The single-run lock (one run drives the cell at a time) and the output locks (one writer
per output at a time: :class:`OutputLock`).

An advisory ``flock`` on ``LOCK_DIR/run.lock`` (``$QUICKHEALTH_LOCK_DIR``, default
``/tmp/quickhealth-<uid>``).  The kernel drops it when the holder exits, however it exits
(``kill -9``, power cut), so a crash never leaves a stale lock behind.  The file holds the
holder's pid, run folder and start time for the refusal message.

The lock folder is private (:func:`open_lock_dir`): made with mode 0700 when missing, and
refused with one line (exit 3) when it is a symbolic link, is not a folder, belongs to another
user or others may read or write it -- another user of the machine could otherwise make
``/tmp/quickhealth-<uid>`` first and plant links named like the next lock file, and the lock's
JSON would be written through them.  Every lock file is opened relative to the folder's
descriptor without following links (``O_NOFOLLOW``; ``O_EXCL`` when it is created) and must be
a regular file of this user with one name.  (``$XDG_RUNTIME_DIR`` is not used: cron and system
services have none, so a TUI session and the nightly job of one user would take their run
locks in two folders and both drive the cell.)

SYNOPSIS
    >>> with RunLock.acquire(run_dir):        # doctest: +SKIP
    ...     run()
"""

from __future__ import annotations

import errno
import fcntl
import functools
import hashlib
import json
import os
import stat
import time
from collections.abc import Callable, Iterable
from contextlib import ExitStack
from pathlib import Path
from typing import Any, TypeVar

from ...identify.errors import HardwareError

ENV_VAR = "QUICKHEALTH_LOCK_DIR"
F = TypeVar("F", bound=Callable[..., Any])


def lock_dir() -> Path:
    """Where the lock lives."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path(f"/tmp/quickhealth-{os.getuid()}")


class LockPlaceUnsafe(HardwareError):
    """The lock folder or a lock file is not this user's own (a link, another user's folder)."""


_ADVICE = f"remove it, or set {ENV_VAR} to a folder only you can use"


def open_lock_dir(d: Path) -> int:
    """A descriptor of the private lock folder ``d`` (made with mode 0700 when missing).

    Raises
    ------
    LockPlaceUnsafe
        ``d`` is a symbolic link or not a folder, belongs to another user, or others may
        read, write or enter it (one line naming it).
    HardwareError
        It cannot be made.
    """
    try:
        d.parent.mkdir(parents=True, exist_ok=True)
        os.mkdir(d, 0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise HardwareError(f"{d}: cannot make the lock folder: {exc.strerror}") from None
    try:
        fd = os.open(d, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR):
            what = "is a symbolic link" if d.is_symlink() else "is not a folder"
            raise LockPlaceUnsafe(
                f"{d}: the lock folder {what}: refusing to keep locks there; {_ADVICE}"
            ) from None
        raise HardwareError(f"{d}: cannot open the lock folder: {exc.strerror}") from None
    st = os.fstat(fd)
    why = None
    if st.st_uid != os.geteuid():
        why = f"belongs to uid {st.st_uid}, not to you (uid {os.geteuid()}): someone else made it"
    elif stat.S_IMODE(st.st_mode) & 0o077:
        why = f"has mode {stat.S_IMODE(st.st_mode):04o}: others may use it (it must be 0700)"
    if why is not None:
        os.close(fd)
        raise LockPlaceUnsafe(
            f"{d}: the lock folder {why}; refusing to keep locks there; {_ADVICE}"
        )
    return fd


def open_lock_file(dir_fd: int, name: str, where: Path) -> int:
    """Open (or create, ``O_EXCL``) lock file ``name`` in the folder ``dir_fd`` without
    following a link; it must be a regular file of this user with one name.

    Raises
    ------
    LockPlaceUnsafe
        A link, a special file, another user's file or a hard link stands there.
    """
    flags = os.O_RDWR | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    path = where / name
    for _ in range(100):  # a holder may remove its file between our two opens
        try:
            fd = os.open(name, flags | os.O_CREAT | os.O_EXCL, 0o600, dir_fd=dir_fd)
            break
        except FileExistsError:
            pass
        try:
            fd = os.open(name, flags, dir_fd=dir_fd)
            break
        except FileNotFoundError:
            continue
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise LockPlaceUnsafe(
                    f"{path}: a symbolic link stands where the lock file goes: refusing to "
                    f"follow it; {_ADVICE}"
                ) from None
            raise HardwareError(f"{path}: cannot open the lock file: {exc.strerror}") from None
    else:  # pragma: no cover - a file made and removed 100 times in a row
        raise HardwareError(f"{path}: cannot open the lock file: it keeps disappearing")
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_nlink != 1:
        os.close(fd)
        raise LockPlaceUnsafe(
            f"{path}: the lock file is not a plain file of yours (another user's, a special "
            f"file or a hard link): refusing to write it; {_ADVICE}"
        )
    return fd


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
        path = d / "run.lock"
        dfd = open_lock_dir(d)
        try:
            fd = open_lock_file(dfd, path.name, d)
        finally:
            os.close(dfd)
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

    def __init__(self, key: str, fd: int, path: Path, dir_fd: int = -1) -> None:
        self.key, self._fd, self.path, self._dir_fd = key, fd, path, dir_fd

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
        dfd = open_lock_dir(d)
        try:
            while True:
                fd = open_lock_file(dfd, path.name, d)
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
                    now = os.stat(path.name, dir_fd=dfd, follow_symlinks=False)
                    same = os.fstat(fd).st_ino == now.st_ino
                except FileNotFoundError:
                    same = False
                if same:
                    break
                os.close(fd)
        except BaseException:
            os.close(dfd)
            raise
        info = {
            "pid": os.getpid(),
            "command": command,
            "output": key[:300],
            "since": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        _held[mine] = 1
        return cls(key, fd, path, dfd)

    def release(self) -> None:
        """Release the lock (and remove its file: nothing is left behind)."""
        mine = (os.getpid(), self.key)
        if mine not in _held:
            return
        _held[mine] -= 1
        if _held[mine] > 0 or self._fd < 0:
            return
        del _held[mine]
        try:  # by name in the folder it was opened in (never through a link)
            os.unlink(self.path.name, dir_fd=self._dir_fd)
        except OSError:
            pass
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)
        os.close(self._dir_fd)
        self._fd = self._dir_fd = -1

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
