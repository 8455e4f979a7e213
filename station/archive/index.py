"""The archive's index: its tables and every statement on them (SQLite or any SQLAlchemy URL).

Tables: ``runs`` (one row per run: time, plan hash, cell, calibration id, software version,
the main figures, healthy or not), ``robots`` (one per robot: its explicit baseline, if set),
``checks`` (the quick checks: a verdict against the baseline, never an assessment) and
``qh_meta`` (the index's identity).  The baseline of a robot is its explicit one, else its
first healthy run.

Writers take the index's write lock (BEGIN IMMEDIATE on SQLite: no lock upgrade deadlocks
between stations); readers read one snapshot (REPEATABLE READ on PostgreSQL).  Every
operation is bounded in time and fails with one line (:mod:`.db`).  The folders are the
archive's (:mod:`.store`).
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from ...identify.errors import InputError
from .db import IndexDB
from .records import FIGURES, META_KEYS, CheckRecord, NoArchive, RunRecord, safe_name


class Index:
    """The tables of one archive index and the statements on them."""

    def __init__(self, url: str, timeout_s: float | None = None) -> None:
        # SQLAlchemy (~0.3 s) only once an archive is opened, not for importing this module
        import sqlalchemy as sa

        self._db = IndexDB(url, timeout_s)  # a bad URL is refused before anything exists
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

    @property
    def name(self) -> str:
        """The index as messages name it: its file (SQLite), else its URL without password."""
        return self._db.name

    @property
    def sqlite_path(self) -> Path | None:
        """The index file of an SQLite URL (None: in memory, or another database)."""
        return self._db.sqlite_path

    def dispose(self) -> None:
        """Close the engine's pooled connections."""
        self.engine.dispose()

    # ---- schema
    def open_schema(self, create: bool) -> None:
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
        with self.write() as con:  # one station creates or migrates the schema at a time
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
        with self.read() as con:
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
            with self.read() as con:
                v = con.execute(
                    self._sa.select(self.t_meta.c.value).where(self.t_meta.c.key == "index_id")
                ).scalar()
            if not v:
                raise InputError(f"{self._db.name}: the index has no identity; open it again")
            self._index_id = str(v)
        return self._index_id

    @contextmanager
    def write(self) -> Iterator[Any]:
        """A write transaction (the index's write lock), bounded in time."""
        with self._db.guard("writing"), self._writer.begin() as con:
            yield con

    @contextmanager
    def read(self) -> Iterator[Any]:
        """One snapshot of the index, bounded in time."""
        with self._db.guard("reading"), self._reader.connect() as con, con.begin():
            yield con

    # ---- names: unique ignoring case
    def check_names(self, con: Any, robot: str, name: str, kind: str = "run") -> None:
        """Refuse a robot name, or a run (``kind="run"``) or check id of that robot, that
        differs only in case from one the index has: on a case-insensitive file system
        (Windows, macOS, an SMB share) the two are one folder, and the second would replace
        the first's files.  In a write transaction ``con`` the check is race-free: SQLite's
        write lock serialises the writers; on PostgreSQL an advisory lock on the folded robot
        name does.

        Raises
        ------
        InputError
            One line naming the name the index has.
        """
        sa = self._sa
        if self._pg and con.in_transaction():
            con.execute(
                sa.text("select pg_advisory_xact_lock(hashtext(:k))"),
                {"k": f"quickhealth-robot:{robot.lower()}"},
            )
        folded = robot.lower()
        others = set()
        for t in (self.t_robots, self.t_checks):
            q = sa.select(t.c.robot).where(sa.func.lower(t.c.robot) == folded).distinct()
            others |= {r for (r,) in con.execute(q) if r != robot}
        if others:
            other = sorted(others)[0]
            raise InputError(
                f"robot {robot!r}: the archive has robot {other!r}, the same name but for case: "
                "on a case-insensitive file system (Windows, macOS, an SMB share) both are one "
                f"folder and one would replace the other's runs; use {other!r}"
            )
        t, col = (self.t_runs, self.t_runs.c.run_id) if kind == "run" else (
            self.t_checks, self.t_checks.c.check_id
        )  # fmt: skip
        q = sa.select(col).where((t.c.robot == robot) & (sa.func.lower(col) == name.lower()))
        same = sorted(r for (r,) in con.execute(q) if r != name)
        if same:
            raise InputError(
                f"{kind} id {name!r}: robot {robot} has {kind} {same[0]!r}, the same id but for "
                "case: on a case-insensitive file system both are one folder; give another "
                f"--{kind}-id"
            )

    # ---- writing rows
    def insert_run(self, con: Any, row: Mapping[str, Any], *, may_replace: bool) -> bool:
        """Insert a run's row (and its robot's) in the write transaction ``con``; True when
        the run had a row already (then replaced, which ``may_replace`` must allow).

        Raises
        ------
        InputError
            The run is already archived (and ``may_replace`` is False), or a second station
            inserted it meanwhile.
        """
        sa = self._sa
        t = self.t_runs
        robot, rid = row["robot"], row["run_id"]
        self.check_names(con, robot, rid)
        key = (t.c.robot == robot) & (t.c.run_id == rid)
        existed = con.execute(sa.select(t.c.run_id).where(key)).first() is not None
        if existed:
            if not may_replace:
                raise InputError(f"run {robot}/{rid} is already archived (use another run id)")
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
        return existed

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

    def insert_check(self, con: Any, row: Mapping[str, Any]) -> None:
        """Insert a quick check's row in the write transaction ``con``.

        Raises
        ------
        InputError
            The check id is already archived for that robot.
        """
        sa = self._sa
        self.check_names(con, row["robot"], row["check_id"], "check")
        try:
            con.execute(sa.insert(self.t_checks).values(**row))
        except sa.exc.IntegrityError:
            raise InputError(
                f"check {row['robot']}/{row['check_id']} is already archived (use another check id)"
            ) from None

    def update_figures(self, robot: str, run_id: str, figures_mm: Mapping[str, float]) -> None:
        """Replace a run's indexed figures (after reprocessing)."""
        sa = self._sa
        vals = {f"{f}_mm": float(v) for f, v in figures_mm.items() if f in FIGURES}
        with self.write() as con:
            con.execute(
                sa.update(self.t_runs)
                .where((self.t_runs.c.robot == robot) & (self.t_runs.c.run_id == run_id))
                .values(**vals)
            )

    def set_baseline(self, robot: str, run_id: str | None) -> None:
        """Make ``run_id`` the robot's explicit baseline (None: back to the first healthy run)."""
        sa = self._sa
        with self.write() as con:
            con.execute(
                sa.update(self.t_robots)
                .where(self.t_robots.c.robot == safe_name(robot, "robot"))
                .values(baseline_run_id=run_id)
            )

    def set_healthy(self, robot: str, run_id: str, healthy: bool | None) -> None:
        """Mark a run healthy or not (used to choose the first healthy baseline)."""
        sa = self._sa
        with self.write() as con:
            con.execute(
                sa.update(self.t_runs)
                .where((self.t_runs.c.robot == robot) & (self.t_runs.c.run_id == run_id))
                .values(healthy=healthy)
            )

    # ---- reading
    def robots(self) -> list[str]:
        """Every robot in the index, sorted."""
        sa = self._sa
        with self.read() as con:
            return sorted(r[0] for r in con.execute(sa.select(self.t_robots.c.robot)))

    def checks(self, robot: str) -> list[CheckRecord]:
        """The robot's quick checks in time order (empty when it has none; ``root`` unset)."""
        sa = self._sa
        t = self.t_checks
        robot = safe_name(robot, "robot")
        with self.read() as con:
            rows = con.execute(
                sa.select(t).where(t.c.robot == robot).order_by(t.c.time_utc, t.c.check_id)
            ).mappings()
            return [check_record(r) for r in rows]

    def runs(self, robot: str) -> list[RunRecord]:
        """The robot's runs in time order, the baseline marked (one snapshot; empty for a
        robot the index does not know)."""
        sa = self._sa
        t = self.t_runs
        robot = safe_name(robot, "robot")
        with self.read() as con:
            rows = con.execute(
                sa.select(t).where(t.c.robot == robot).order_by(t.c.time_utc, t.c.run_id)
            ).mappings()
            recs = [run_record(r) for r in rows]
            explicit = con.execute(
                sa.select(self.t_robots.c.baseline_run_id).where(self.t_robots.c.robot == robot)
            ).scalar()
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
        with self.read() as con:
            for r in con.execute(q).mappings():
                d = dict(r)
                explicit, first_ok, n = d.pop("qh_explicit"), d.pop("qh_first_ok"), d.pop("qh_n")
                b = explicit or first_ok
                rec = run_record(d)
                out.append((replace(rec, baseline=rec.run_id == b), int(n), b))
        return out

    def run_keys(self) -> set[tuple[str, str]]:
        """Every indexed ``(robot, run_id)``."""
        sa = self._sa
        with self.read() as con:
            return {
                (r, i) for r, i in con.execute(sa.select(self.t_runs.c.robot, self.t_runs.c.run_id))
            }


def run_record(r: Mapping[str, Any], baseline: bool = False) -> RunRecord:
    """A ``runs`` row as a record (a NULL figure is NaN)."""
    d = dict(r)
    for f in FIGURES:
        if d[f"{f}_mm"] is None:
            d[f"{f}_mm"] = math.nan
    return RunRecord(**d, baseline=baseline)


def check_record(r: Mapping[str, Any], root: str = "") -> CheckRecord:
    """A ``checks`` row as a record (a NULL time is NaN)."""
    d = dict(r)
    for k in ("robot_time_s", "full_loop_robot_time_s"):
        d[k] = math.nan if d.get(k) is None else float(d[k])
    return CheckRecord(**d, root=root)
