"""The archive index's database: time-outs on every operation, every failure one line.

:class:`IndexDB` wraps the SQLAlchemy engine of an archive index (SQLite by default, any
SQLAlchemy URL, PostgreSQL for a fleet).  Every index operation runs inside
:meth:`IndexDB.guard`, which

- bounds it in time (``timeout_s``: ``--db-timeout``, else ``$QUICKHEALTH_DB_TIMEOUT``, else
  10 s): on PostgreSQL the connection attempt (``connect_timeout``), each statement on the
  server (``statement_timeout``, lock waits included) and, for a server that stops
  answering altogether, the whole operation on the client (a watchdog that shuts the
  connection's socket down after three time-outs); on SQLite the wait for another
  station's write lock (the busy time-out) and each statement (a progress handler);
- turns every database failure into one line: :class:`InputError` (exit 2) for a URL that
  is not one, an unknown database kind or a missing driver, an index file that is damaged,
  not a database, a folder or in a folder that does not exist, a database that is not a
  quickhealth index; :class:`HardwareError` (exit 3) for a server that cannot be reached,
  refuses the connection or does not answer in time, and a lock held too long.

The URL is never printed with its password, and never has to be typed on a command line
(where every user of the machine sees it in ``ps``): :func:`index_url` also takes it from
``$QUICKHEALTH_DB`` or from the file ``$QUICKHEALTH_DB_FILE`` names.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from stat import S_ISREG
from typing import Any

from ...identify.errors import HardwareError, InputError, QuickhealthError

TIMEOUT_ENV = "QUICKHEALTH_DB_TIMEOUT"
URL_ENV = "QUICKHEALTH_DB"
URL_FILE_ENV = "QUICKHEALTH_DB_FILE"
DEFAULT_TIMEOUT_S = 10.0
#: the client-side watchdog of one PostgreSQL operation, in time-outs (connect, statements)
WATCHDOG_TIMEOUTS = 3.0


def timeout_s(value: float | None = None) -> float:
    """The index time-out: ``value``, else ``$QUICKHEALTH_DB_TIMEOUT``, else 10 s."""
    if value is None:
        text = os.environ.get(TIMEOUT_ENV)
        if text is None:
            return DEFAULT_TIMEOUT_S
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"{TIMEOUT_ENV}={text!r}: not a number of seconds") from None
        where = f"{TIMEOUT_ENV}={text!r}"
    else:
        where = f"--db-timeout {value!r}"
    if not (math.isfinite(value) and 0 < value <= 3600):
        raise InputError(f"{where}: the index time-out must be in (0, 3600] s")
    return float(value)


def index_url(given: str | None = None) -> str | None:
    """The index URL: ``given`` (``--db``), else ``$QUICKHEALTH_DB``, else the first line of
    the file ``$QUICKHEALTH_DB_FILE`` names (a file only its owner may read), else None (the
    archive's own SQLite index).  A Dask worker finds the index this way: jobs never carry
    it (:mod:`quickhealth.station.reprocess`).

    Raises
    ------
    InputError
        The file is missing, empty, not a plain file, or others may read it (one line).
    """
    if given:
        return given
    env = os.environ.get(URL_ENV)
    if env:
        return env.strip()
    name = os.environ.get(URL_FILE_ENV)
    if not name:
        return None
    where = f"{URL_FILE_ENV}={name}"
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise InputError(f"{where}: cannot read the index URL: {exc.strerror}") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not S_ISREG(st.st_mode):
            raise InputError(f"{where}: not a plain file")
        if st.st_mode & 0o077:
            raise InputError(
                f"{where}: others may read it (mode {st.st_mode & 0o777:04o}) and the index "
                f"password in it: chmod 600 {name}"
            )
        first = fh.read(4096).decode("utf-8", "replace").strip().splitlines()
    if not first or not first[0].strip():
        raise InputError(f"{where}: empty; expected the index URL on its first line")
    return first[0].strip()


def shown(url: str) -> str:
    """The URL as it may be printed: without its password."""
    import sqlalchemy as sa  # SQLAlchemy (~0.3 s) only once an index is used

    try:
        return sa.engine.make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - an unparsable URL is shown cut, never its secrets
        return url.split("@")[-1][:80]


class IndexDB:
    """The engine of one archive index with its time-outs and error translation."""

    def __init__(self, url: str, timeout: float | None = None) -> None:
        import sqlalchemy as sa  # SQLAlchemy (~0.3 s) only once an index is used

        self._sa = sa
        self.timeout_s = timeout_s(timeout)
        try:
            self.parsed = sa.engine.make_url(url)
        except sa.exc.ArgumentError:
            raise InputError(
                f"--db {url[:80]!r}: not a database URL (e.g. sqlite:///PATH/index.sqlite or "
                "postgresql+psycopg://user@host/quickhealth)"
            ) from None
        self.url = url
        self.shown = shown(url)
        self.kind = self.parsed.get_backend_name()
        self.sqlite = self.kind == "sqlite"
        self.pg = self.kind == "postgresql"
        self._cons: weakref.WeakSet[Any] = weakref.WeakSet()
        self._deadline = math.inf  # SQLite statements: the progress handler's limit
        try:
            self.engine = self._make_engine()
        except (sa.exc.NoSuchModuleError, ImportError) as exc:
            raise InputError(
                f"--db {self.shown}: cannot use a {self.kind!r} database here "
                f"({str(exc).splitlines()[0][:120]}); the index is SQLite or PostgreSQL "
                "(postgresql+psycopg://…, pip install -e '.[postgres]')"
            ) from None
        except sa.exc.ArgumentError as exc:
            raise InputError(f"--db {self.shown}: {str(exc).splitlines()[0][:200]}") from None

    @property
    def sqlite_path(self) -> Path | None:
        """The index file of an SQLite URL (None: in memory, or another database)."""
        db = self.parsed.database if self.sqlite else None
        return Path(db) if db and db != ":memory:" and not db.startswith("file:") else None

    @property
    def name(self) -> str:
        """The index as messages name it: its file (SQLite), else its URL without password."""
        p = self.sqlite_path
        return str(p) if p is not None else self.shown

    def _make_engine(self) -> Any:
        """SQLite made safe for many writing processes, PostgreSQL with its time-outs.

        SQLite: each connection waits up to the time-out for another station's lock;
        transactions start with ``BEGIN`` (readers: one snapshot) or ``BEGIN IMMEDIATE``
        (writers: the write lock up front, so two writers never deadlock upgrading their
        locks).  The rollback journal (not WAL) keeps the index usable on a shared network
        folder.
        """
        sa = self._sa
        t = self.timeout_s
        if self.pg:
            eng = sa.create_engine(
                self.url,
                pool_pre_ping=True,
                connect_args={
                    "connect_timeout": max(2, math.ceil(t)),  # libpq's smallest
                    "options": f"-c statement_timeout={int(t * 1000)}",
                },
            )
        elif not self.sqlite:
            return sa.create_engine(self.url, pool_pre_ping=True)
        else:
            eng = sa.create_engine(self.url, connect_args={"timeout": t})

        @sa.event.listens_for(eng, "connect")
        def _connect(dbapi_con: Any, _rec: Any) -> None:
            if self.sqlite:
                dbapi_con.isolation_level = None  # we issue BEGIN ourselves
                dbapi_con.set_progress_handler(self._over_time, 10_000)
            else:
                try:
                    self._cons.add(dbapi_con)
                except TypeError:  # pragma: no cover - a driver without weak references
                    pass

        if self.sqlite:

            @sa.event.listens_for(eng, "begin")
            def _begin(con: Any) -> None:
                write = con.get_execution_options().get("qh_write", False)
                con.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")

        return eng

    def _over_time(self) -> int:
        """SQLite's progress handler: non-zero interrupts the running statement."""
        return 1 if time.monotonic() > self._deadline else 0

    def _cut(self, fired: threading.Event) -> None:
        """The watchdog: shut the socket of every connection down, so a call blocked on a
        server that stopped answering returns with an error at once."""
        fired.set()
        for con in list(self._cons):
            try:
                fd = con.fileno()
                s = socket.socket(fileno=os.dup(fd))
            except (OSError, AttributeError, ValueError, TypeError):
                continue
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            finally:
                s.close()

    @contextmanager
    def guard(self, what: str = "") -> Iterator[None]:
        """Bound one index operation in time and turn its failures into one line."""
        sa = self._sa
        fired = threading.Event()
        timer = None
        outer = self._deadline
        if self.pg:
            timer = threading.Timer(WATCHDOG_TIMEOUTS * self.timeout_s, self._cut, (fired,))
            timer.daemon = True
            timer.start()
        elif self.sqlite:
            self._deadline = min(outer, time.monotonic() + self.timeout_s)
        try:
            yield
        except sa.exc.SQLAlchemyError as exc:
            raise self.translate(exc, fired.is_set(), what) from None
        finally:
            if timer is not None:
                timer.cancel()
            self._deadline = outer

    # ------------------------------------------------------------------ messages

    def translate(self, exc: BaseException, timed_out: bool = False, what: str = "") -> Exception:
        """The one-line error of a database failure (see the module's docstring)."""
        sa = self._sa
        orig = getattr(exc, "orig", None) or exc
        text = " ".join(str(orig).split()) or type(orig).__name__
        first = text[:200]
        doing = f" ({what})" if what else ""
        t = f"{self.timeout_s:g} s"
        if self.sqlite:
            return self._sqlite_error(text, first, doing)
        if "timeout expired" in text:  # connecting: libpq waits at least 2 s
            t = f"{max(2, math.ceil(self.timeout_s))} s"
        if timed_out or "timeout expired" in text:
            return HardwareError(
                f"the index server {self.shown} did not answer within {t}{doing}: is it up "
                f"and reachable? (--db-timeout or {TIMEOUT_ENV} sets the time-out)"
            )
        if "statement timeout" in text or "canceling statement" in text:
            return HardwareError(
                f"the index server {self.shown} did not finish{doing} within {t}: a lock held "
                f"by another station, or the server overloaded ({first})"
            )
        if isinstance(exc, sa.exc.ProgrammingError | sa.exc.NoSuchTableError):
            return InputError(
                f"--db {self.shown}: not a quickhealth archive index ({first}); give the "
                "index's own database"
            )
        if isinstance(exc, sa.exc.DBAPIError | sa.exc.TimeoutError):
            return HardwareError(f"cannot use the index server {self.shown}{doing}: {first}")
        return QuickhealthError(f"the index {self.shown}{doing}: {first}")

    def _sqlite_error(self, text: str, first: str, doing: str) -> Exception:
        p = self.sqlite_path
        name = str(p) if p is not None else self.shown
        low = text.lower()
        if "unable to open database file" in low:
            why = "cannot open it"
            if p is not None:
                if p.is_dir():
                    why = "it is a folder, not an index file"
                elif not p.parent.is_dir():
                    why = f"its folder {p.parent} does not exist"
                elif not os.access(p.parent, os.W_OK):
                    why = f"no permission to write in {p.parent}"
            return InputError(f"{name}: not a usable archive index: {why}")
        if "not a database" in low or "malformed" in low or "no such table" in low:
            return InputError(
                f"{name}: the archive index is damaged or not a quickhealth index ({first}); "
                "restore it from a backup"
            )
        if "no such column" in low or "has no column" in low:
            return InputError(
                f"{name}: not a quickhealth archive index (other columns: {first}); restore it "
                "from a backup"
            )
        if "readonly" in low or "read-only" in low:
            return InputError(f"{name}: the archive index is read-only{doing}: {first}")
        if "locked" in low or "busy" in low:
            return HardwareError(
                f"{name}: the archive index stayed locked by another station for "
                f"{self.timeout_s:g} s{doing} (--db-timeout or {TIMEOUT_ENV} waits longer)"
            )
        if "interrupted" in low:
            return HardwareError(
                f"{name}: an index operation{doing} took longer than {self.timeout_s:g} s"
            )
        return HardwareError(f"{name}: the archive index failed{doing}: {first}")
