"""A real Dask cluster on loopback for the tests and benchmarks: `dask scheduler` + workers.

``DaskCluster(n_workers).start()`` starts ``dask scheduler`` on 127.0.0.1 at a free port
(the port the scheduler picked, read from its scheduler file) and ``n_workers``
``dask worker`` processes (one thread each, no nanny: the worker is the process a test may
kill), each in its own process group with its output in a log file.  Both command lines are
docs/monitoring.md's one-machine set-up (:func:`documented`: every socket bound to
127.0.0.1, dashboards included), with free ports; ``listening()`` lists the sockets the
cluster's processes listen on.  The workers' environment names the index URL file
``DaskCluster.index_url_file`` (``$QUICKHEALTH_DB_FILE``; absent until a test writes it).  ``stop()`` ends every
process group (SIGTERM, then SIGKILL after a few seconds) and is registered with atexit; a
detached watchdog kills the scheduler if the test process dies without them, and the workers
die by themselves 30 s after losing the scheduler: nothing outlives a test run.
Imported as ``qh_dask`` (tests/helpers is on the test path).
"""

from __future__ import annotations

import atexit
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs" / "monitoring.md"


def documented(kind: str) -> list[str]:
    """The arguments of docs/monitoring.md's one-machine ``dask scheduler`` or ``dask
    worker`` line (after ``dask KIND``; the worker's without the scheduler's address), with
    every fixed port made 0 (a free one)."""
    for line in DOCS.read_text().splitlines():
        words = line.split()
        if words[:2] == ["dask", kind] and "127.0.0.1" in line:
            args = words[2:] if kind == "scheduler" else words[3:]
            args = [re.sub(r"^127\.0\.0\.1:\d+$", "127.0.0.1:0", a) for a in args]
            return [("0" if k and args[k - 1] == "--port" else a) for k, a in enumerate(args)]
    raise RuntimeError(f"{DOCS}: no one-machine `dask {kind}` line")


class DaskCluster:
    def __init__(self, n_workers: int = 2) -> None:
        self.n_workers = n_workers
        self.dir = Path(tempfile.mkdtemp(prefix="qh-dask-"))
        self.address = ""
        self.scheduler: subprocess.Popen | None = None
        self.workers: dict[str, subprocess.Popen] = {}
        self._dask = str(Path(sys.executable).parent / "dask")
        self.index_url_file = self.dir / "index-url"

    def _spawn(self, name: str, argv: list[str]) -> subprocess.Popen:
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
               "QUICKHEALTH_DB_FILE": str(self.index_url_file)}  # fmt: skip
        env.pop("QUICKHEALTH_DB", None)
        log = open(self.dir / f"{name}.log", "ab")  # the child keeps its own copy
        try:
            return subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                start_new_session=True, env=env, cwd=self.dir,
            )  # fmt: skip
        finally:
            log.close()

    def start(self, timeout_s: float = 90.0) -> DaskCluster:
        atexit.register(self.stop)
        sfile = self.dir / "scheduler.json"
        self.scheduler = self._spawn(
            "scheduler",
            [self._dask, "scheduler", *documented("scheduler"),
             "--scheduler-file", str(sfile), "--idle-timeout", "900"],
        )  # fmt: skip
        t_end = time.monotonic() + timeout_s
        while not self.address:
            if self.scheduler.poll() is not None or time.monotonic() > t_end:
                self.stop()
                raise RuntimeError(f"dask scheduler did not start: {self.log('scheduler')}")
            try:
                self.address = json.loads(sfile.read_text())["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.1)
        self._watchdog()
        for i in range(self.n_workers):
            self.start_worker(f"w{i}")
        self.wait_for_workers(self.n_workers, t_end - time.monotonic())
        return self

    def _watchdog(self) -> None:
        """A detached shell that kills the scheduler once this process is gone, even when it
        dies without running atexit (the workers follow within their 30 s death timeout)."""
        script = (
            f"while kill -0 {os.getpid()} 2>/dev/null; do sleep 2; done; "
            f"kill -KILL -{self.scheduler.pid} 2>/dev/null; rm -rf {self.dir}"
        )
        subprocess.Popen(
            ["sh", "-c", script], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL, start_new_session=True,
        )  # fmt: skip

    def start_worker(self, name: str) -> None:
        self.workers[name] = self._spawn(
            name,
            [self._dask, "worker", self.address, *documented("worker"), "--name", name,
             "--no-nanny", "--death-timeout", "30", "--local-directory", str(self.dir / name)],
        )  # fmt: skip

    def wait_for_workers(self, n: int, timeout_s: float = 90.0) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s") as c:
            try:
                c.wait_for_workers(n, timeout=max(timeout_s, 1.0))
            except TimeoutError:
                self.stop()
                raise RuntimeError(f"dask workers did not join: {self.log('w0')}") from None

    def listening(self) -> list[tuple[str, int, str]]:
        """(address, port, process) of every socket the cluster's processes listen on."""
        import psutil  # a dependency of distributed

        out = []
        for name, p in [("scheduler", self.scheduler), *self.workers.items()]:
            if p is None or p.poll() is not None:
                continue
            for proc in [psutil.Process(p.pid), *psutil.Process(p.pid).children(recursive=True)]:
                for c in proc.net_connections(kind="inet"):
                    if c.status == psutil.CONN_LISTEN:
                        out.append((c.laddr.ip, c.laddr.port, name))
        return out

    def kill_worker(self, name: str) -> None:
        """SIGKILL one worker process (as a crash or the OOM killer would)."""
        p = self.workers[name]
        os.killpg(p.pid, signal.SIGKILL)
        p.wait(timeout=30)

    def log(self, name: str) -> str:
        p = self.dir / f"{name}.log"
        lines = p.read_text(errors="replace").strip().splitlines() if p.is_file() else []
        return lines[-1] if lines else "(no output)"

    def stop(self) -> None:
        procs = [p for p in [self.scheduler, *self.workers.values()] if p is not None]
        for p in procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        t_end = time.monotonic() + 2  # a dask process that ignores SIGTERM this long is killed
        for p in procs:
            try:
                p.wait(timeout=max(0.1, t_end - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                p.wait(timeout=10)
        self.scheduler, self.workers = None, {}
        shutil.rmtree(self.dir, ignore_errors=True)
