"""A throw-away PostgreSQL server for the tests and benchmarks (the system's ``pg_ctl``).

``PgServer.start()`` runs ``initdb`` and ``pg_ctl start`` in a fresh temporary folder, on
127.0.0.1 at a free port, trust authentication, superuser ``qh``.  PostgreSQL refuses to run
as root: when we are root the server runs as the ``postgres`` user (created by Debian's
``postgresql`` package) through ``runuser``.  ``new_database()`` gives each test its own
database; ``stop()`` stops the server (immediate mode) and removes its folder, as does a
detached watchdog once the test process is gone however it died.  Imported as
``qh_pg`` (tests/helpers is on the test path).
"""

from __future__ import annotations

import atexit
import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path


class PgUnavailable(RuntimeError):
    """The server cannot be started here (message: one line saying why)."""


def find_pg_bin() -> Path | None:
    """Folder of the newest ``pg_ctl`` (Debian: /usr/lib/postgresql/N/bin), else PATH."""
    found = sorted(
        glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"),
        key=lambda p: int(Path(p).parts[-3]) if Path(p).parts[-3].isdigit() else 0,
    )
    if found:
        return Path(found[-1]).parent
    w = shutil.which("pg_ctl")
    return Path(w).parent if w else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class PgServer:
    def __init__(self) -> None:
        self.bin = find_pg_bin()
        self.base: Path | None = None
        self.port = 0
        self._n = 0
        self._running = False

    def _cmd(self, *argv: str) -> list[str]:
        if os.geteuid() == 0:
            return ["runuser", "-u", "postgres", "--", *argv]
        return list(argv)

    def start(self) -> PgServer:
        if self.bin is None:
            raise PgUnavailable(
                "PostgreSQL: no pg_ctl under /usr/lib/postgresql/*/bin or on PATH "
                "(install the Debian postgresql package: make postgres)"
            )
        if os.geteuid() == 0:
            try:
                pw = pwd.getpwnam("postgres")
            except KeyError:
                raise PgUnavailable(
                    "PostgreSQL: running as root but there is no 'postgres' user to run the "
                    "server as (reinstall the Debian postgresql package)"
                ) from None
        self.base = Path(tempfile.mkdtemp(prefix="qh-pg-"))
        if os.geteuid() == 0:
            os.chown(self.base, pw.pw_uid, pw.pw_gid)
        data, log = self.base / "data", self.base / "server.log"
        env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
        r = subprocess.run(
            self._cmd(
                str(self.bin / "initdb"),
                "-D",
                str(data),
                "-A",
                "trust",
                "-U",
                "qh",
                "-E",
                "UTF8",
                "--no-sync",
                "--no-instructions",
            ),  # fmt: skip
            capture_output=True,
            text=True,
            env=env,
            timeout=120,
        )
        if r.returncode != 0:
            last = (r.stderr.strip() or r.stdout.strip() or "?").splitlines()[-1]
            self._cleanup()
            raise PgUnavailable(f"PostgreSQL: initdb failed: {last}")
        self.port = _free_port()
        opts = (
            f"-p {self.port} -k {self.base} -c listen_addresses=127.0.0.1 -c fsync=off "
            "-c synchronous_commit=off -c full_page_writes=off -c max_connections=200"
        )
        r = subprocess.run(
            self._cmd(
                str(self.bin / "pg_ctl"),
                "-D",
                str(data),
                "-o",
                opts,
                "-l",
                str(log),
                "-w",
                "-t",
                "60",
                "start",
            ),  # fmt: skip
            capture_output=True,
            text=True,
            env=env,
            stdin=subprocess.DEVNULL,
            timeout=120,
        )
        if r.returncode != 0:
            tail = log.read_text().strip().splitlines()[-1:] if log.is_file() else []
            self._cleanup()
            raise PgUnavailable(
                "PostgreSQL: pg_ctl start failed: " + (tail[0] if tail else r.stderr.strip())
            )
        self._running = True
        atexit.register(self.stop)
        self._watchdog()
        return self

    def _watchdog(self) -> None:
        """A detached shell that stops the server once this process is gone, even when it
        dies without running atexit (a segfault, SIGKILL): no server outlives its test run."""
        stop = " ".join(
            self._cmd(
                str(self.bin / "pg_ctl"), "-D", str(self.base / "data"), "-m", "immediate", "stop"
            )
        )
        script = (
            f"while kill -0 {os.getpid()} 2>/dev/null; do sleep 2; done; "
            f"[ -d {self.base} ] && {{ {stop}; rm -rf {self.base}; }}"
        )
        subprocess.Popen(
            ["sh", "-c", script],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )

    def url(self, database: str = "postgres") -> str:
        """SQLAlchemy URL of a database on this server."""
        return f"postgresql+psycopg://qh@127.0.0.1:{self.port}/{database}"

    def new_database(self, prefix: str = "t") -> str:
        """A fresh empty database; its SQLAlchemy URL."""
        import sqlalchemy as sa

        self._n += 1
        name = f"{prefix}_{os.getpid()}_{self._n}"
        eng = sa.create_engine(self.url(), isolation_level="AUTOCOMMIT")
        try:
            with eng.connect() as con:
                con.execute(sa.text(f'create database "{name}"'))
        finally:
            eng.dispose()
        return self.url(name)

    def stop(self) -> None:
        if self._running and self.base is not None:
            self._running = False
            subprocess.run(
                self._cmd(
                    str(self.bin / "pg_ctl"),
                    "-D",
                    str(self.base / "data"),
                    "-m",
                    "immediate",
                    "-w",
                    "stop",
                ),  # fmt: skip
                capture_output=True,
                timeout=60,
            )
        self._cleanup()

    def _cleanup(self) -> None:
        if self.base is not None:
            shutil.rmtree(self.base, ignore_errors=True)
            self.base = None
