"""The station's one way to write a file: atomic, umask-respecting, never over an input.

Every file the station writes (CSV, JSON, HTML, URScript, URDF, PNG, the run journal's images)
goes through :func:`write_atomic`: the bytes go to a temporary file next to the target, which
is then renamed over it, so a reader sees either the old file or the whole new one, never a
half-written one.  The temporary file is created with mode ``0o666`` filtered by the process
umask (like ``open(path, "w")``; ``tempfile.mkstemp`` would force ``0600``).

:func:`refuse_overwriting_inputs` is called by every command before it computes anything:
an output path that names one of the command's input files is refused with one line (exit 2),
so ``predict M meas.csv --out meas.csv`` cannot destroy the measurements.

A file that cannot be written is one line: exit 2 when the path itself is unusable (read-only
file system, no permission, not a directory), exit 3 for a failure of the machine (disk full,
I/O error).
"""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Iterable
from pathlib import Path

from quickhealth.identify.errors import InputError, QuickhealthError

# errors that say "this path cannot be written": the user picks another one (exit 2)
_USAGE_ERRNOS = {
    errno.EROFS,
    errno.EACCES,
    errno.EPERM,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.ENOENT,
    errno.ENAMETOOLONG,
    errno.ELOOP,
}


def _write_error(path: Path, exc: OSError) -> QuickhealthError:
    what = exc.strerror or type(exc).__name__
    if exc.errno in _USAGE_ERRNOS:
        return InputError(f"{path}: cannot write: {what}")
    return QuickhealthError(f"{path}: writing failed: {what}")


def fsync_dir(path: str | os.PathLike[str]) -> None:
    """Make a rename or a new file in directory ``path`` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(
    path: str | os.PathLike[str],
    data: str | bytes,
    *,
    durable: bool = False,
    sync_dir: bool = False,
    mkdir: bool = True,
) -> None:
    """Write ``data`` (text is UTF-8) to ``path`` through a temporary file and a rename.

    Parameters
    ----------
    durable : bool
        ``fsync`` the file before the rename (the run journal, plans: survives a power cut).
    sync_dir : bool
        Also ``fsync`` the directory after the rename (the new name is durable too).
    mkdir : bool
        Create missing parent directories.

    Raises
    ------
    InputError
        The path cannot be written (read-only file system, permission, not a directory).
    QuickhealthError
        The write failed on the machine's side (disk full, I/O error); exit status 3.
    """
    p = Path(path)
    buf = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a file name")
    tmp = p.with_name(f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        if mkdir:
            p.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise _write_error(p, exc) from None
    try:
        try:
            view = memoryview(buf)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            if durable:
                os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _write_error(p, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if sync_dir:
        fsync_dir(p.parent)


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """:func:`write_atomic` of a text (UTF-8)."""
    write_atomic(path, text)


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def refuse_overwriting_inputs(
    outputs: Iterable[tuple[str, str | os.PathLike[str] | None]],
    inputs: Iterable[str | os.PathLike[str] | None],
) -> None:
    """Refuse (one line, exit 2) an output path that is one of the inputs.

    ``outputs`` are ``(option, path)`` pairs (``path`` None = not asked for), ``inputs`` the
    files the command reads.  Compared as files (hard links and symlinks count), or as
    resolved paths when a file does not exist yet.
    """
    ins = [Path(i) for i in inputs if i is not None]
    outs = [(opt, Path(o)) for opt, o in outputs if o is not None]
    for opt, o in outs:
        for i in ins:
            if _same_file(o, i):
                raise InputError(
                    f"{o}: {opt} names an input file of this command; refusing to overwrite it"
                )
    seen: dict[Path, str] = {}
    for opt, o in outs:
        key = o.resolve()
        if key in seen:
            raise InputError(f"{o}: {opt} and {seen[key]} name the same file")
        seen[key] = opt
