"""The archive: run and check folders under one root, kept in step with the index.

:class:`Archive` places folders (a hidden staging copy, marked, renamed into place inside the
index transaction that inserts its row) and answers what the index holds; the statements are
:class:`~.index.Index`'s, reading and checking run folders :mod:`.folders`'.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from ...identify.errors import InputError
from ..formats.common import one_line
from ..fsio import copy_plain_tree, make_dirs, plain_tree, write_atomic, write_error
from .folders import (
    PreparedRun,
    mark,
    prepare_run,
    read_json,
    refuse_foreign,
    sweep_stale_staging,
)
from .index import Index, check_record
from .records import (
    INDEX_FILE,
    MARKER,
    CheckRecord,
    NoArchive,
    RunRecord,
    default_root,
    iso_utc,
    parse_time,
    safe_name,
)


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
    line (:mod:`.db`).
    """

    def __init__(
        self,
        root: Path,
        url: str | None = None,
        *,
        create: bool = True,
        timeout_s: float | None = None,
    ) -> None:
        given = Path(root)
        if given.exists() and not given.is_dir():
            raise InputError(
                f"{given}: names a file; the archive is a folder (of index.sqlite and robots/)"
            )
        self.root = given.resolve()
        self.url = url or f"sqlite:///{self.root / INDEX_FILE}"
        self.index = Index(self.url, timeout_s)  # a bad URL is refused before anything exists
        self.engine = self.index.engine
        index_file = self.index.sqlite_path
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
            self.index.open_schema(create)
            if not self.root.is_dir():  # a shared index: the run folders' root
                if not create:
                    return
                made += [p for p in (self.root, *self.root.parents) if not p.exists()][::-1]
                make_dirs(self.root)
        except BaseException:
            self.index.dispose()
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
        self.index.dispose()
        index_file = self.index.sqlite_path
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

    @property
    def index_id(self) -> str:
        """The index's identity: the mark of the folders it put here (:meth:`.Index.index_id`)."""
        return self.index.index_id

    @classmethod
    def open(
        cls,
        root: str | Path | None = None,
        url: str | None = None,
        *,
        create: bool = True,
        timeout_s: float | None = None,
    ) -> Archive:
        """The archive at ``root`` (default :func:`~.records.default_root`); created if missing
        unless ``create`` is False (then a missing archive is refused with one line, exit 2).
        ``timeout_s`` bounds every index operation (:mod:`.db`; default 10 s)."""
        return cls(Path(root) if root else default_root(), url, create=create, timeout_s=timeout_s)

    # ---- paths
    def run_path(self, robot: str, run_id: str) -> Path:
        """Folder of a run; never outside the archive root."""
        return self._inside("robots", "run", robot, run_id)

    def check_path(self, robot: str, check_id: str) -> Path:
        """Folder of a quick check; never outside the archive root."""
        return self._inside("checks", "check", robot, check_id)

    def _inside(self, folder: str, kind: str, robot: str, name: str) -> Path:
        """``root/folder/robot/name`` (each part checked by :func:`safe_name`), refused in one
        line should it resolve outside the archive root."""
        p = (
            self.root / folder / safe_name(robot, "robot") / safe_name(name, f"{kind} id")
        ).resolve()
        if not p.is_relative_to(self.root):
            raise InputError(f"{kind} {robot}/{name} would lie outside the archive {self.root}")
        return p

    def folder(self, rec: RunRecord) -> Path:
        """The run's folder in the archive."""
        return self.run_path(rec.robot, rec.run_id)

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
        """Copy a run folder into the archive and index it (:func:`~.folders.prepare_run`,
        then :meth:`add_prepared`; the parameters are ``prepare_run``'s)."""
        prep = prepare_run(
            robot, run_dir, run_id=run_id, time_utc=time_utc, meta=meta, healthy=healthy
        )
        return self.add_prepared(prep, replace_existing=replace_existing)

    def add_prepared(self, prep: PreparedRun, *, replace_existing: bool = False) -> RunRecord:
        """Copy a checked run folder into the archive and index it.

        The folder is copied into a hidden staging folder first (regular files and folders
        only: :func:`~quickhealth.station.fsio.copy_plain_tree`), marked with this index's
        identity (:data:`~.records.MARKER`), then renamed into place inside the transaction
        that inserts its row.  An archive folder of that run that this index has no row for is
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
        marked = mark(self.index_id, robot, rid)
        if in_place:
            self._refuse_foreign(dst, robot, rid, replacing=True)
            self._index_and_place(row, None, dst, True, True, marked)
            return self.get(robot, rid)

        with self.index.read() as con:  # before anything is written (again when indexed)
            self.index.check_names(con, robot, rid)
        make_dirs(dst.parent)
        sweep_stale_staging(dst.parent, self.index_id)
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".incoming-{rid}-", dir=dst.parent))
        except OSError as exc:
            raise write_error(dst.parent, exc) from None
        try:
            write_atomic(stage / "owner.json", marked)  # first: a killed copy is known as ours
            copy_plain_tree(src, stage / "run")  # the slow part, outside any lock
            write_atomic(stage / "run" / MARKER, marked)
            self._index_and_place(row, stage, dst, replace_existing, False, marked)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        return self.get(robot, rid)

    def _refuse_foreign(self, folder: Path, robot: str, rid: str, *, replacing: bool) -> None:
        refuse_foreign(
            folder,
            robot,
            rid,
            index_id=self.index_id,
            index_name=self.index.name,
            replacing=replacing,
        )

    def _index_and_place(
        self,
        row: dict[str, Any],
        stage: Path | None,
        dst: Path,
        replace_existing: bool,
        in_place: bool,
        marked: str,
    ) -> None:
        """Insert the run's row and rename its staged folder into place, in one transaction."""

        robot, rid = row["robot"], row["run_id"]
        moved: list[tuple[Path, Path]] = []  # renames to undo if the transaction fails
        try:
            with self.index.write() as con:
                # a run folder that already is the archive's (the TUI fits in place and
                # registers again after each refit) updates its row
                existed = self.index.insert_run(con, row, may_replace=replace_existing or in_place)
                if in_place:
                    write_atomic(dst / MARKER, marked)
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

    def update_figures(self, robot: str, run_id: str, figures_mm: Mapping[str, float]) -> None:
        """Replace a run's indexed figures (after reprocessing)."""
        self.index.update_figures(robot, run_id, figures_mm)

    def set_baseline(self, robot: str, run_id: str | None) -> None:
        """Make ``run_id`` the robot's baseline (None: back to the first healthy run)."""
        if run_id is not None:
            self.get(robot, run_id)  # must exist
        self.index.set_baseline(robot, run_id)

    def set_healthy(self, robot: str, run_id: str, healthy: bool | None) -> None:
        """Mark a run healthy or not (used to choose the first healthy baseline)."""
        self.get(robot, run_id)
        self.index.set_healthy(robot, run_id, healthy)

    # ---- quick checks
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
        doc = read_json(cp)
        if doc.get("schema") != "quickhealth.check/1" or doc.get("verdict") not in (
            "unchanged",
            "changed",
        ):
            raise InputError(f"{cp}: not a quick check's result (schema quickhealth.check/1)")
        plain_tree(src)  # links and special files refused up front
        cid = safe_name(check_id or str(doc.get("run_id") or src.resolve().name), "check id")
        when = str(doc.get("started_utc") or "")
        t_iso = (
            iso_utc(parse_time(when))
            if when
            else iso_utc(datetime.fromtimestamp(cp.stat().st_mtime, UTC))
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
        for k in ("baseline_run_id", "verdict", "changes", "plan_hash"):  # index rows: one line
            one_line(row[k], f"{cp}: its {k}")
        if in_place:  # the TUI checks straight into the archive: its row, its mark
            with self.index.write() as con:
                self.index.insert_check(con, row)
                write_atomic(dst / MARKER, mark(self.index_id, robot, cid))
            return check_record(row, str(self.root))
        with self.index.read() as con:  # before anything is written (again when indexed)
            self.index.check_names(con, robot, cid, "check")
        make_dirs(dst.parent)
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".incoming-{cid}-", dir=dst.parent))
        except OSError as exc:
            raise write_error(dst.parent, exc) from None
        try:
            copy_plain_tree(src, stage / "check")
            write_atomic(stage / "check" / MARKER, mark(self.index_id, robot, cid))
            with self.index.write() as con:
                self.index.insert_check(con, row)
                if dst.exists() or dst.is_symlink():
                    raise InputError(f"{dst}: already exists: refusing to replace it")
                (stage / "check").rename(dst)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        return check_record(row, str(self.root))

    def checks(self, robot: str) -> list[CheckRecord]:
        """The robot's quick checks in time order (empty when it has none)."""
        return [replace(c, root=str(self.root)) for c in self.index.checks(robot)]

    # ---- reading
    def robots(self) -> list[str]:
        """Every robot in the archive, sorted."""
        return self.index.robots()

    def runs(self, robot: str) -> list[RunRecord]:
        """The robot's runs in time order, the baseline marked (one snapshot of the index).

        Raises
        ------
        InputError
            Unknown robot.
        """
        recs = self.index.runs(robot)
        if not recs:
            known = ", ".join(self.robots()) or "none"
            raise InputError(
                f"robot {robot!r} has no runs in the archive {self.root} (robots: {known})"
            )
        return recs

    def fleet(self) -> list[tuple[RunRecord, int, str | None]]:
        """Every robot's latest run, its number of runs and its baseline run id, sorted by
        robot (one query: :meth:`.Index.fleet`)."""
        return self.index.fleet()

    def orphans(self) -> list[Path]:
        """Run folders with no row in this index (and staging folders ``.incoming-*``): left
        by a writer killed before its commit, or put there by another index sharing the
        archive folder.  ``add_run`` of that run replaces only those carrying this index's
        mark (:func:`~.folders.marker_owner`); it refuses the others."""
        indexed = self.index.run_keys()
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


def _finite_or_none(v: object) -> float | None:
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None
