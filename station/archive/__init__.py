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
    states = [run_state(arch, r) for r in arch.runs("ur5-cell3")]

Modules, by job: :mod:`.records` (names, the default place, the index's records),
:mod:`.db` (the database engine: time-outs, one-line failures), :mod:`.index` (the tables and
every statement), :mod:`.folders` (reading and checking run folders, the folders' mark),
:mod:`.store` (:class:`Archive`: folders placed in step with the index), :mod:`.trend` (the
trend's inputs and the trend over a robot's runs).
"""

from .folders import PreparedRun, marker_owner, prepare_run, report_figures, run_metadata
from .records import (
    ENV_VAR,
    FIGURES,
    INDEX_FILE,
    MARKER,
    META_KEYS,
    CheckRecord,
    NoArchive,
    RunRecord,
    default_root,
    safe_name,
)
from .store import Archive
from .trend import check_lines, missing_words, model_arrays, run_state, trend_for, trend_runs

__all__ = [
    "ENV_VAR",
    "FIGURES",
    "INDEX_FILE",
    "MARKER",
    "META_KEYS",
    "Archive",
    "CheckRecord",
    "NoArchive",
    "PreparedRun",
    "RunRecord",
    "check_lines",
    "default_root",
    "marker_owner",
    "missing_words",
    "model_arrays",
    "prepare_run",
    "report_figures",
    "run_metadata",
    "run_state",
    "safe_name",
    "trend_for",
    "trend_runs",
]
