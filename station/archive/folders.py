"""The archive's run folders: what a run folder says about itself, checking one before it is
archived, and the mark that tells which index put a folder into the archive.

- :func:`run_metadata`, :func:`report_figures`: a run folder's metadata and main figures;
- :func:`prepare_run`: a run folder checked for :meth:`~.store.Archive.add_prepared`, before
  anything is written;
- :func:`marker_owner`, :func:`mark`, :func:`refuse_foreign`, :func:`sweep_stale_staging`:
  the :data:`~.records.MARKER` of archived folders, so that stations sharing an archive folder
  but not its index never replace each other's runs.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from ...identify.errors import InputError
from .. import formats
from ..formats import load_json_limited
from ..fsio import pid_alive, plain_tree
from ..provenance import software_version, version_number
from ..reporting.verdict import healthy_of
from .records import FIGURES, MARKER, META_KEYS, RunRecord, iso_utc, parse_time, safe_name


def read_json(path: Path) -> dict[str, Any]:

    doc = load_json_limited(path, "json")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object")
    return doc


def _csv_meta(path: Path) -> dict[str, str]:
    """``# key: value`` comment lines at the top of a CSV v1 file."""
    out: dict[str, str] = {}
    with path.open(encoding="utf-8", errors="replace") as fh:
        for raw in fh:
            for line in raw.splitlines():  # the lines the measurement reader sees
                if not line.startswith("#"):
                    return out
                kv = formats.common.read_meta_line(line)
                if kv is not None:
                    out[kv[0]] = kv[1]
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
        doc = read_json(p)
        for src in (doc, doc.get("meta", {}), doc.get("run", {})):
            if isinstance(src, dict):
                meta.update({k: str(v) for k, v in src.items() if isinstance(v, str | int)})
    plan = run_dir / "plan.json"
    if "plan_hash" not in meta and plan.is_file():
        doc = read_json(plan)
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
    if meta.get("software_version"):
        meta["software_version"] = version_number(meta["software_version"])
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
        Default: the verdict the report carries (:func:`~quickhealth.station.reporting.verdict.healthy_of`: its
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
        formats.one_line(v, f"--{k.replace('_', '-')}")  # an index row, a report line
        if len(str(v)) > 200:
            raise InputError(f"--{k.replace('_', '-')}: at most 200 characters")
    if time_utc is not None:
        parse_time(time_utc)
    given = Path(run_dir)
    if not given.is_dir():
        raise InputError(f"{given}: not a run folder")
    src = given.resolve()
    report_p = src / "report.json"
    if not report_p.is_file():
        raise InputError(f"{given}: no report.json (fit the run first: quickhealth identify fit)")
    report = read_json(report_p)
    # a run the trend and reprocess can use: the fit's figures and a valid model
    formats.check_report(report, str(report_p), complete=False)
    model_p = src / "model.json"
    if not model_p.is_file():
        raise InputError(f"{given}: no model.json (fit the run first: quickhealth identify fit)")
    formats.read_model(model_p)
    _, files, n_bytes = plain_tree(given)  # links and special files refused up front
    found = run_metadata(src)
    for k, v in found.items():
        if k in (*META_KEYS, "run_id", "time_utc", "started_utc"):
            formats.one_line(v, f"{given}: its {k}")
            if len(str(v)) > 200:
                raise InputError(f"{given}: its {k} is longer than 200 characters")
    found.update(meta or {})
    rid = run_id if run_id is not None else (found.get("run_id") or src.name)
    rid = safe_name(rid, "run id")
    when = time_utc or found.get("time_utc") or found.get("started_utc")
    if when:
        t_iso = iso_utc(parse_time(when))
    else:
        t_iso = iso_utc(datetime.fromtimestamp(report_p.stat().st_mtime, UTC))
    if not found.get("software_version"):
        found["software_version"] = software_version()
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


def mark(index_id: str, robot: str, run_id: str) -> str:
    """The contents of an archived folder's :data:`~.records.MARKER`: the index that put it
    there and the writer (host, process, time)."""

    doc = {
        "index_id": index_id,
        "robot": robot,
        "run_id": run_id,
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "time_utc": iso_utc(datetime.now(UTC)),
    }
    return json.dumps(doc, indent=1) + "\n"


def refuse_foreign(
    folder: Path, robot: str, rid: str, *, index_id: str, index_name: str, replacing: bool
) -> None:
    """Refuse (one line, exit 2) to replace a folder the index ``index_id`` cannot prove is its
    own: one marked by another index, or (``replacing`` False: the index has no row for the
    run) one with no mark of this index at all."""
    owner = marker_owner(folder)
    if owner == index_id or (replacing and owner is None):
        return
    whose = (
        f"a run put there by another index ({owner[:12]}…)"
        if owner
        else "a folder this index did not put there"
    )
    raise InputError(
        f"{folder}: holds {whose}; this index ({index_name}) has no row for "
        f"{robot}/{rid}: refusing to replace it (stations sharing an archive folder must "
        "share the index, --db); give another --run-id"
    )


def sweep_stale_staging(folder: Path, index_id: str) -> None:
    """Remove staging folders (``.incoming-*``) the index ``index_id``'s writers on this
    machine left when they were killed (their process is gone); another index's or a live
    writer's are left alone."""

    for d in folder.glob(".incoming-*"):
        try:
            doc = json.loads((d / "owner.json").read_text(encoding="utf-8"))
            mine = doc.get("index_id") == index_id and doc.get("host") == socket.gethostname()
            stale = mine and not pid_alive(int(doc["pid"]))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
        if stale and not d.is_symlink():
            shutil.rmtree(d, ignore_errors=True)
