"""Fleet benchmark: reprocessing 200 archived runs, and index queries from 1 k to 100 k runs.

Part 1 archives 200 runs (20 robots × 10; copies of 10 synthetic run folders of the digital
twin, 40 poses, order-1 model) and reprocesses them (refit + workspace error, 5000 samples)
on three paths, printing the time per run:

- local processes (``--workers``, default 2);
- a real Dask cluster on loopback: ``dask scheduler`` + 2 ``dask worker`` processes;
- the index on PostgreSQL (a throw-away server, the system's pg_ctl) against SQLite:
  ``archive add``, the job list read from the index, and ``--update-index`` per run.

Part 2 fills the index with synthetic rows (100 runs per robot) and times the two queries a
fleet makes: the trend of one robot (``Archive.runs``: its runs in time order, baseline
marked) and the last run of every robot (``Archive.fleet``), at 1 k, 10 k and 100 k runs, on
both databases; at 100 k also without the ``(robot, time_utc, run_id)`` index.
Target: a trend query <= 50 ms at 100 k runs.

    .venv/bin/python benchmarks/reprocess.py [--runs 200] [--max-rows 100000] [--skip-reprocess]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests" / "helpers"))  # qh_runs, qh_pg, qh_dask


def _timed(fn, repeat: int = 1) -> float:
    """Median wall time of ``fn()`` (s)."""
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def archive_runs(root: Path, url: str | None, sources: list[Path], n: int) -> tuple[object, float]:
    from quickhealth.station.archive import Archive

    arch = Archive.open(root, url)
    t0 = time.perf_counter()
    for k in range(n):
        arch.add_run(f"ur5-{k % 20:02d}", sources[k % len(sources)], run_id=f"run{k:04d}",
                     time_utc=f"2026-{1 + (k // 20) // 28:02d}-{1 + (k // 20) % 28:02d}T08:00:00Z")  # fmt: skip
    return arch, (time.perf_counter() - t0) / n


def part1(args: argparse.Namespace, base: Path, pg) -> None:
    import qh_dask
    import qh_runs

    from quickhealth.station.reprocess import jobs_for_archive, reprocess

    print(f"== reprocessing {args.runs} archived runs (40 poses, order 1, 5000 workspace samples)")
    t0 = time.perf_counter()
    sources = [qh_runs.make_run(base / f"src{i}", i, n_poses=40, light=True) for i in range(10)]
    print(f"   made 10 source runs in {time.perf_counter() - t0:.1f} s")
    sq, sq_add = archive_runs(base / "arch-sqlite", None, sources, args.runs)
    pgu = pg.new_database("bench")
    pa, pg_add = archive_runs(base / "arch-pg", pgu, sources, args.runs)
    index = {}
    for name, arch in (("SQLite", sq), ("PostgreSQL", pa)):
        t0 = time.perf_counter()
        jobs = jobs_for_archive(arch, tag="bench", workspace_samples=5000)
        index[name] = [time.perf_counter() - t0]
    t0 = time.perf_counter()
    res = reprocess(jobs, workers=args.workers)  # the jobs never touch the index
    t_local = time.perf_counter() - t0
    assert all(r.ok for r in res), [r.error for r in res if not r.ok][:3]
    for name, arch in (("SQLite", sq), ("PostgreSQL", pa)):
        t0 = time.perf_counter()
        for r in res:
            arch.update_figures(r.robot, r.run_id, r.figures_mm)
        index[name].append(time.perf_counter() - t0)
    cl = qh_dask.DaskCluster(n_workers=2).start()
    try:
        djobs = jobs_for_archive(sq, tag="bench-dask", workspace_samples=5000)
        reprocess(djobs[:4], scheduler=cl.address)  # workers import quickhealth once
        t0 = time.perf_counter()
        dres = reprocess(djobs, scheduler=cl.address)
        t_dask = time.perf_counter() - t0
    finally:
        cl.stop()
    same = all(
        a.coeffs == b.coeffs and a.figures_mm == b.figures_mm
        for a, b in zip(res, dres, strict=True)
    )
    n = args.runs
    print(f"   {'path':<44} {'per run':>10} {'total':>8}")
    print(f"   {f'local processes ({args.workers} workers)':<44} "
          f"{t_local / n * 1e3:8.1f} ms {t_local:7.1f} s")  # fmt: skip
    print(f"   {'Dask cluster, 2 worker processes (loopback)':<44} "
          f"{t_dask / n * 1e3:8.1f} ms {t_dask:7.1f} s   same results as local: {same}")  # fmt: skip
    print("   the index, per run:                   SQLite    PostgreSQL")
    print(f"     archive add (copy + index)        {sq_add * 1e3:7.2f} ms  {pg_add * 1e3:7.2f} ms")
    for i, what in enumerate(("jobs read from the index", "--update-index (a transaction)")):
        print(f"     {what:<32}  {index['SQLite'][i] / n * 1e3:7.2f} ms  "
              f"{index['PostgreSQL'][i] / n * 1e3:7.2f} ms")  # fmt: skip
    for name in ("SQLite", "PostgreSQL"):
        tot = t_local + sum(index[name])
        print(f"   reprocess --update-index, local, {name} index: {tot / n * 1e3:.1f} ms per run")


def _fill(arch, n: int, start: int) -> None:
    """Synthetic index rows: robots of 100 runs each, one run a week."""
    import sqlalchemy as sa

    rows = []
    for k in range(start, n):
        robot, i = f"robot-{k // 100:05d}", k % 100
        rows.append({
            "robot": robot, "run_id": f"r{i:03d}",
            "time_utc": f"{2024 + i // 52}-{1 + (i % 52) // 5:02d}-{1 + (i % 52) % 5 * 5:02d}T08:00:00Z",
            "path": f"robots/{robot}/r{i:03d}", "plan_hash": "p", "cell": "c",
            "calibration_id": "cal", "software_version": "0.1.0",
            "mean_mm": 0.2, "std_mm": 0.05, "max_mm": 0.4 + 1e-3 * i, "healthy": True,
        })  # fmt: skip
    robots = sorted({r["robot"] for r in rows})
    with arch.engine.begin() as con:
        for j in range(0, len(rows), 5000):
            con.execute(sa.insert(arch.index.t_runs), rows[j : j + 5000])
        con.execute(
            sa.insert(arch.index.t_robots), [{"robot": r, "baseline_run_id": None} for r in robots]
        )


def part2(args: argparse.Namespace, base: Path, pg) -> None:
    import sqlalchemy as sa

    from quickhealth.station.archive import Archive

    sizes = [s for s in (1_000, 10_000, 100_000) if s <= args.max_rows]
    print("== index queries (100 runs per robot; median of repeated queries)")
    print(
        f"   {'runs':>8} {'robots':>7}   {'trend of one robot':>22}   {'last run of every robot':>26}"
    )
    print(f"   {'':>8} {'':>7}   {'SQLite':>10} {'PostgreSQL':>11}   {'SQLite':>12} {'PostgreSQL':>13}")  # fmt: skip
    archs = {
        "SQLite": Archive.open(base / "q-sqlite"),
        "PostgreSQL": Archive.open(base / "q-pg", pg.new_database("query")),
    }
    have = 0
    res = {}
    for n in sizes:
        for name, a in archs.items():
            _fill(a, n, have)
            if name == "PostgreSQL":
                with a.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as c:
                    c.execute(sa.text("analyze"))
            robot = f"robot-{n // 200:05d}"
            a.runs(robot)
            t_trend = _timed(lambda a=a, robot=robot: a.runs(robot), 30)
            t_fleet = _timed(a.fleet, 3)
            res[(n, name)] = (t_trend, t_fleet)
        have = n
        (st, sf), (pt, pf) = res[(n, "SQLite")], res[(n, "PostgreSQL")]
        print(f"   {n:>8} {n // 100:>7}   {st * 1e3:7.2f} ms {pt * 1e3:8.2f} ms   "
              f"{sf * 1e3:9.1f} ms {pf * 1e3:10.1f} ms")  # fmt: skip
    n = sizes[-1]
    for name, a in archs.items():  # the same trend query without the (robot, time) index
        with a.engine.begin() as con:
            con.execute(sa.text("drop index ix_runs_robot_time"))
        robot = f"robot-{n // 200:05d}"
        t = _timed(lambda a=a, robot=robot: a.runs(robot), 30)
        tf = _timed(a.fleet, 3)
        print(f"   {name} at {n} runs without ix_runs_robot_time: trend {t * 1e3:.2f} ms, "
              f"last runs {tf * 1e3:.1f} ms")  # fmt: skip
    worst = max(res[(n, k)][0] for k in archs)
    print(
        f"   target: trend query <= 50 ms at {n} runs: {worst * 1e3:.2f} ms "
        + ("(met)" if worst <= 0.05 else "(NOT met)")
    )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-rows", type=int, default=100_000)
    ap.add_argument("--skip-reprocess", action="store_true", help="only the index queries")
    args = ap.parse_args()
    import qh_pg

    pg = qh_pg.PgServer().start()
    try:
        with tempfile.TemporaryDirectory(prefix="qh-bench-") as d:
            if not args.skip_reprocess:
                part1(args, Path(d), pg)
            part2(args, Path(d), pg)
    finally:
        pg.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
