"""The station's one way to write a file: atomic, umask-respecting, never over an input.

Every file the station writes (CSV, JSON, HTML, URScript, URDF, PNG, the run journal's images)
goes through :func:`write_atomic`: the bytes go to a temporary file next to the target, which
is then renamed over it, so a reader sees either the old file or the whole new one, never a
half-written one.  The temporary file is created with mode ``0o666`` filtered by the process
umask (like ``open(path, "w")``; ``tempfile.mkstemp`` would force ``0600``).

:func:`refuse_overwriting_inputs` is called by every command before it computes anything:
an output path that names one of the command's input files is refused with one line (exit 2),
so ``predict M meas.csv --out meas.csv`` cannot destroy the measurements.

Figures (matplotlib) are written by :func:`write_figure`: rendered into memory, then
:func:`write_atomic`, so a PNG is never half-written and its errors are the same one line.

:func:`claim_output_folder` is the rule for commands that write into a folder (``plan``,
``identify fit``): an existing folder that holds results of another kind (a plan, a run, a
fit) or of another run is refused without ``--force``; the command's own earlier results
there are replaced, and the command says so in one line.

A file that cannot be written is one line: exit 2 when the path itself is unusable (read-only
file system, no permission, not a directory), exit 3 for a failure of the machine (disk full,
I/O error).
"""

from __future__ import annotations

import errno
import fnmatch
import io
import os
import re
import secrets
import stat as _stat
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..identify.errors import InputError, QuickhealthError

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


def write_error(path: Path, exc: OSError) -> QuickhealthError:
    """The one-line error of a failed write of ``path`` (exit 2 for the path, 3 for the machine)."""
    what = exc.strerror or type(exc).__name__
    if exc.errno == errno.ELOOP:
        what = "a symbolic link stands there; not followed"
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


def open_append(path: str | os.PathLike[str]) -> int:
    """A descriptor appending to ``path`` (made 0644 when missing), never through a symbolic
    link (``O_NOFOLLOW``): the run journal and run.log.

    Raises
    ------
    InputError
        A link or something else that cannot be written stands there (one line).
    """
    try:
        return os.open(
            path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644
        )
    except OSError as exc:
        raise write_error(Path(path), exc) from None


_SECRET_IN_URL = re.compile(r"([A-Za-z][A-Za-z0-9+.\-]*://[^\s/?#@:\"'<>]*):[^\s/?#@\"'<>]*@")


def redact_urls(text: str) -> str:
    """``text`` with the password of every URL in it replaced by ``***``
    (``postgresql+psycopg://qh:SECRET@db/qh`` -> ``postgresql+psycopg://qh:***@db/qh``), as
    SQLAlchemy shows them.  Every text file the product writes passes here
    (:func:`write_atomic`): an archive, a report or its backups never hold an index password."""
    if "://" not in text:  # the common case: one C-level scan
        return text
    return _SECRET_IN_URL.sub(r"\1:***@", text)


def write_atomic(
    path: str | os.PathLike[str],
    data: str | bytes,
    *,
    durable: bool = False,
    sync_dir: bool = False,
    mkdir: bool = True,
) -> None:
    """Write ``data`` (text is UTF-8, with the passwords of URLs redacted: :func:`redact_urls`)
    to ``path`` through a temporary file and a rename.

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
    buf = redact_urls(data).encode("utf-8") if isinstance(data, str) else bytes(data)
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a file name")
    tmp = p.with_name(f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        if mkdir:
            p.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise write_error(p, exc) from None
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
        raise write_error(p, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if sync_dir:
        fsync_dir(p.parent)


_TEMP_NAME = re.compile(r"^\..+\.(\d+)\.[0-9a-f]{8}\.tmp$")  # write_atomic's temporary files


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_temp_files(folder: str | os.PathLike[str]) -> list[str]:
    """Delete the temporary files :func:`write_atomic` left in ``folder`` when its process was
    killed between writing and renaming (``kill -9``, a power cut): those whose writer's
    process no longer exists.  Their final files were never renamed into place, so nothing
    of value is lost.  Returns the names removed."""
    d = Path(folder)
    gone = []
    for f in sorted(d.iterdir()) if d.is_dir() else []:
        m = _TEMP_NAME.match(f.name)
        if m and f.is_file() and not pid_alive(int(m.group(1))):
            f.unlink(missing_ok=True)
            gone.append(f.name)
    return gone


def make_dirs(path: str | os.PathLike[str]) -> Path:
    """``mkdir -p`` with the errors of :func:`write_atomic` (one line; exit 2 for a path that
    cannot be written, 3 for a failure of the machine); returns the path."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{p}: exists and is not a folder") from None
    except OSError as exc:
        raise write_error(p, exc) from None
    return p


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """:func:`write_atomic` of a text (UTF-8)."""
    write_atomic(path, text)


def write_figure(
    fig: Any, path: str | os.PathLike[str], *, dpi: int = 100, format: str = "png"
) -> str:
    """Render a matplotlib figure (PNG, or ``format``: "pdf") in memory, then
    :func:`write_atomic` it; returns the path.  The figure is closed afterwards if it belongs
    to pyplot (no figure left open)."""
    buf = io.BytesIO()
    fig.savefig(buf, format=format, dpi=dpi)
    try:
        import matplotlib.pyplot as plt  # matplotlib (0.5 s) only once a figure is written

        if plt.fignum_exists(getattr(fig, "number", -1)):
            plt.close(fig)
    except ImportError:  # pragma: no cover - matplotlib made the figure
        pass
    write_atomic(path, buf.getvalue())
    return str(path)


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


def refuse_outputs_inside(
    outputs: Iterable[tuple[str, str | os.PathLike[str] | None]],
    folder: str | os.PathLike[str],
    what: str,
) -> None:
    """Refuse (one line, exit 2) an output path inside ``folder`` (e.g. the archive, whose
    index and run folders are the input of ``trend``)."""
    root = Path(folder).resolve()
    for opt, o in outputs:
        if o is not None and Path(o).resolve().is_relative_to(root):
            raise InputError(f"{o}: {opt} lies inside {what} {root}; refusing to write there")


# ------------------------------------------------------------------------- output folders

#: The files each kind of result folder holds (names or glob patterns).
RESULT_FILES: Mapping[str, tuple[str, ...]] = {
    "plan": ("plan.json", "loop.script", "fig6_joints.png", "fig6_targets.png"),
    "run": ("journal.jsonl", "run.json", "measurements.csv", "images", "run.log", "check.json"),
    "fit": (
        "model.json",
        "report.json",
        "residuals.csv",
        "residuals.png",
        "workspace_histogram.png",
        "joint*_curves.png",
        "report.html",
        "diagnosis.json",
    ),
}
_KIND_WORDS = {"plan": "a plan", "run": "a run", "fit": "a fit"}


def result_files(folder: str | os.PathLike[str]) -> dict[str, list[str]]:
    """The result files of each kind present in ``folder`` (names, sorted; empty lists for a
    missing folder).  Files of no kind (a user's notes) are not results."""
    d = Path(folder)
    names = sorted(p.name for p in d.iterdir()) if d.is_dir() else []
    return {
        kind: [n for n in names if any(fnmatch.fnmatchcase(n, pat) for pat in pats)]
        for kind, pats in RESULT_FILES.items()
    }


def claim_output_folder(
    folder: str | os.PathLike[str],
    other: Sequence[str] = (),
    *,
    force: bool = False,
    option: str = "--out",
) -> str:
    """May a command that writes results of ``kind`` write into ``folder``?

    Parameters
    ----------
    folder : path
        The output folder (may not exist yet).
    other : sequence of str
        What in the folder belongs to another kind or another run, each a few words naming
        the files (:func:`foreign_results`, plus the caller's own findings such as "the fit
        of other.csv"); empty when everything there is the command's own.
    force : bool
        ``--force``: write anyway (the files of the same names are replaced, nothing else is
        touched).
    option : str
        The option naming the folder, for the message.

    Returns
    -------
    str
        With ``force``, what was foreign there ("" if nothing): :func:`replacing_line` says it.

    Raises
    ------
    InputError
        ``folder`` is a file, or it holds results of another kind or run and ``force`` is
        False: one line naming them and ``--force``.  Called before anything is written.
    """
    d = Path(folder)
    if d.exists() and not d.is_dir():
        raise InputError(f"{d}: {option} exists and is not a folder")
    what = "; ".join(other)
    if what and not force:
        raise InputError(
            f"{d}: {option} holds {what}: choose another folder, or give --force to write "
            "into it anyway"
        )
    return what


def foreign_results(folder: str | os.PathLike[str], kind: str) -> list[str]:
    """What in ``folder`` is a result of another kind than ``kind`` (``"plan"``, ``"run"`` or
    ``"fit"``; for :func:`claim_output_folder`), each as "a run (journal.jsonl,
    measurements.csv)"."""
    return [
        f"{_KIND_WORDS[k]} ({', '.join(names)})"
        for k, names in result_files(folder).items()
        if k != kind and names
    ]


def replacing_line(
    folder: str | os.PathLike[str], names: Iterable[str], why: str = "", forced: str = ""
) -> str:
    """The one line a command prints when it replaces files in its output folder ("" when
    there is nothing to say): the paths replaced, and why that is fine (``why``: "the same
    plan") or that ``--force`` overrode what was there (``forced``, from
    :func:`claim_output_folder`)."""
    d = Path(folder)
    paths = ", ".join(str(d / n) for n in sorted(names))
    note = f"--force: {d} held {forced}" if forced else why
    if paths:
        return f"replacing {paths}" + (f" ({note})" if note else "")
    return f"--force: wrote into {d}, which held {forced}" if forced else ""


# ------------------------------------------------------------------ copying a run folder


def _link_refusal(p: Path) -> InputError:
    try:
        target = os.readlink(p)
    except OSError:
        target = "?"
    return InputError(
        f"{p}: a symbolic link (-> {target}): a run folder is copied as regular files and "
        "folders only, never through a link (it could name files outside the run); replace "
        "the link by the file itself"
    )


def _special_refusal(p: Path) -> InputError:
    return InputError(
        f"{p}: not a regular file (a pipe, socket or device): a run folder is copied as "
        "regular files and folders only"
    )


def plain_tree(folder: str | os.PathLike[str]) -> tuple[list[Path], list[Path], int]:
    """The sub-folders and files of ``folder`` (relative paths, sorted: a folder before what
    it holds) and the files' total size in bytes.  Refused (one line, exit 2) when it holds a
    symbolic link or a file that is not a regular file anywhere inside: a link is never
    followed, and a FIFO would block a copy forever."""
    root = Path(folder)
    dirs: list[Path] = []
    files: list[Path] = []
    total = 0
    stack = [Path()]
    while stack:
        rel = stack.pop()
        try:
            entries = sorted(os.scandir(root / rel), key=lambda e: e.name)
        except OSError as exc:
            raise InputError(f"{root / rel}: cannot read: {exc.strerror}") from None
        for e in entries:
            p = root / rel / e.name
            if e.is_symlink():
                raise _link_refusal(p)
            if e.is_dir(follow_symlinks=False):
                stack.append(rel / e.name)
                dirs.append(rel / e.name)
            elif e.is_file(follow_symlinks=False):
                files.append(rel / e.name)
                total += e.stat(follow_symlinks=False).st_size
            else:
                raise _special_refusal(p)
    return sorted(dirs), sorted(files), total


_write_out = os.write  # the disk boundary of a copy (the tests fill the disk here)


def _copy_plain_file(fd_in: int, src: Path, dst: Path) -> None:
    """Copy one open regular file to the new file ``dst``, keeping its mode and modification
    time.  A read error is the source's (exit 2), a write error the target's
    (:func:`write_error`: disk full is exit 3)."""
    st = os.fstat(fd_in)
    try:
        fd_out = os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise write_error(dst, exc) from None
    try:
        while True:
            try:
                chunk = os.read(fd_in, 1 << 20)
            except OSError as exc:
                raise InputError(f"{src}: cannot read: {exc.strerror}") from None
            if not chunk:
                break
            view = memoryview(chunk)
            while view:
                try:
                    n = _write_out(fd_out, view)
                except OSError as exc:
                    raise write_error(dst, exc) from None
                view = view[n:]
        os.fchmod(fd_out, _stat.S_IMODE(st.st_mode))
        os.utime(fd_out, ns=(st.st_atime_ns, st.st_mtime_ns))
    finally:
        os.close(fd_out)


def _copy_dir(dfd: int, src: Path, dst: Path) -> None:
    """Copy the folder open as ``dfd`` (path ``src``, for messages) to the new folder ``dst``;
    every entry is opened relative to its folder's descriptor without following a link, so a
    link planted while the copy runs is refused, never followed."""
    try:
        dst.mkdir()
    except OSError as exc:
        raise write_error(dst, exc) from None
    nofollow = os.O_RDONLY | os.O_NOFOLLOW
    for name in sorted(os.listdir(dfd)):
        p = src / name
        try:
            st = os.stat(name, dir_fd=dfd, follow_symlinks=False)
        except OSError as exc:
            raise InputError(f"{p}: cannot read: {exc.strerror}") from None
        if _stat.S_ISLNK(st.st_mode):
            raise _link_refusal(p)
        if not (_stat.S_ISDIR(st.st_mode) or _stat.S_ISREG(st.st_mode)):
            raise _special_refusal(p)
        flags = nofollow | (os.O_DIRECTORY if _stat.S_ISDIR(st.st_mode) else os.O_NONBLOCK)
        try:
            fd = os.open(name, flags, dir_fd=dfd)
        except OSError as exc:
            if exc.errno in (errno.ELOOP, errno.ENOTDIR):
                raise _link_refusal(p) from None
            raise InputError(f"{p}: cannot read: {exc.strerror}") from None
        try:
            mode = os.fstat(fd).st_mode
            if _stat.S_ISDIR(mode):
                _copy_dir(fd, p, dst / name)
            elif _stat.S_ISREG(mode):
                _copy_plain_file(fd, p, dst / name)
            else:
                raise _special_refusal(p)
        finally:
            os.close(fd)


def copy_plain_tree(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Copy folder ``src`` to the new folder ``dst``: regular files and folders only.

    A symbolic link or a special file anywhere in ``src`` is refused with one line (exit 2),
    never followed, even one planted while the copy runs.  A failed write is one line: exit 2
    for a path that cannot be written, 3 for the machine (disk full, I/O error).  On failure
    ``dst`` is left for the caller to remove (it is a staging folder).
    """
    s = Path(src)
    plain_tree(s)  # refuse before the first byte is copied
    try:
        fd = os.open(s, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise InputError(f"{s}: cannot read: {exc.strerror}") from None
    try:
        _copy_dir(fd, s, Path(dst))
    finally:
        os.close(fd)
