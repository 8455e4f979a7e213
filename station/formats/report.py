"""report.json: reading, writing and checking the document (schema ``quickhealth.report/2``).

The content of an assessment's report is built by :mod:`quickhealth.station.report_json`;
this module holds the schema (the one ``REPORT_SCHEMA``), the writer of the file and the one
checker, :func:`check_report`.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from quickhealth.identify.errors import InputError

from .common import load_json_limited, write_text_atomic

REPORT_SCHEMA = "quickhealth.report/2"  # the one definition; version-1 files are still read
REPORT_SCHEMAS_READ = ("quickhealth.report/1", REPORT_SCHEMA)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def write_report(path: str | os.PathLike[str], report: dict[str, Any]) -> None:
    """Write report.json (``schema`` and this writer's ``provenance`` set; NaN/inf become null)."""
    from ..provenance import provenance

    doc = {"schema": REPORT_SCHEMA, **_jsonable(report), "provenance": provenance()}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def read_report(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read report.json."""
    p = Path(path)
    doc = load_json_limited(p, "report")
    if not isinstance(doc, dict) or doc.get("schema") not in REPORT_SCHEMAS_READ:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(f"{p}: not a quickhealth report (schema {got!r})")
    return doc


#: Top-level keys every report.json of an assessment has, and their JSON types.
REQUIRED: dict[str, type | tuple[type, ...]] = {
    "n_poses": int,
    "n_params": int,
    "n_params_total": int,
    "bic": float,
    "chi2": float,
    "chi2_with_prior": float,
    "dof": int,
    "rms_pos_mm": float,
    "converged": bool,
    "robot": str,
    "effects": list,
    "orders": dict,
    "joint_range_deg": dict,
    "unidentifiable": list,
    "chi2_check": (dict, type(None)),
    "search": (dict, type(None)),
    "noise": dict,
    "summary": list,
    "workspace": dict,
    "joint_curves": list,
    "residuals": list,
}
WORKSPACE_KEYS = ("conditions", "n_samples", "mean_mm", "std_mm", "max_mm", "p95_mm", "histogram")
#: The figures the archive and the trend read from every report, version 1 or 2.
REPORT_FIGURES = ("mean_mm", "std_mm", "max_mm")
REPORT_NUMBERS = ("n_poses", "rms_pos_mm", "chi2", "bic")


def check_report(doc: Any, name: str = "report.json", *, complete: bool = True) -> None:
    """Check a report.json document; the one checker of the format (docs/identify.md).

    Parameters
    ----------
    complete : bool
        True: a schema-2 assessment report (every key of :data:`REQUIRED` with its type, the
        workspace map with its conditions, one residual row per pose) whose figures are all
        finite.  False (``archive add``): only the figures the archive and the trend read
        (``workspace.mean_mm/std_mm/max_mm``, ``n_poses``, ``rms_pos_mm``, ``chi2``,
        ``bic``), so version-1 reports are still accepted.

    Raises
    ------
    InputError
        One line naming the first thing wrong.
    """
    if not isinstance(doc, dict):
        raise InputError(f"{name}: not a quickhealth report (a JSON object is expected)")
    if complete:
        _check_schema(doc, name)
    ws = doc.get("workspace")
    for key in REPORT_FIGURES:
        v = ws.get(key) if isinstance(ws, dict) else doc.get(f"workspace_{key}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
            raise InputError(
                f"{name}: workspace.{key} is {'missing' if v is None else repr(v)}: "
                "not a complete fit report (run quickhealth identify fit)"
            )
    for key in REPORT_NUMBERS:
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(
                f"{name}: {key} is {'missing' if v is None else repr(v)}: not a complete fit "
                "report (run quickhealth identify fit)"
            )


def _check_schema(doc: dict[str, Any], name: str) -> None:
    """The structure of a schema-2 assessment report (keys, types, conditions, residuals)."""
    if doc.get("schema") != REPORT_SCHEMA:
        raise InputError(f"{name}: schema is {doc.get('schema')!r}, expected {REPORT_SCHEMA!r}")
    for key, typ in REQUIRED.items():
        if key not in doc:
            raise InputError(f"{name}: missing key {key!r}")
        v = doc[key]
        ok = isinstance(v, typ) or (typ is float and isinstance(v, int) and not isinstance(v, bool))
        if not ok:
            raise InputError(f"{name}: {key!r} is {type(v).__name__}, expected {typ}")
    for key in WORKSPACE_KEYS:
        if key not in doc["workspace"]:
            raise InputError(f"{name}: workspace has no {key!r}")
    cond = doc["workspace"]["conditions"]
    if not isinstance(cond, dict) or not {"temp_c", "time_s", "text"} <= set(cond):
        raise InputError(f"{name}: workspace.conditions needs temp_c, time_s and text")
    needs = {"thermal": "temp_c", "drift": "time_s"}
    for eff, key in needs.items():
        if eff in doc["effects"] and cond[key] is None:
            raise InputError(f"{name}: the model has {eff} but the conditions give no {key}")
    if len(doc["residuals"]) != doc["n_poses"]:
        raise InputError(
            f"{name}: {len(doc['residuals'])} residual rows for {doc['n_poses']} poses"
        )
    if doc["n_poses"] and "pos_mm" not in doc["residuals"][0]:
        raise InputError(f"{name}: residual rows need pos_mm")
