"""Many stations at once: 8 processes archive and trend 10 runs each into one index.

On SQLite (one shared archive folder) and on a real PostgreSQL server.  Four of the eight are
killed in the middle of a write: three SIGKILL themselves at a fixed point of one
``add_run`` (mid-copy, row inserted, folder renamed in but not committed), one is SIGKILLed
from outside at a random moment.  Afterwards: no run lost (every run a station finished is
there), none doubled, none half-written (every indexed run's folder equals its source), the
index is valid, and a killed run can be archived again.
"""

import filecmp
import json
import multiprocessing as mp
import random
import time
from pathlib import Path

import pytest
import qh_fleet
import qh_runs as _runs

from quickhealth.station.archive import MARKER, Archive, report_figures
from quickhealth.station.formats import load_json_limited

N_STATIONS, N_RUNS, KILL_RUN = 8, 10, 4
KILLS = {5: "copy", 6: "insert", 7: "rename"}  # station -> where it kills itself
SHOT = 4  # the station killed from outside


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """Five small synthetic run folders (25 poses, order 1) with a few image files."""
    base = tmp_path_factory.mktemp("fleet-src")
    out = []
    for i in range(5):
        d = _runs.make_run(base / f"src{i}", i, n_poses=25, light=True)
        (d / "images").mkdir()
        for j in range(4):  # copying takes a little while, as a real run's images do
            (d / "images" / f"{j:04d}_L.png").write_bytes(bytes([i, j]) * 100_000)
        out.append(str(d))
    return out


def _same_tree(a: Path, b: Path) -> bool:
    cmp = filecmp.dircmp(a, b, ignore=[MARKER])  # the archive's mark of the index
    if cmp.left_only or cmp.right_only or cmp.funny_files:
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    return not mismatch and not errors and all(_same_tree(a / d, b / d) for d in cmp.common_dirs)


def _fleet(tmp_path, url, sources):
    root = tmp_path / "shared-archive"
    Archive.open(root, url)  # the schema exists before the stations start (they race too)
    figures = {
        s: report_figures(load_json_limited(Path(s) / "report.json"))[0]["max"] for s in sources
    }
    # children fork from a clean single-threaded server that imported the code once
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(["qh_fleet", "quickhealth.station.commands.archive"])
    procs = {}
    for k in range(N_STATIONS):
        args = (url, str(root), f"ur5-{k % 4}", k, sources, figures, N_RUNS,
                str(tmp_path / f"progress{k}"), str(tmp_path / f"result{k}.json"),
                KILLS.get(k), KILL_RUN)  # fmt: skip
        procs[k] = ctx.Process(target=qh_fleet.station, args=args)
    for p in procs.values():
        p.start()
    # shoot one station at a random moment once it has archived a few runs
    prog = tmp_path / f"progress{SHOT}"
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end and procs[SHOT].is_alive():
        if prog.is_file() and len(prog.read_text().split()) >= 3:
            time.sleep(random.Random().uniform(0.0, 0.2))
            procs[SHOT].kill()
            break
        time.sleep(0.005)
    for p in procs.values():
        p.join(timeout=240)
    for p in procs.values():
        if p.is_alive():
            p.kill()
            pytest.fail("a station hung for 4 minutes", pytrace=False)
    return root, procs


@pytest.mark.slow
@pytest.mark.parametrize("db", ["sqlite", "postgresql"])
def test_eight_stations_at_once_with_kills(tmp_path, sources, db, request):
    url = None if db == "sqlite" else request.getfixturevalue("pg_server").new_database("fleet")
    root, procs = _fleet(tmp_path, url, sources)
    arch = Archive.open(root, url)
    # the shot must have landed mid-run (it waits for 3 of 10 runs), else the random kill
    # went untested
    assert procs[SHOT].exitcode == -9, ("station shot from outside", procs[SHOT].exitcode)
    killed = set(KILLS) | {SHOT}
    for k, p in procs.items():
        if k in killed:
            assert p.exitcode == -9, (k, p.exitcode)  # SIGKILL, not an exception
        else:
            assert p.exitcode == 0, (k, p.exitcode)
            res = json.loads((tmp_path / f"result{k}.json").read_text())
            assert res["errors"] == [] and res["trends"] == N_RUNS, res
    if db == "sqlite":
        import sqlite3

        con = sqlite3.connect(root / "index.sqlite")
        assert con.execute("pragma integrity_check").fetchone()[0] == "ok"
        con.close()
    rows = [(r.robot, r.run_id) for rb in arch.robots() for r in arch.runs(rb)]
    doubled = len(rows) - len(set(rows))
    lost, partial, inflight = [], [], []
    for k in range(N_STATIONS):
        done = (tmp_path / f"progress{k}").read_text().split()
        robot = f"ur5-{k % 4}"
        for i in range(N_RUNS):
            rid = qh_fleet.run_id(k, i)
            there = (robot, rid) in rows
            if rid in done and not there:
                lost.append(rid)
            if there:
                src = Path(qh_fleet.source_of(sources, k, i))
                if not _same_tree(src, arch.folder(arch.get(robot, rid))):
                    partial.append(rid)
            if rid not in done and there:
                inflight.append(rid)  # killed after its commit, before it wrote progress
    n_expected = (N_STATIONS - len(killed)) * N_RUNS
    print(
        f"\n{db}: {len(rows)} runs indexed ({n_expected} from the stations that lived), "
        f"{len(lost)} lost, {doubled} doubled, {len(partial)} partial; killed stations "
        f"{sorted(killed)}; leftovers without a row: {[p.name for p in arch.orphans()]}"
    )
    assert not lost and not doubled and not partial, (lost, doubled, partial)
    for k, where in KILLS.items():  # killed before the commit: the run is not in the index
        robot, rid = f"ur5-{k % 4}", qh_fleet.run_id(k, KILL_RUN)
        assert (tmp_path / f"progress{k}").read_text().split() == [
            qh_fleet.run_id(k, i) for i in range(KILL_RUN)
        ], where
        assert (robot, rid) not in rows, where
        # the station's next attempt archives it whole, over any leftover of the killed one
        arch.add_run(robot, qh_fleet.source_of(sources, k, KILL_RUN), run_id=rid,
                     time_utc=qh_fleet.run_time(k, KILL_RUN))  # fmt: skip
        assert _same_tree(
            Path(qh_fleet.source_of(sources, k, KILL_RUN)), arch.folder(arch.get(robot, rid))
        )
    # the shot station's run in flight: absent from the index, or there whole (checked above);
    # a folder it may have renamed in before its commit is an orphan the next attempt replaces
    robot = f"ur5-{SHOT % 4}"
    done = (tmp_path / f"progress{SHOT}").read_text().split()
    flying = next(i for i in range(N_RUNS) if qh_fleet.run_id(SHOT, i) not in done)
    rid = qh_fleet.run_id(SHOT, flying)
    if (robot, rid) not in rows:
        arch.add_run(robot, qh_fleet.source_of(sources, SHOT, flying), run_id=rid,
                     time_utc=qh_fleet.run_time(SHOT, flying))  # fmt: skip
        assert _same_tree(
            Path(qh_fleet.source_of(sources, SHOT, flying)), arch.folder(arch.get(robot, rid))
        )
    assert not [p for p in arch.orphans() if not p.name.startswith(".incoming-")]
    # the trends still read cleanly after the kills
    from quickhealth.station.archive import trend_for

    for rb in arch.robots():
        assert len(trend_for(arch, rb).run_ids) == len(arch.runs(rb))
