"""The run archive: one folder per run plus an index, for many robots over months.

Layout (``ROOT`` from ``--archive DIR``, else ``$QUICKHEALTH_ARCHIVE``, else
``~/quickhealth-archive``)::

    ROOT/index.sqlite                      the index (or a PostgreSQL database, see below)
    ROOT/robots/<robot>/<run_id>/          a copy of the run folder: measurements.csv,
                                           model.json, report.json, plan.json, images …

The index holds one row per run (time, plan hash, cell, calibration id, software version,
the main figures, healthy or not) and one per robot (its explicit baseline, if set).  The
baseline of a robot is the run set with :meth:`Archive.set_baseline`, else its first healthy
run.  Robot names and run ids are plain names (letters, digits, ``._-``, no ``..``): they can
never point outside ``ROOT``.

A fleet can share one index: pass an SQLAlchemy URL (``postgresql+psycopg://user@host/db``)
as ``url``; the run folders then live under ``ROOT`` on a shared file system.  SQLite is the
default (``sqlite:///ROOT/index.sqlite``).

SYNOPSIS::

    arch = Archive.open("/data/qh-archive")
    rec = arch.add_run("ur5-cell3", "runs/2026-11-22", run_id="2026-11-22")
    arch.set_baseline("ur5-cell3", rec.run_id)
    states = [arch.run_state(r) for r in arch.runs("ur5-cell3")]
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import socket
import tempfile
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..identify.errormodel import ErrorModelSpec
from ..identify.errors import InputError
from ..identify.fit import fit_model
from . import formats
from .formats import load_json_limited
from .fsio import copy_plain_tree, make_dirs, pid_alive, plain_tree, write_atomic, write_error
from .indexdb import IndexDB
from .provenance import software_version
from .reporting.verdict import healthy_of

if TYPE_CHECKING:
    from ..identify.trend import RunState, TrendResult

ENV_VAR = "QUICKHEALTH_ARCHIVE"
#: the main figures, as ``identify.trend.FIGURES`` (a test checks): importing the trend costs
#: scipy.stats, about 2 s, which listing or adding a run does not need
FIGURES: tuple[str, ...] = ("mean", "std", "max")
INDEX_FILE = "index.sqlite"
#: the mark an archived run folder carries: the identity of the index that put it there
MARKER = ".quickhealth-archive.json"
META_KEYS: tuple[str, ...] = ("plan_hash", "cell", "calibration_id", "software_version")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


class NoArchive(InputError):
    """No archive at the place named (nothing archived there yet): a reader is refused."""


def safe_name(name: str, what: str) -> str:
    """Check that a robot name or run id is a plain name that stays inside the archive.

    Raises
    ------
    InputError
        For empty names, path separators, ``..``, or characters outside ``[A-Za-z0-9._-]``.
    """
    if not isinstance(name, str) or not _NAME.match(name) or ".." in name:
        raise InputError(
            f"{what} {name!r} is not allowed: use letters, digits, '.', '_' and '-' "
            "(at most 100, starting with a letter or digit, no '..')"
        )
    return name


def default_root() -> Path:
    """``$QUICKHEALTH_ARCHIVE`` if set, else ``~/quickhealth-archive``."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path.home() / "quickhealth-archive"


@dataclass(frozen=True)
class RunRecord:
    """One archived run as the index holds it (figures in mm, time in UTC)."""

    robot: str
    run_id: str
    time_utc: str  # ISO 8601
    path: str  # relative to the archive root
    plan_hash: str = ""
    cell: str = ""
    calibration_id: str = ""
    software_version: str = ""
    mean_mm: float = math.nan
    std_mm: float = math.nan
    max_mm: float = math.nan
    healthy: bool | None = None
    baseline: bool = False

    @property
    def t_s(self) -> float:
        """Unix time of the run (s)."""
        return _parse_time(self.time_utc).timestamp()

    @property
    def figures_mm(self) -> dict[str, float]:
        """``{"mean": …, "std": …, "max": …}`` (mm)."""
        return {"mean": self.mean_mm, "std": self.std_mm, "max": self.max_mm}

    @property
    def meta(self) -> dict[str, str]:
        """Plan hash, cell, calibration id and software version."""
        return {k: getattr(self, k) for k in META_KEYS}


@dataclass(frozen=True)
class CheckRecord:
    """One archived quick check (``quickhealth check``): not an assessment, so it has no
    figures and never becomes a baseline; the trend lists it apart from the runs."""

    robot: str
    check_id: str
    time_utc: str  # ISO 8601
    path: str  # relative to the archive root
    baseline_run_id: str
    verdict: str  # "unchanged" | "changed"
    decided: bool
    poses: int
    robot_time_s: float
    full_loop_robot_time_s: float
    changes: str  # the named changes in words ("" when none)
    plan_hash: str = ""
    root: str = ""  # the archive root (not stored)

    @property
    def t_s(self) -> float:
        """Unix time of the check (s)."""
        return _parse_time(self.time_utc).timestamp()


def _parse_time(s: str) -> datetime:
    try:
        t = datetime.fromisoformat(str(s).replace("Z", "+00:00"))
        t = (t if t.tzinfo else t.replace(tzinfo=UTC)).astimezone(UTC)
        t.timestamp()
    except (ValueError, OverflowError, OSError):
        raise InputError(
            f"time {str(s)[:40]!r} is not an ISO 8601 time of years 1..9999 "
            "(e.g. 2026-11-22T10:30:00Z)"
        ) from None
    return t


def _iso(t: datetime) -> str:
    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


# ------------------------------------------------------------------ reading a run folder


def _read_json(path: Path) -> dict[str, Any]:

    doc = load_json_limited(path, "json")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object")
    return doc


def _csv_meta(path: Path) -> dict[str, str]:
    """``# key: value`` comment lines at the top of a CSV v1 file."""
    out: dict[str, str] = {}
    with path.open() as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            key, sep, value = line[1:].partition(":")
            if sep:
                out[key.strip()] = value.strip()
    return out


def run_metadata(run_dir: Path) -> dict[str, str]:
    """Metadata of a run folder: plan hash, cell, calibration id, software version, time, robot.

    Looked up, later sources winning: ``measurements.csv`` comments, ``run.json``,
    ``report.json`` (top level or its ``meta``/``run`` object), and the plan's ``plan_hash``;
    the software from the journal's start record, the calibration from the instrument name.
    """
    meta: dict[str, str] = {}
    meas = run_dir / "measurements.csv"
    if meas.is_file():
        meta.update(_csv_meta(meas))
    for name in ("run.json", "report.json"):
        p = run_dir / name
        if not p.is_file():
            continue
        doc = _read_json(p)
        for src in (doc, doc.get("meta", {}), doc.get("run", {})):
            if isinstance(src, dict):
                meta.update({k: str(v) for k, v in src.items() if isinstance(v, str | int)})
    plan = run_dir / "plan.json"
    if "plan_hash" not in meta and plan.is_file():
        doc = _read_json(plan)
        if isinstance(doc.get("plan_hash"), str):
            meta["plan_hash"] = doc["plan_hash"]
    journal = run_dir / "journal.jsonl"
    if journal.is_file() and "software_version" not in meta:
        with journal.open() as fh:  # the station's start record names the software
            first = fh.readline()
        try:
            start = json.loads(first)
        except json.JSONDecodeError:
            start = {}
        rec = start.get("rec", start) if isinstance(start, dict) else {}
        if isinstance(rec, dict) and isinstance(rec.get("software"), str):
            meta["software_version"] = rec["software"]
    aliases = (
        ("calibration", "calibration_id"),
        ("instrument", "calibration_id"),  # the station writes "stereo camera CAL.json"
        ("version", "software_version"),
        ("software", "software_version"),
    )
    for alias, key in aliases:
        if key not in meta and meta.get(alias):
            meta[key] = meta[alias]
    return meta


def report_figures(report: Mapping[str, Any]) -> tuple[dict[str, float], dict[str, float]]:
    """Main figures (mm) and their standard uncertainties (mm) from a report.json object.

    Accepts ``{"workspace": {"mean_mm": …, "std_mm": …, "max_mm": …, "mean_sigma_mm": …}}``
    or the same keys with a ``workspace_`` prefix at the top level.
    """
    ws = report.get("workspace")
    src: Mapping[str, Any] = ws if isinstance(ws, Mapping) else {}
    figs, sig = {}, {}
    for f in FIGURES:
        for key, dst in ((f"{f}_mm", figs), (f"{f}_sigma_mm", sig)):
            v = src.get(key, report.get(f"workspace_{key}"))
            if isinstance(v, int | float) and math.isfinite(v):
                dst[f] = float(v)
    return figs, sig


def model_arrays(
    doc: Mapping[str, Any], name: str = "model.json"
) -> tuple[ErrorModelSpec, np.ndarray, np.ndarray | None]:
    """Error-model spec, Chebyshev coefficients (SI) and their covariance from a model.json object.

    The covariance is the Chebyshev block of the fit's covariance (effect parameters left out).
    """

    fitted = formats.model_from_json(dict(doc), name)
    n = fitted.spec.n_params
    return fitted.spec, np.asarray(fitted.coeffs, float), np.asarray(fitted.cov, float)[:n, :n]


# ------------------------------------------------------------------ checking a run to add


@dataclass(frozen=True)
class PreparedRun:
    """A run folder checked for the archive (:func:`prepare_run`): nothing written yet."""

    src: Path  # resolved
    robot: str
    run_id: str
    record: RunRecord  # its row (``path`` is set when it is placed)
    n_files: int
    n_bytes: int


def prepare_run(
    robot: str,
    run_dir: str | Path,
    *,
    run_id: str | None = None,
    time_utc: str | None = None,
    meta: Mapping[str, str] | None = None,
    healthy: bool | None = None,
) -> PreparedRun:
    """Check a run folder for :meth:`Archive.add_prepared` before any archive exists: a
    refused run creates nothing (no archive folder, no index).

    Parameters
    ----------
    robot : str
    run_dir : path
        A run folder (at least ``report.json``; ``model.json`` for the curve comparison),
        holding regular files and folders only (a symbolic link is refused, never followed).
    run_id : str, optional
        Default: the folder's ``run_id`` metadata, else the folder name.
    time_utc : str, optional
        ISO 8601; default the folder's ``time_utc``/``started_utc`` metadata, else the
        modification time of its report.json.
    meta : mapping, optional
        Overrides plan_hash, cell, calibration_id, software_version (at most 200 characters).
    healthy : bool, optional
        Default: the verdict the report carries (:func:`~.verdict.healthy_of`: its
        ``verdict`` section, else ``run.healthy``, else an older top-level ``healthy``) if
        present, else unknown (counts as healthy for choosing the first baseline).

    Raises
    ------
    InputError
        One line: a name that is not plain, a time that is not ISO 8601 (or not a year
        1..9999), a missing or incomplete report.json or model.json, a link or a special
        file in the folder.
    """

    robot = safe_name(robot, "robot")
    if run_id is not None:
        safe_name(run_id, "run id")
    for k, v in (meta or {}).items():
        if len(str(v)) > 200 or any(c < " " for c in str(v)):
            raise InputError(
                f"--{k.replace('_', '-')}: at most 200 characters without control characters"
            )
    if time_utc is not None:
        _parse_time(time_utc)
    given = Path(run_dir)
    if not given.is_dir():
        raise InputError(f"{given}: not a run folder")
    src = given.resolve()
    report_p = src / "report.json"
    if not report_p.is_file():
        raise InputError(f"{given}: no report.json (fit the run first: quickhealth identify fit)")
    report = _read_json(report_p)
    # a run the trend and reprocess can use: the fit's figures and a valid model
    formats.check_report(report, str(report_p), complete=False)
    model_p = src / "model.json"
    if not model_p.is_file():
        raise InputError(f"{given}: no model.json (fit the run first: quickhealth identify fit)")
    formats.read_model(model_p)
    _, files, n_bytes = plain_tree(given)  # links and special files refused up front
    found = run_metadata(src)
    for k, v in found.items():
        if k in META_KEYS and len(str(v)) > 200:
            raise InputError(f"{given}: its {k} is longer than 200 characters")
    found.update(meta or {})
    rid = run_id if run_id is not None else (found.get("run_id") or src.name)
    rid = safe_name(rid, "run id")
    when = time_utc or found.get("time_utc") or found.get("started_utc")
    if when:
        t_iso = _iso(_parse_time(when))
    else:
        t_iso = _iso(datetime.fromtimestamp(report_p.stat().st_mtime, UTC))
    if not found.get("software_version"):
        found["software_version"] = _software_version()
    figs, _ = report_figures(report)
    if healthy is None:
        healthy = healthy_of(report)
    rec = RunRecord(
        robot=robot,
        run_id=rid,
        time_utc=t_iso,
        path="",
        **{k: str(found.get(k, "")) for k in META_KEYS},
        mean_mm=figs.get("mean", math.nan),
        std_mm=figs.get("std", math.nan),
        max_mm=figs.get("max", math.nan),
        healthy=healthy,
    )
    return PreparedRun(src, robot, rid, rec, len(files), n_bytes)


def marker_owner(folder: Path) -> str | None:
    """The identity of the index that put an archive run folder there (its :data:`MARKER`),
    or None for a folder without a readable mark."""
    m = folder / MARKER
    try:
        if m.is_symlink() or not m.is_file() or m.stat().st_size > 4096:
            return None
        doc = json.loads(m.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    v = doc.get("index_id") if isinstance(doc, dict) else None
    return v if isinstance(v, str) and v else None


# ---------------------------------------------------------------------------- the archive


class Archive:
    """Run folders under ``root`` plus an index (SQLite by default, any SQLAlchemy URL).

    Safe for many stations at once (processes on one machine or a fleet on one PostgreSQL
    index): a run is copied to a hidden staging folder first, and its folder is renamed into
    place inside the index transaction that inserts its row, so a reader never sees a row
    without its complete folder, and a writer killed at any moment leaves the run either fully
    archived or not in the index at all (a leftover folder without a row, marked with this
    index's identity, is replaced by the next ``add_run`` of that run).  A folder this index
    did not put there is never replaced or deleted, so stations that share the archive
    folder but not the index cannot destroy each other's runs.  A read (``runs``) is one
    snapshot of the index.  Every index operation is bounded in time and fails with one
    line (:mod:`.indexdb`).
    """

    def __init__(
        self,
        root: Path,
        url: str | None = None,
        *,
        create: bool = True,
        timeout_s: float | None = None,
    ) -> None:
        # SQLAlchemy (~0.3 s) only once an archive is opened, not for importing this module
        import sqlalchemy as sa

        given = Path(root)
        if given.exists() and not given.is_dir():
            raise InputError(
                f"{given}: names a file; the archive is a folder (of index.sqlite and robots/)"
            )
        self.root = given.resolve()
        self.url = url or f"sqlite:///{self.root / INDEX_FILE}"
        self._db = IndexDB(self.url, timeout_s)  # a bad URL is refused before anything exists
        self._sa = sa
        self.engine = self._db.engine
        self._pg = self._db.pg
        self._index_id: str | None = None
        # writers: BEGIN IMMEDIATE on SQLite (no lock upgrade deadlocks between stations);
        # readers: one snapshot per read (REPEATABLE READ on PostgreSQL, BEGIN on SQLite)
        self._writer = self.engine.execution_options(qh_write=True)
        self._reader = (
            self.engine.execution_options(isolation_level="REPEATABLE READ")
            if self._pg
            else self.engine
        )
        md = sa.MetaData()
        self.t_runs = sa.Table(
            "runs",
            md,
            sa.Column("robot", sa.String(100), primary_key=True),
            sa.Column("run_id", sa.String(100), primary_key=True),
            sa.Column("time_utc", sa.String(32), nullable=False),
            sa.Column("path", sa.String(300), nullable=False),
            *(sa.Column(k, sa.String(200), nullable=False, default="") for k in META_KEYS),
            sa.Column("mean_mm", sa.Float),
            sa.Column("std_mm", sa.Float),
            sa.Column("max_mm", sa.Float),
            sa.Column("healthy", sa.Boolean, nullable=True),
            # a robot's runs in time order straight from the index (trend, latest run)
            sa.Index("ix_runs_robot_time", "robot", "time_utc", "run_id"),
        )
        self.t_robots = sa.Table(
            "robots",
            md,
            sa.Column("robot", sa.String(100), primary_key=True),
            sa.Column("baseline_run_id", sa.String(100), nullable=True),
        )
        # quick checks: a verdict against the baseline, never an assessment (no figures)
        self.t_checks = sa.Table(
            "checks",
            md,
            sa.Column("robot", sa.String(100), primary_key=True),
            sa.Column("check_id", sa.String(100), primary_key=True),
            sa.Column("time_utc", sa.String(32), nullable=False),
            sa.Column("path", sa.String(300), nullable=False),
            sa.Column("baseline_run_id", sa.String(100), nullable=False, default=""),
            sa.Column("verdict", sa.String(20), nullable=False),
            sa.Column("decided", sa.Boolean, nullable=False),
            sa.Column("poses", sa.Integer, nullable=False),
            sa.Column("robot_time_s", sa.Float),
            sa.Column("full_loop_robot_time_s", sa.Float),
            sa.Column("changes", sa.String(1000), nullable=False, default=""),
            sa.Column("plan_hash", sa.String(200), nullable=False, default=""),
        )
        # the index's identity: which run folders this index put into the archive folder
        self.t_meta = sa.Table(
            "qh_meta",
            md,
            sa.Column("key", sa.String(50), primary_key=True),
            sa.Column("value", sa.String(200), nullable=False),
        )
        self._md = md
        index_file = self._db.sqlite_path
        if not create:
            if not self.root.is_dir() and url is None:
                raise NoArchive(f"{self.root}: no archive there (quickhealth archive add makes it)")
            if index_file is not None and not index_file.exists():
                raise NoArchive(
                    f"{index_file}: no archive index there (quickhealth archive add makes it)"
                )
        made: list[Path] = []  # what this call created, removed again if it fails
        self._made = made  # ... or if the command that opened it is refused (undo_creation)
        try:
            if url is None and not self.root.is_dir():
                made += [p for p in (self.root, *self.root.parents) if not p.exists()][::-1]
                make_dirs(self.root)
            if index_file is not None and not index_file.exists():
                made.append(index_file)
            self._open_schema(create)
            if not self.root.is_dir():  # a shared index: the run folders' root
                if not create:
                    return
                made += [p for p in (self.root, *self.root.parents) if not p.exists()][::-1]
                make_dirs(self.root)
        except BaseException:
            self.engine.dispose()
            if index_file is not None and index_file in made:
                made.append(Path(f"{index_file}-journal"))
            for p in reversed(made):
                try:
                    p.unlink() if p.is_file() else p.rmdir()
                except OSError:
                    pass
            raise

    def undo_creation(self) -> None:
        """Remove what opening this archive created (its folder, its SQLite index) when it
        still holds no run: a refused ``archive add`` leaves nothing behind."""
        if not self._made:
            return
        try:
            empty = not self.robots() and not (
                self.root in self._made and any((self.root / "robots").glob("*/*"))
            )
        except Exception:  # noqa: BLE001 - an index that cannot be read is not ours to judge
            return
        if not empty:
            return
        self.engine.dispose()
        index_file = self._db.sqlite_path
        if index_file is not None and index_file in self._made:
            self._made.append(Path(f"{index_file}-journal"))
        robots = self.root / "robots"
        for d in sorted(robots.glob("*"), reverse=True) if self.root in self._made else []:
            if d.is_dir() and not d.is_symlink():
                try:
                    d.rmdir()
                except OSError:
                    pass
        if self.root in self._made:
            self._made.append(robots)
        for p in reversed(self._made):
            try:
                p.unlink() if p.is_file() else p.rmdir()
            except OSError:
                pass
        self._made = []

    def _open_schema(self, create: bool) -> None:
        """Check the index's tables; create them (or add what newer versions added)."""
        sa = self._sa
        state = self._schema_state()
        if state == "current":
            return
        if state == "empty" and not create:
            raise NoArchive(
                f"{self._db.name}: the index holds no archive yet (quickhealth archive add "
                "makes it)"
            )
        with self._write() as con:  # one station creates or migrates the schema at a time
            if self._pg:
                con.execute(sa.text("select pg_advisory_xact_lock(7243411)"))
            self._md.create_all(con)
            for ix in self.t_runs.indexes:  # indexes added since the archive was made
                ix.create(con, checkfirst=True)
            have = con.execute(
                sa.select(self.t_meta.c.value).where(self.t_meta.c.key == "index_id")
            ).first()
            if have is None:
                con.execute(sa.insert(self.t_meta).values(key="index_id", value=uuid.uuid4().hex))

    def _schema_state(self) -> str:
        """``current`` (every table, column and index there), ``empty`` (no table yet) or
        ``old`` (made by an earlier version: tables or indexes to add).  A read: works on a
        read-only archive too.  A ``runs`` or ``robots`` table without the columns this
        version reads is a damaged or foreign index: refused (one line, exit 2)."""
        with self._read() as con:
            ins = self._sa.inspect(con)
            names = set(ins.get_table_names())
            for t in (self.t_runs, self.t_robots, self.t_meta, self.t_checks):
                if t.name not in names:
                    continue
                cols = {c["name"] for c in ins.get_columns(t.name)}
                missing = [c.name for c in t.columns if c.name not in cols]
                if missing:
                    raise InputError(
                        f"{self._db.name}: not a quickhealth archive index (its table "
                        f"{t.name!r} lacks {', '.join(missing)}); restore the index from a backup"
                    )
            if not names & {"runs", "robots"}:
                return "empty"
            if not {"runs", "robots", "qh_meta", "checks"} <= names:
                return "old"
            have = {ix["name"] for ix in ins.get_indexes("runs")}
            if not all(ix.name in have for ix in self.t_runs.indexes):
                return "old"
            got = con.execute(
                self._sa.select(self.t_meta.c.value).where(self.t_meta.c.key == "index_id")
            ).first()
        return "current" if got is not None else "old"

    @property
    def index_id(self) -> str:
        """This index's identity (a random id made with it): the mark of the run folders it
        put into the archive folder, so that stations sharing the folder but not the index
        never replace each other's runs."""
        if self._index_id is None:
            with self._read() as con:
                v = con.execute(
                    self._sa.select(self.t_meta.c.value).where(self.t_meta.c.key == "index_id")
                ).scalar()
            if not v:
                raise InputError(f"{self._db.name}: the index has no identity; open it again")
            self._index_id = str(v)
        return self._index_id

    @contextmanager
    def _write(self) -> Iterator[Any]:
        with self._db.guard("writing"), self._writer.begin() as con:
            yield con

    @contextmanager
    def _read(self) -> Iterator[Any]:
        with self._db.guard("reading"), self._reader.connect() as con, con.begin():
            yield con

    @classmethod
    def open(
        cls,
        root: str | Path | None = None,
        url: str | None = None,
        *,
        create: bool = True,
        timeout_s: float | None = None,
    ) -> Archive:
        """The archive at ``root`` (default :func:`default_root`); created if missing unless
        ``create`` is False (then a missing archive is refused with one line, exit 2).
        ``timeout_s`` bounds every index operation (:mod:`.indexdb`; default 10 s)."""
        return cls(Path(root) if root else default_root(), url, create=create, timeout_s=timeout_s)

    # ---- paths
    def run_path(self, robot: str, run_id: str) -> Path:
        """Folder of a run; never outside the archive root."""
        return self._inside("robots", "run", robot, run_id)

    def _inside(self, folder: str, kind: str, robot: str, name: str) -> Path:
        """``root/folder/robot/name`` (each part checked by :func:`safe_name`), refused in one
        line should it resolve outside the archive root."""
        p = (
            self.root / folder / safe_name(robot, "robot") / safe_name(name, f"{kind} id")
        ).resolve()
        if not p.is_relative_to(self.root):
            raise InputError(f"{kind} {robot}/{name} would lie outside the archive {self.root}")
        return p

    # ---- writing
    def add_run(
        self,
        robot: str,
        run_dir: str | Path,
        *,
        run_id: str | None = None,
        time_utc: str | None = None,
        meta: Mapping[str, str] | None = None,
        healthy: bool | None = None,
        replace_existing: bool = False,
    ) -> RunRecord:
        """Copy a run folder into the archive and index it (:func:`prepare_run`, then
        :meth:`add_prepared`; the parameters are :func:`prepare_run`'s)."""
        prep = prepare_run(
            robot, run_dir, run_id=run_id, time_utc=time_utc, meta=meta, healthy=healthy
        )
        return self.add_prepared(prep, replace_existing=replace_existing)

    def add_prepared(self, prep: PreparedRun, *, replace_existing: bool = False) -> RunRecord:
        """Copy a checked run folder into the archive and index it.

        The folder is copied into a hidden staging folder first (regular files and folders
        only: :func:`~quickhealth.station.fsio.copy_plain_tree`), marked with this index's
        identity (:data:`MARKER`), then renamed into place inside the transaction that
        inserts its row.  An archive folder of that run that this index has no row for is
        replaced only when it carries this index's mark (a writer of this index killed
        between the rename and the commit); any other (another index's run, a folder of
        unknown origin) is refused with one line and left as it is.

        Raises
        ------
        InputError
            The run is already archived (unless ``replace_existing``), or its folder in the
            archive belongs to another index.
        """

        src, robot, rid = prep.src, prep.robot, prep.run_id
        dst = self.run_path(robot, rid)
        in_place = dst.exists() and dst.resolve() == src
        rec = replace(prep.record, path=str(dst.relative_to(self.root)))
        row = {k: v for k, v in rec.__dict__.items() if k != "baseline"}
        row = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}
        mark = self._mark(robot, rid)
        if in_place:
            self._refuse_foreign(dst, robot, rid, replacing=True)
            self._index_and_place(row, None, dst, True, True, mark)
            return self.get(robot, rid)

        make_dirs(dst.parent)
        self._sweep_stale_staging(dst.parent)
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".incoming-{rid}-", dir=dst.parent))
        except OSError as exc:
            raise write_error(dst.parent, exc) from None
        try:
            write_atomic(stage / "owner.json", mark)  # first: a killed copy is known as ours
            copy_plain_tree(src, stage / "run")  # the slow part, outside any lock
            write_atomic(stage / "run" / MARKER, mark)
            self._index_and_place(row, stage, dst, replace_existing, False, mark)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        return self.get(robot, rid)

    def _mark(self, robot: str, run_id: str) -> str:
        """The contents of a run folder's :data:`MARKER`: this index and the writer."""

        doc = {
            "index_id": self.index_id,
            "robot": robot,
            "run_id": run_id,
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "time_utc": _iso(datetime.now(UTC)),
        }
        return json.dumps(doc, indent=1) + "\n"

    def _refuse_foreign(self, folder: Path, robot: str, rid: str, *, replacing: bool) -> None:
        """Refuse (one line, exit 2) to replace a folder this index cannot prove is its own:
        one marked by another index, or (``replacing`` False: this index has no row for the
        run) one with no mark of this index at all."""
        owner = marker_owner(folder)
        if owner == self.index_id or (replacing and owner is None):
            return
        whose = (
            f"a run put there by another index ({owner[:12]}…)"
            if owner
            else "a folder this index did not put there"
        )
        raise InputError(
            f"{folder}: holds {whose}; this index ({self._db.name}) has no row for "
            f"{robot}/{rid}: refusing to replace it (stations sharing an archive folder must "
            "share the index, --db); give another --run-id"
        )

    def _sweep_stale_staging(self, folder: Path) -> None:
        """Remove staging folders this index's writers on this machine left when they were
        killed (their process is gone); another index's or a live writer's are left alone."""

        for d in folder.glob(".incoming-*"):
            try:
                doc = json.loads((d / "owner.json").read_text(encoding="utf-8"))
                mine = doc.get("index_id") == self.index_id and doc.get("host") == (
                    socket.gethostname()
                )
                stale = mine and not pid_alive(int(doc["pid"]))
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                continue
            if stale and not d.is_symlink():
                shutil.rmtree(d, ignore_errors=True)

    def _index_and_place(
        self,
        row: dict[str, Any],
        stage: Path | None,
        dst: Path,
        replace_existing: bool,
        in_place: bool,
        mark: str,
    ) -> None:
        """Insert the run's row and rename its staged folder into place, in one transaction."""

        sa = self._sa
        t = self.t_runs
        robot, rid = row["robot"], row["run_id"]
        key = (t.c.robot == robot) & (t.c.run_id == rid)
        moved: list[tuple[Path, Path]] = []  # renames to undo if the transaction fails
        try:
            with self._write() as con:
                existed = con.execute(sa.select(t.c.run_id).where(key)).first() is not None
                if existed:
                    # a run folder that already is the archive's (the TUI fits in place and
                    # registers again after each refit) updates its row
                    if not (replace_existing or in_place):
                        raise InputError(
                            f"run {robot}/{rid} is already archived (use another run id)"
                        )
                    con.execute(sa.delete(t).where(key))
                try:
                    # the row is the run's lock: a second station adding the same run waits
                    # here and then fails on the primary key
                    con.execute(sa.insert(t).values(**row))
                except sa.exc.IntegrityError:
                    raise InputError(
                        f"run {robot}/{rid} is already archived (use another run id)"
                    ) from None
                con.execute(self._insert_robot(robot))
                if in_place:
                    write_atomic(dst / MARKER, mark)
                    return
                assert stage is not None
                if dst.exists() or dst.is_symlink():
                    # the old copy (replace) or a leftover of this index's killed writer;
                    # never a folder another index (or nobody known) put there
                    self._refuse_foreign(dst, robot, rid, replacing=existed)
                    dst.rename(stage / "old")
                    moved.append((stage / "old", dst))
                try:
                    (stage / "run").rename(dst)  # never over a folder: rename(2) refuses
                except OSError as exc:
                    if dst.exists():  # another index's station put it there just now
                        self._refuse_foreign(dst, robot, rid, replacing=False)

                    raise write_error(dst, exc) from None
                moved.append((dst, stage / "run"))
        except BaseException:
            for a, b in reversed(moved):
                if a.exists() and not b.exists():
                    a.rename(b)
            raise

    def _insert_robot(self, robot: str) -> Any:
        """``INSERT robot … ON CONFLICT DO NOTHING`` (two stations may add its first run)."""
        name = self.engine.dialect.name
        if name in ("postgresql", "sqlite"):
            mod = __import__(f"sqlalchemy.dialects.{name}", fromlist=["insert"])
            return (
                mod.insert(self.t_robots)
                .values(robot=robot, baseline_run_id=None)
                .on_conflict_do_nothing(index_elements=["robot"])
            )
        sa = self._sa  # other databases: insert unless present (single-writer use)
        sel = sa.select(sa.literal(robot), sa.null()).where(
            ~sa.exists().where(self.t_robots.c.robot == robot)
        )
        return sa.insert(self.t_robots).from_select(["robot", "baseline_run_id"], sel)

    def update_figures(self, robot: str, run_id: str, figures_mm: Mapping[str, float]) -> None:
        """Replace a run's indexed figures (after reprocessing)."""
        sa = self._sa
        vals = {f"{f}_mm": float(v) for f, v in figures_mm.items() if f in FIGURES}
        with self._write() as con:
            con.execute(
                sa.update(self.t_runs)
                .where((self.t_runs.c.robot == robot) & (self.t_runs.c.run_id == run_id))
                .values(**vals)
            )

    def set_baseline(self, robot: str, run_id: str | None) -> None:
        """Make ``run_id`` the robot's baseline (None: back to the first healthy run)."""
        if run_id is not None:
            self.get(robot, run_id)  # must exist
        sa = self._sa
        with self._write() as con:
            con.execute(
                sa.update(self.t_robots)
                .where(self.t_robots.c.robot == safe_name(robot, "robot"))
                .values(baseline_run_id=run_id)
            )

    def set_healthy(self, robot: str, run_id: str, healthy: bool | None) -> None:
        """Mark a run healthy or not (used to choose the first healthy baseline)."""
        self.get(robot, run_id)
        sa = self._sa
        with self._write() as con:
            con.execute(
                sa.update(self.t_runs)
                .where((self.t_runs.c.robot == robot) & (self.t_runs.c.run_id == run_id))
                .values(healthy=healthy)
            )

    # ---- quick checks
    def check_path(self, robot: str, check_id: str) -> Path:
        """Folder of a quick check; never outside the archive root."""
        return self._inside("checks", "check", robot, check_id)

    def add_check(
        self, robot: str, check_dir: str | Path, *, check_id: str | None = None
    ) -> CheckRecord:
        """Copy a quick check's folder (``quickhealth check``) into the archive and index it
        as a check of ``robot``: listed by :meth:`checks` and the trend, never a run.

        The folder is copied into a staging folder first and renamed into place inside the
        transaction that inserts its row (as :meth:`add_prepared` does for a run); a check
        made in its archive folder (:meth:`check_path`, the TUI's) is indexed in place.

        Raises
        ------
        InputError
            No check.json (or one that is not a check's), a name that is not plain, a check
            id already archived, a link or special file in the folder.
        """
        robot = safe_name(robot, "robot")
        src = Path(check_dir)
        cp = src / "check.json"
        if not cp.is_file():
            raise InputError(f"{src}: no check.json (not a quick check's folder)")
        doc = _read_json(cp)
        if doc.get("schema") != "quickhealth.check/1" or doc.get("verdict") not in (
            "unchanged",
            "changed",
        ):
            raise InputError(f"{cp}: not a quick check's result (schema quickhealth.check/1)")
        plain_tree(src)  # links and special files refused up front
        cid = safe_name(check_id or str(doc.get("run_id") or src.resolve().name), "check id")
        when = str(doc.get("started_utc") or "")
        t_iso = (
            _iso(_parse_time(when))
            if when
            else _iso(datetime.fromtimestamp(cp.stat().st_mtime, UTC))
        )
        words = "; ".join(
            f"{c.get('words', '')} {float(c.get('size', 0.0)):.3g} {c.get('size_unit', '')}"
            for c in doc.get("changes", [])
        )[:1000]
        dst = self.check_path(robot, cid)
        in_place = dst.exists() and src.resolve() == dst  # checked into its archive folder
        row = {
            "robot": robot,
            "check_id": cid,
            "time_utc": t_iso,
            "path": str(dst.relative_to(self.root)),
            "baseline_run_id": str((doc.get("baseline") or {}).get("run_id", ""))[:100],
            "verdict": str(doc["verdict"]),
            "decided": bool(doc.get("decided", False)),
            "poses": int(doc.get("poses", 0)),
            "robot_time_s": _finite_or_none(doc.get("robot_time_s")),
            "full_loop_robot_time_s": _finite_or_none(doc.get("full_loop_robot_time_s")),
            "changes": words,
            "plan_hash": str(doc.get("plan_hash", ""))[:200],
        }
        sa = self._sa
        t = self.t_checks
        if in_place:  # the TUI checks straight into the archive: its row, its mark
            with self._write() as con:
                try:
                    con.execute(sa.insert(t).values(**row))
                except sa.exc.IntegrityError:
                    raise InputError(
                        f"check {robot}/{cid} is already archived (use another check id)"
                    ) from None
                write_atomic(dst / MARKER, self._mark(robot, cid))
            return self._check_record(row)
        make_dirs(dst.parent)
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".incoming-{cid}-", dir=dst.parent))
        except OSError as exc:
            raise write_error(dst.parent, exc) from None
        try:
            copy_plain_tree(src, stage / "check")
            write_atomic(stage / "check" / MARKER, self._mark(robot, cid))
            with self._write() as con:
                try:
                    con.execute(sa.insert(t).values(**row))
                except sa.exc.IntegrityError:
                    raise InputError(
                        f"check {robot}/{cid} is already archived (use another check id)"
                    ) from None
                if dst.exists() or dst.is_symlink():
                    raise InputError(f"{dst}: already exists: refusing to replace it")
                (stage / "check").rename(dst)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        return self._check_record(row)

    def _check_record(self, r: Mapping[str, Any]) -> CheckRecord:
        d = dict(r)
        for k in ("robot_time_s", "full_loop_robot_time_s"):
            d[k] = math.nan if d.get(k) is None else float(d[k])
        return CheckRecord(**d, root=str(self.root))

    def checks(self, robot: str) -> list[CheckRecord]:
        """The robot's quick checks in time order (empty when it has none)."""
        sa = self._sa
        t = self.t_checks
        robot = safe_name(robot, "robot")
        with self._read() as con:
            rows = con.execute(
                sa.select(t).where(t.c.robot == robot).order_by(t.c.time_utc, t.c.check_id)
            ).mappings()
            return [self._check_record(r) for r in rows]

    # ---- reading
    def robots(self) -> list[str]:
        """Every robot in the archive, sorted."""
        sa = self._sa
        with self._read() as con:
            return sorted(r[0] for r in con.execute(sa.select(self.t_robots.c.robot)))

    @staticmethod
    def _record(r: Mapping[str, Any], baseline: bool = False) -> RunRecord:
        d = dict(r)
        for f in FIGURES:
            if d[f"{f}_mm"] is None:
                d[f"{f}_mm"] = math.nan
        return RunRecord(**d, baseline=baseline)

    def runs(self, robot: str) -> list[RunRecord]:
        """The robot's runs in time order, the baseline marked (one snapshot of the index).

        Raises
        ------
        InputError
            Unknown robot.
        """
        sa = self._sa
        t = self.t_runs
        robot = safe_name(robot, "robot")
        with self._read() as con:
            rows = con.execute(
                sa.select(t).where(t.c.robot == robot).order_by(t.c.time_utc, t.c.run_id)
            ).mappings()
            recs = [self._record(r) for r in rows]
            explicit = con.execute(
                sa.select(self.t_robots.c.baseline_run_id).where(self.t_robots.c.robot == robot)
            ).scalar()
        if not recs:
            known = ", ".join(self.robots()) or "none"
            raise InputError(
                f"robot {robot!r} has no runs in the archive {self.root} (robots: {known})"
            )
        b = (
            str(explicit)
            if explicit is not None
            else next((r.run_id for r in recs if r.healthy is not False), None)
        )
        return [replace(r, baseline=r.run_id == b) for r in recs]

    def fleet(self) -> list[tuple[RunRecord, int, str | None]]:
        """Every robot's latest run, its number of runs and its baseline run id, sorted by robot.

        One query whatever the size of the fleet: per robot, the latest and the first healthy
        run are one probe each of the ``(robot, time_utc, run_id)`` index.
        """
        sa = self._sa
        t, rb = self.t_runs, self.t_robots
        r2 = t.alias("r2")  # the inner scans, correlated to the robot only

        def probe(desc: bool, healthy_only: bool) -> Any:
            order = (r2.c.time_utc, r2.c.run_id)
            q = sa.select(r2.c.run_id).where(r2.c.robot == rb.c.robot)
            if healthy_only:
                q = q.where(sa.or_(r2.c.healthy.is_(None), r2.c.healthy))
            order = tuple(c.desc() for c in order) if desc else order
            return q.order_by(*order).limit(1).correlate(rb).scalar_subquery()

        count = sa.select(sa.func.count()).where(r2.c.robot == rb.c.robot).correlate(rb)
        q = (
            sa.select(
                t,
                rb.c.baseline_run_id.label("qh_explicit"),
                probe(False, True).label("qh_first_ok"),
                count.scalar_subquery().label("qh_n"),
            )
            .select_from(rb)  # robots drive: one index probe each, then the run by its key
            .join(t, (t.c.robot == rb.c.robot) & (t.c.run_id == probe(True, False)))
            .order_by(rb.c.robot)
        )
        out = []
        with self._read() as con:
            for r in con.execute(q).mappings():
                d = dict(r)
                explicit, first_ok, n = d.pop("qh_explicit"), d.pop("qh_first_ok"), d.pop("qh_n")
                b = explicit or first_ok
                rec = self._record(d)
                out.append((replace(rec, baseline=rec.run_id == b), int(n), b))
        return out

    def orphans(self) -> list[Path]:
        """Run folders with no row in this index (and staging folders ``.incoming-*``): left
        by a writer killed before its commit, or put there by another index sharing the
        archive folder.  ``add_run`` of that run replaces only those carrying this index's
        mark (:func:`marker_owner`); it refuses the others."""
        sa = self._sa
        with self._read() as con:
            indexed = {
                (r, i) for r, i in con.execute(sa.select(self.t_runs.c.robot, self.t_runs.c.run_id))
            }
        out = []
        base = self.root / "robots"
        for rd in sorted(base.iterdir()) if base.is_dir() else []:
            for d in sorted(rd.iterdir()):
                if d.is_dir() and (rd.name, d.name) not in indexed:
                    out.append(d)
        return out

    def baseline(self, robot: str) -> RunRecord | None:
        """The explicit baseline, else the first healthy run, else None."""
        return next((r for r in self.runs(robot) if r.baseline), None)

    def get(self, robot: str, run_id: str) -> RunRecord:
        """One run's record."""
        for r in self.runs(robot):
            if r.run_id == run_id:
                return r
        raise InputError(f"run {run_id!r} of robot {robot!r} is not in the archive {self.root}")

    def folder(self, rec: RunRecord) -> Path:
        """The run's folder in the archive."""
        return self.run_path(rec.robot, rec.run_id)

    def run_state(
        self, rec: RunRecord, like: RunRecord | None = None, folder: Path | None = None
    ) -> RunState:
        """What the trend needs of a run: figures and their uncertainty, error model, metadata.

        Parameters
        ----------
        rec : RunRecord
        like : RunRecord, optional
            The baseline.  When the run's model has other orders than the baseline's, the run's
            measurements are fitted again at the baseline's orders (cached in the run folder as
            ``model.like-<baseline>.json``), so that a term one fit selected and the other did
            not is not mistaken for a change.
        folder : path, optional
            Read the run's fit from this folder instead of its archive folder (a reprocessed
            copy): its report's figures replace the index's.
        """

        own = folder is not None
        folder = self.folder(rec) if folder is None else Path(folder)
        figs, sig = rec.figures_mm, {}
        rp = folder / "report.json"
        if rp.is_file():
            f2, sig = report_figures(_read_json(rp))
            keep = {} if own else {k: v for k, v in figs.items() if not math.isnan(v)}
            figs = {**figs, **f2, **keep}
        spec = coeffs = cov = None
        mp = folder / "model.json"
        csv = folder / "measurements.csv"
        if mp.is_file():
            spec, coeffs, cov = model_arrays(_read_json(mp), str(mp))
            if like is not None and like.run_id != rec.run_id and csv.is_file():
                bp = self.folder(like) / "model.json"
                if bp.is_file():
                    bspec, _, _ = model_arrays(_read_json(bp), str(bp))
                    same = (
                        bspec.orders.shape == spec.orders.shape
                        and np.array_equal(bspec.orders, spec.orders)
                        and np.allclose(bspec.q_lo, spec.q_lo)
                        and np.allclose(bspec.q_hi, spec.q_hi)
                    )
                    if not same and bspec.n_joints == spec.n_joints:
                        spec, coeffs, cov = self._like_model(folder, mp, csv, like, bspec)
        q_measured = None
        if spec is not None and csv.is_file():
            q = formats.read_measurements(csv, spec.n_joints).q
            q_measured = (q.min(axis=0), q.max(axis=0))
        from ..identify.trend import RunState  # scipy.stats: see FIGURES

        return RunState(
            run_id=rec.run_id,
            t_s=rec.t_s,
            figures_mm=figs,
            spec=spec,
            coeffs=coeffs,
            cov=cov,
            figure_sigma_mm=sig,
            meta=rec.meta,
            q_measured=q_measured,
        )

    def _like_model(
        self, folder: Path, mp: Path, csv: Path, like: RunRecord, bspec: ErrorModelSpec
    ) -> tuple[ErrorModelSpec, np.ndarray, np.ndarray | None]:

        cache = folder / f"model.like-{safe_name(like.run_id, 'run id')}.json"
        if not cache.is_file():
            own = formats.read_model(mp)
            meas = formats.read_measurements(csv, own.robot.n_joints)
            refit = fit_model(own.robot, meas, bspec, own.effects, own.noise, own.prior)
            formats.write_model(cache, refit)
        return model_arrays(_read_json(cache), str(cache))


def _finite_or_none(v: object) -> float | None:
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _software_version() -> str:

    return software_version()


def trend_runs(
    arch: Archive, robot: str, upto: str | None = None
) -> tuple[list[RunRecord], list[RunRecord]]:
    """The robot's runs a trend can read (time order, up to run ``upto``), and those left out
    because their archive folder is missing (deleted behind the index).

    Raises
    ------
    InputError
        The latest run's folder (the run judged) or the baseline's is missing: a verdict
        without them would be made up.  One line naming the folder.
    """
    recs = arch.runs(robot)
    if upto is not None:
        ids = [r.run_id for r in recs]
        if upto in ids:
            recs = recs[: ids.index(upto) + 1]
    missing = [r for r in recs if not arch.folder(r).is_dir()]
    gone = {r.run_id for r in missing}
    latest = recs[-1]
    if latest.run_id in gone:
        raise InputError(
            f"latest run {latest.run_id} of robot {robot}: its folder {arch.folder(latest)} is "
            "missing (deleted behind the index?): it cannot be judged; restore the folder"
        )
    base = next((r for r in recs if r.baseline), None)
    if base is not None and base.run_id in gone:
        raise InputError(
            f"baseline run {base.run_id} of robot {robot}: its folder {arch.folder(base)} is "
            "missing (deleted behind the index?): restore it, or choose another baseline "
            "(quickhealth archive baseline ROBOT RUN_ID)"
        )
    return [r for r in recs if r.run_id not in gone], missing


def missing_words(arch: Archive, missing: list[RunRecord]) -> list[str]:
    """One warning per run :func:`trend_runs` left out."""
    return [
        f"run {r.run_id}: its folder {arch.folder(r)} is missing (deleted behind the index?): "
        "left out of the trend"
        for r in missing
    ]


def check_lines(checks: list[CheckRecord]) -> list[str]:
    """A robot's quick checks, one line each (not assessments: no figures)."""
    if not checks:
        return []
    out = [f"quick checks ({len(checks)}; not assessments):"]
    for c in checks:
        frac = (
            c.robot_time_s / c.full_loop_robot_time_s if c.full_loop_robot_time_s else float("nan")
        )
        out.append(
            f"  {c.check_id:<23} {c.time_utc:<21} {c.verdict.upper() if c.verdict == 'changed' else c.verdict}"
            f"{'' if c.decided else ' (undecided)'} after {c.poses} poses, {c.robot_time_s:.0f} s "
            f"({100 * frac:.0f} % of the loop) vs baseline {c.baseline_run_id}"
            + (f": {c.changes}" if c.changes else "")
        )
    return out


def trend_for(arch: Archive, robot: str, **kwargs: Any) -> TrendResult:
    """:func:`~quickhealth.identify.trend.assess_trend` over a robot's archived runs (oldest
    first) whose folders exist (:func:`trend_runs`), against its baseline run; ``kwargs`` go
    to ``assess_trend``."""
    from ..identify.trend import assess_trend  # scipy.stats: see FIGURES

    recs, _ = trend_runs(arch, robot)
    b = next((i for i, r in enumerate(recs) if r.baseline), None)
    if b is None:
        raise InputError(
            f"robot {robot!r} has no healthy run to be its baseline: "
            "quickhealth archive baseline ROBOT RUN_ID"
        )
    states = [arch.run_state(r, like=recs[b]) for r in recs]
    return assess_trend(states, b, **kwargs)
