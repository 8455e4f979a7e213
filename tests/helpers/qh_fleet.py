"""Many stations at once on one archive: the station process of the concurrency test.

``station()`` runs in its own process: it archives ``n_runs`` runs of one robot (copies of
small synthetic run folders, each under its own run id and time) and after each one reads the
robot's trend and the fleet view, checking that what it reads is consistent.  It appends one
line per archived run to ``progress`` (so a killed station still says what it finished) and
writes its findings to ``result`` at the end.  ``kill_at`` makes the station SIGKILL itself in
the middle of one write: ``copy`` (after two files of the run are copied), ``insert`` (row
inserted, transaction open), ``rename`` (folder renamed into place, transaction not yet
committed).  Imported as ``qh_fleet`` (tests/helpers is on the test path).
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path


def run_id(station: int, i: int) -> str:
    return f"s{station}-{i:02d}"


def run_time(station: int, i: int) -> str:
    return f"2026-01-{i + 1:02d}T{station:02d}:00:00Z"


def source_of(sources: list[str], station: int, i: int) -> str:
    return sources[(station + i) % len(sources)]


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _arm(kill_at: str, rid: str) -> None:
    """Make this process kill itself at one point of the next ``add_run`` of ``rid``."""
    from quickhealth.station.archive.index import Index

    if kill_at == "copy":
        from quickhealth.station import fsio

        real, n = fsio._copy_plain_file, [0]

        def copyfile(*a, **k):
            n[0] += 1
            if n[0] > 2:
                _die()
            return real(*a, **k)

        fsio._copy_plain_file = copyfile
    elif kill_at == "insert":
        Index._insert_robot = lambda self, robot: _die()
    elif kill_at == "rename":
        real_rename = Path.rename

        def rename(self, target):
            out = real_rename(self, target)
            if Path(target).name == rid:
                _die()
            return out

        Path.rename = rename
    else:
        raise ValueError(kill_at)


def station(
    url: str | None,
    root: str,
    robot: str,
    k: int,
    sources: list[str],
    figures: dict[str, float],
    n_runs: int,
    progress: str,
    result: str,
    kill_at: str | None = None,
    kill_run: int = 4,
) -> None:
    from quickhealth.station.archive import Archive, trend_for

    arch = Archive.open(root, url)
    errors: list[str] = []
    seen: set[str] = set()
    counts: dict[str, int] = {}
    mine: list[str] = []
    n_trends = 0
    for i in range(n_runs):
        rid = run_id(k, i)
        if kill_at is not None and i == kill_run:
            _arm(kill_at, rid)
        arch.add_run(robot, source_of(sources, k, i), run_id=rid, time_utc=run_time(k, i))
        mine.append(rid)
        with open(progress, "a") as fh:
            fh.write(rid + "\n")
        res = trend_for(arch, robot)
        n_trends += 1
        ids = list(res.run_ids)
        times = [arch.get(robot, r).time_utc for r in ids] if i == n_runs - 1 else None
        if len(set(ids)) != len(ids):
            errors.append(f"trend after {rid}: a run twice: {ids}")
        if not set(mine) <= set(ids):
            errors.append(f"trend after {rid}: own runs missing: {sorted(set(mine) - set(ids))}")
        if not seen <= set(ids):
            errors.append(f"trend after {rid}: runs vanished: {sorted(seen - set(ids))}")
        if times is not None and times != sorted(times):
            errors.append(f"trend after {rid}: not in time order")
        for j, r in enumerate(ids):  # every run's folder agrees with its source
            st, idx = int(r[1 : r.index("-")]), int(r[r.index("-") + 1 :])
            want = figures[source_of(sources, st, idx)]
            if abs(res.figures_mm["max"][j] - want) > 1e-9:
                errors.append(f"trend after {rid}: {r} max {res.figures_mm['max'][j]} != {want}")
        seen |= set(ids)
        for last, n, _ in arch.fleet():  # the fleet view never goes back
            if n < counts.get(last.robot, 0):
                errors.append(f"fleet view after {rid}: {last.robot} went from {counts} to {n}")
            counts[last.robot] = n
    Path(result).write_text(json.dumps({"errors": errors, "trends": n_trends}))
