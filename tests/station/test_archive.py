"""The run archive: folders plus index, many robots, baselines, names that cannot escape."""

import importlib.util
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.archive import Archive, default_root, safe_name

_spec = importlib.util.spec_from_file_location("_runs", Path(__file__).with_name("_runs.py"))
_runs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_runs)


@pytest.fixture(scope="module")
def run_dirs(tmp_path_factory):
    base = tmp_path_factory.mktemp("runs")
    return [
        _runs.make_run(base / f"r{i}", i, n_poses=30, time_utc=f"2026-0{i + 1}-01T08:00:00Z")
        for i in range(3)
    ]


def test_runs_of_many_robots_with_metadata(tmp_path, run_dirs):
    a = Archive.open(tmp_path / "arch")
    for d in run_dirs:
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
    # the index is a plain SQLite file other tools can read
    con = sqlite3.connect(tmp_path / "arch" / "index.sqlite")
    assert con.execute("select count(*) from runs").fetchone()[0] == 4
    # the trend's view of a run: figures, model with covariance, metadata
    st = a.run_state(recs[1])
    assert st.spec is not None and st.cov.shape == (st.spec.n_params,) * 2
    assert np.isfinite(st.figures_mm["max"]) and st.meta["plan_hash"] == "plan-a"


def test_baseline_explicit_or_first_healthy(tmp_path, run_dirs):
    a = Archive.open(tmp_path / "arch")
    for d in run_dirs:
        a.add_run("ur5-a", d)
    assert a.baseline("ur5-a").run_id == "r0"
    a.set_healthy("ur5-a", "r0", False)
    assert a.baseline("ur5-a").run_id == "r1"
    a.set_baseline("ur5-a", "r2")
    assert a.baseline("ur5-a").run_id == "r2"
    assert [r.baseline for r in a.runs("ur5-a")] == [False, False, True]
    a.set_baseline("ur5-a", None)
    assert a.baseline("ur5-a").run_id == "r1"
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


def test_duplicate_and_bad_inputs(tmp_path, run_dirs):
    a = Archive.open(tmp_path / "arch")
    a.add_run("ur5-a", run_dirs[0])
    with pytest.raises(InputError, match="already archived"):
        a.add_run("ur5-a", run_dirs[0])
    with pytest.raises(InputError, match="no report.json"):
        a.add_run("ur5-a", tmp_path)
    with pytest.raises(InputError, match="has no runs"):
        a.runs("unknown")
    with pytest.raises(InputError, match="ISO 8601"):
        a.add_run("ur5-a", run_dirs[1], time_utc="yesterday")
