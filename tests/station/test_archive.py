"""The run archive: folders plus index, many robots, baselines, names that cannot escape."""

import json
import sqlite3

import numpy as np
import pytest
import qh_runs as _runs

from quickhealth.identify.errors import InputError
from quickhealth.station.archive import MARKER, Archive, default_root, run_state, safe_name
from quickhealth.station.archive.folders import mark
from quickhealth.station.cli import main


@pytest.fixture(scope="module")
def run_dirs(tmp_path_factory):
    base = tmp_path_factory.mktemp("runs")
    runs = [
        _runs.make_run(base / f"r{i}", i, n_poses=30, time_utc=f"2026-0{i + 1}-01T08:00:00Z")
        for i in range(3)
    ]
    runs.append(  # a month later joint 2 tilts by 0.5 mrad more about x
        _runs.make_run(
            base / "r3", 3, n_poses=30, time_utc="2026-04-01T08:00:00Z", degrade={"j2.ex.c0": 5e-4}
        )
    )
    return runs


def test_runs_of_many_robots_with_metadata(tmp_path, run_dirs, index_url):
    a = Archive.open(tmp_path / "arch", url=index_url)
    for d in run_dirs[:3]:
        a.add_run("ur5-a", d)
    a.add_run("ur5-b", run_dirs[0], run_id="first", meta={"cell": "cell-7"})
    assert a.robots() == ["ur5-a", "ur5-b"]
    recs = a.runs("ur5-a")
    assert [r.run_id for r in recs] == ["r0", "r1", "r2"]
    assert recs[0].plan_hash == "plan-a" and recs[0].cell == "reference"
    assert recs[0].calibration_id == "cal-1" and recs[0].software_version
    assert a.runs("ur5-b")[0].cell == "cell-7"
    assert 0.05 < recs[0].mean_mm < recs[0].max_mm < 5.0
    assert (tmp_path / "arch" / "robots" / "ur5-a" / "r1" / "model.json").is_file()
    if index_url is None:  # the index is a plain SQLite file other tools can read
        con = sqlite3.connect(tmp_path / "arch" / "index.sqlite")
        assert con.execute("select count(*) from runs").fetchone()[0] == 4
    else:
        assert not (tmp_path / "arch" / "index.sqlite").exists()
    # the fleet view: every robot's latest run, its count and baseline, in three queries
    assert [(r.robot, r.run_id, n, b) for r, n, b in a.fleet()] == [
        ("ur5-a", "r2", 3, "r0"),
        ("ur5-b", "first", 1, "first"),
    ]
    # the trend's view of a run: figures, model with covariance, metadata
    st = run_state(a, recs[1])
    assert st.spec is not None and st.cov.shape == (st.spec.n_params,) * 2
    assert np.isfinite(st.figures_mm["max"]) and st.meta["plan_hash"] == "plan-a"


def test_baseline_explicit_or_first_healthy(tmp_path, run_dirs, index_url):
    a = Archive.open(tmp_path / "arch", url=index_url)
    for d in run_dirs[:3]:
        a.add_run("ur5-a", d)
    assert a.baseline("ur5-a").run_id == "r0"
    a.set_healthy("ur5-a", "r0", False)
    assert a.baseline("ur5-a").run_id == "r1"
    a.set_baseline("ur5-a", "r2")
    assert a.baseline("ur5-a").run_id == "r2"
    assert [r.baseline for r in a.runs("ur5-a")] == [False, False, True]
    assert a.fleet()[0][2] == "r2"
    a.set_baseline("ur5-a", None)
    assert a.baseline("ur5-a").run_id == "r1"
    assert a.fleet()[0][2] == "r1"  # first healthy, r0 is not
    with pytest.raises(InputError, match="not in the archive"):
        a.set_baseline("ur5-a", "nope")


@pytest.mark.parametrize(
    "bad", ["../x", "..", "a/b", "/etc", "", ".hidden", "a..b", "x" * 101, "a b"]
)
def test_names_cannot_escape_the_archive(tmp_path, run_dirs, bad):
    a = Archive.open(tmp_path / "arch")
    with pytest.raises(InputError):
        a.add_run(bad, run_dirs[0])
    with pytest.raises(InputError):
        a.add_run("ok", run_dirs[0], run_id=bad)
    with pytest.raises(InputError):
        safe_name(bad, "robot")
    assert not any((tmp_path).glob("x*")) and not (tmp_path / "b").exists()


def test_the_archive_names_the_trends_figures():
    from quickhealth.identify import trend
    from quickhealth.station import archive

    assert archive.FIGURES == trend.FIGURES


def test_archive_location_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("QUICKHEALTH_ARCHIVE", str(tmp_path / "env-arch"))
    assert default_root() == tmp_path / "env-arch"
    a = Archive.open()
    assert a.root == (tmp_path / "env-arch").resolve() and (a.root / "index.sqlite").is_file()


def test_sqlalchemy_url_selects_the_index(tmp_path, run_dirs):
    url = f"sqlite:///{tmp_path / 'shared-index.db'}"
    a = Archive.open(tmp_path / "arch", url=url)
    a.add_run("ur5-a", run_dirs[0])
    b = Archive.open(tmp_path / "arch", url=url)  # a second station on the same index
    assert [r.run_id for r in b.runs("ur5-a")] == ["r0"]
    assert not (tmp_path / "arch" / "index.sqlite").exists()


def test_duplicate_and_bad_inputs(tmp_path, run_dirs, index_url):
    a = Archive.open(tmp_path / "arch", url=index_url)
    a.add_run("ur5-a", run_dirs[0])
    with pytest.raises(InputError, match="already archived"):
        a.add_run("ur5-a", run_dirs[0])
    with pytest.raises(InputError, match="no report.json"):
        a.add_run("ur5-a", tmp_path)
    with pytest.raises(InputError, match="has no runs"):
        a.runs("unknown")
    with pytest.raises(InputError, match="ISO 8601"):
        a.add_run("ur5-a", run_dirs[1], time_utc="yesterday")
    # replacing a run swaps its folder and row in one go
    rec = a.add_run("ur5-a", run_dirs[2], run_id="r0", replace_existing=True)
    assert [r.run_id for r in a.runs("ur5-a")] == ["r0"] and rec.time_utc.startswith("2026-03")
    assert json.loads((a.folder(rec) / "run.json").read_text())["time_utc"].startswith("2026-03")
    # a folder without a row is replaced by the next add only when it carries this index's
    # mark (a writer of this index killed before its commit); one of unknown origin is kept
    ghost = a.root / "robots" / "ur5-a" / "ghost"
    ghost.mkdir()
    (ghost / "half.png").write_bytes(b"x")
    assert a.orphans() == [ghost]
    with pytest.raises(InputError, match=r"ghost: holds a folder this index did not put there"):
        a.add_run("ur5-a", run_dirs[1], run_id="ghost")
    assert (ghost / "half.png").read_bytes() == b"x" and a.orphans() == [ghost]
    (ghost / MARKER).write_text(mark(a.index_id, "ur5-a", "ghost"))
    a.add_run("ur5-a", run_dirs[1], run_id="ghost")
    assert not (ghost / "half.png").exists() and not a.orphans()
    assert not list((a.root / "robots" / "ur5-a").glob(".incoming-*"))
    # a run folder that is the archive's own registers again in place (refit): row updated
    own = a.folder(a.get("ur5-a", "ghost"))
    a.add_run("ur5-a", own, run_id="ghost", healthy=False)
    assert a.get("ur5-a", "ghost").healthy is False and (own / "report.json").is_file()
    # issue 32: names unique ignoring case, in one archive and one index (SQLite, PostgreSQL)
    with pytest.raises(InputError, match=r"robot 'UR5-A': the archive has robot 'ur5-a'"):
        a.add_run("UR5-A", run_dirs[1], run_id="r9")
    with pytest.raises(InputError, match=r"run id 'GHOST': robot ur5-a has run 'ghost'"):
        a.add_run("ur5-a", run_dirs[1], run_id="GHOST")
    assert a.robots() == ["ur5-a"] and not (a.root / "robots" / "UR5-A").exists()
    assert sorted(r.run_id for r in a.runs("ur5-a")) == ["ghost", "r0"]


def test_the_verdict_comes_from_the_reports_run_object(tmp_path, run_dirs, index_url):
    # the TUI writes its verdict as run.healthy (report.json has no second, top-level copy);
    # reports written before that carried a top-level "healthy": both are read
    import shutil

    a = Archive.open(tmp_path / "arch", url=index_url)
    for name, extra in (
        ("tui", {"run": {"run_id": "tui", "healthy": False}}),
        ("old", {"healthy": False}),
    ):
        d = tmp_path / name
        shutil.copytree(run_dirs[0], d)
        rep = json.loads((d / "report.json").read_text())
        (d / "report.json").write_text(json.dumps({**rep, **extra}))
        a.add_run("ur5-a", d, run_id=name)
        assert a.get("ur5-a", name).healthy is False
    a.add_run("ur5-a", run_dirs[1], run_id="plain")
    assert a.get("ur5-a", "plain").healthy is None  # unknown: counts as healthy for a baseline


def _trend(capsys, *argv):
    rc = main(["trend", *argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_trend_command_flags_the_degraded_joint_not_the_healthy_repeat(
    tmp_path, run_dirs, capsys, index_url
):
    arch = str(tmp_path / "arch")
    db = ["--db", index_url] if index_url else []
    for d in run_dirs[:2]:
        assert main(["archive", "add", str(d), "--robot", "ur5-a", "--archive", arch, *db]) == 0
    rc, out, _ = _trend(capsys, "ur5-a", "--archive", arch, *db)
    assert rc == 0, out
    # the words first: the latest run's verdict, as its report and the TUI say it
    lines = out[out.index("ur5-a: latest run r1 (") :].splitlines()
    assert lines[1] == "HEALTHY: no spec set and unchanged since the baseline run r0"
    assert "no accuracy spec set (spec_mm in the cell or robot file)" in out
    main(["archive", "add", str(run_dirs[3]), "--robot", "ur5-a", "--archive", arch, *db])
    capsys.readouterr()
    rc, out, _ = _trend(capsys, "ur5-a", "--archive", arch, *db, "--json", str(tmp_path / "t.json"))
    assert rc == 1
    tail = out[out.index("ur5-a: latest run r3 (") :].splitlines()
    # j2.ex.c0 turns joint 3's axis about x (the link between them twisted): named as that
    # fault in its own unit, and nothing else blamed
    assert tail[1].startswith("FLAGGED: the robot changed since its baseline: joint 3 tilt about x")
    assert "changed by +0.5" in tail[1], out
    # nothing else blamed: the one line below is the same change with its statistics
    assert [x for x in tail if x.startswith("  - ")] == [
        next(x for x in tail if x.startswith("  - in full: joint 3 tilt about x changed by"))
    ], out
    assert "r1                       2026-" in out and "healthy\n" in out  # earlier: as then
    doc = json.loads((tmp_path / "t.json").read_text())
    assert doc["flagged"] and doc["baseline"] == "r0"
    (ch,) = doc["changes"]
    assert ch["fault"] == "j3.tilt_x" and ch["size_unit"] == "mrad"
    assert abs(ch["size"] - 0.5) < 2 * ch["sigma"] and ch["sigma"] < 0.05
    # only the threshold counts: the max error is well below 5 mm
    rc, _, _ = _trend(
        capsys, "ur5-a", "--archive", arch, *db, "--fail-on", "threshold", "--threshold-mm", "5"
    )
    assert rc == 0
    rc, out, _ = _trend(
        capsys, "ur5-a", "--archive", arch, *db, "--fail-on", "threshold", "--threshold-mm", "0.1"
    )
    assert rc == 1 and "above the spec of 0.1 mm (max TCP error, --threshold-mm)" in out


def test_trend_warns_when_runs_are_not_comparable(tmp_path, run_dirs, capsys):
    arch = str(tmp_path / "arch")
    main(["archive", "add", str(run_dirs[0]), "--robot", "r", "--archive", arch])
    main(
        [
            "archive",
            "add",
            str(run_dirs[1]),
            "--robot",
            "r",
            "--archive",
            arch,
            "--plan-hash",
            "other",
            "--calibration-id",
            "cal-2",
        ]
    )
    capsys.readouterr()
    rc, out, _ = _trend(capsys, "r", "--archive", arch)
    assert "warning: run r1: plan hash other differs from the baseline's plan-a" in out
    assert "calibration id cal-2 differs" in out


def test_cli_errors_are_one_line_with_status_2(tmp_path, run_dirs, capsys):
    arch = str(tmp_path / "arch")
    assert main(["archive", "add", str(run_dirs[0]), "--robot", "../evil", "--archive", arch]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "robot '../evil' is not allowed" in err[0]
    assert not (tmp_path / "evil").exists() and not (tmp_path / "arch").exists()
    assert main(["trend", "nobody", "--archive", arch]) == 2  # reading never makes an archive
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "arch: no archive there" in err[0]
    assert not (tmp_path / "arch").exists()
    main(["archive", "add", str(run_dirs[0]), "--robot", "ok", "--archive", arch])
    assert main(["trend", "nobody", "--archive", arch]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no runs" in err[0]
    assert main(["trend", "x", "--archive", arch, "--threshold-mm", "-1"]) == 2
    capsys.readouterr()
    main(["archive", "add", str(run_dirs[0]), "--robot", "ok", "--archive", arch])
    assert main(["archive", "baseline", "ok", "--archive", arch]) == 2
    assert main(["archive", "baseline", "ok", "r0", "--archive", arch]) == 0
    assert main(["archive", "list", "--archive", arch]) == 0
    out = capsys.readouterr().out
    assert "ok: 1 runs, baseline r0" in out


def test_runs_fitted_at_other_orders_are_refitted_like_the_baseline(tmp_path, run_dirs, index_url):
    """A term one fit selected and the other did not is not a change: the later run is
    refitted at the baseline's orders (cached next to it) before the curves are compared."""
    other = _runs.make_run(tmp_path / "o2", 5, n_poses=30, order=2, time_utc="2026-05-01T08:00:00Z")
    a = Archive.open(tmp_path / "arch", url=index_url)
    a.add_run("ur5-a", run_dirs[0])
    a.add_run("ur5-a", other, run_id="o2")
    base, rec = a.runs("ur5-a")
    plain = run_state(a, rec)
    like = run_state(a, rec, like=base)
    assert plain.spec.orders.max() == 2 and np.array_equal(
        like.spec.orders, run_state(a, base).spec.orders
    )
    assert (a.folder(rec) / "model.like-r0.json").is_file()
    from quickhealth.station.archive import trend_for

    res = trend_for(a, "ur5-a")
    assert not res.flags(), res.flags()


def test_postgresql_index_shared_by_two_stations(tmp_path, run_dirs, pg_server):
    """Two stations (two Archive objects, two connection pools) on one PostgreSQL index."""
    url = pg_server.new_database()
    a = Archive.open(tmp_path / "shared", url=url)
    b = Archive.open(tmp_path / "shared", url=url)
    a.add_run("ur5-a", run_dirs[0])
    b.add_run("ur5-a", run_dirs[1])
    b.set_baseline("ur5-a", "r1")
    assert [(r.run_id, r.baseline) for r in a.runs("ur5-a")] == [("r0", False), ("r1", True)]
    assert run_state(a, a.runs("ur5-a")[0]).spec is not None
    with pytest.raises(InputError, match="already archived"):
        b.add_run("ur5-a", run_dirs[0], run_id="r0")


def test_old_archives_gain_the_new_index(tmp_path, run_dirs, index_url):
    """An index made before ix_runs_robot_time existed is migrated when opened."""
    import sqlalchemy as sa

    a = Archive.open(tmp_path / "arch", url=index_url)
    a.add_run("ur5-a", run_dirs[0])
    with a.engine.begin() as con:
        con.execute(sa.text("drop index ix_runs_robot_time"))
    assert "ix_runs_robot_time" not in {i["name"] for i in sa.inspect(a.engine).get_indexes("runs")}
    b = Archive.open(tmp_path / "arch", url=index_url)
    assert "ix_runs_robot_time" in {i["name"] for i in sa.inspect(b.engine).get_indexes("runs")}
    assert [r.run_id for r in b.runs("ur5-a")] == ["r0"]


def test_an_index_server_that_stops_answering_is_one_line_not_a_hang(tmp_path, run_dirs, pg_server):
    """A server that stops answering in the middle of a session (the server and the backends
    serving the archive frozen with SIGSTOP: a hung host, a dead link) is cut off by the
    client's watchdog after three time-outs, and the reconnection by the connect time-out:
    HardwareError (exit 3) after seconds, instead of a command that hangs forever."""
    import os
    import signal
    import time

    import sqlalchemy as sa

    from quickhealth.identify.errors import HardwareError

    url = pg_server.new_database()
    Archive.open(tmp_path / "arch", url=url).add_run("ur5-a", run_dirs[0])
    a = Archive.open(tmp_path / "arch", url=url, timeout_s=0.5)
    assert [r.run_id for r in a.runs("ur5-a")] == ["r0"]
    with a.engine.connect() as con:  # the backends serving this archive's pooled connections
        q = "select pid from pg_stat_activity where datname = current_database()"
        backends = [int(r[0]) for r in con.execute(sa.text(q))]
    backends.append(int((pg_server.base / "data" / "postmaster.pid").read_text().split()[0]))
    for pid in backends:
        os.kill(pid, signal.SIGSTOP)  # backends of this test's own server
    try:
        t0 = time.monotonic()
        with pytest.raises(HardwareError, match=r"did not answer within (0\.5|2) s \(reading\)"):
            a.runs("ur5-a")
        dt = time.monotonic() - t0
    finally:
        for pid in backends:
            os.kill(pid, signal.SIGCONT)
    assert dt < 10, dt
    assert [r.run_id for r in a.runs("ur5-a")] == ["r0"]  # a new connection works again


def test_one_version_written_two_ways_is_one_version():
    """Seen by issue 32: the trend warned that "software version 0.1.0 differs from the
    baseline's quickhealth 0.1.0" (the journal's start record names the software as
    provenance writes it, the archive its number)."""
    from quickhealth.identify.trend import comparability_warnings
    from quickhealth.station.archive import RunRecord
    from quickhealth.station.provenance import version_number

    a = RunRecord("r", "run1", "2026-01-01T00:00:00Z", "", software_version="quickhealth 0.1.0")
    b = RunRecord("r", "run2", "2026-01-02T00:00:00Z", "", software_version="0.1.0")
    c = RunRecord("r", "run3", "2026-01-03T00:00:00Z", "", software_version="0.2.0")
    assert a.meta["software_version"] == b.meta["software_version"] == "0.1.0"
    assert version_number(" quickhealth  0.1.0 ") == "0.1.0" and version_number("") == ""

    class Run:  # what comparability_warnings reads of a run
        def __init__(self, rec):
            self.run_id, self.meta = rec.run_id, rec.meta

    words = comparability_warnings([Run(a), Run(b), Run(c)], 0, ("software_version",))
    assert len(words) == 1 and "run run3: software version 0.2.0 differs" in words[0], words
