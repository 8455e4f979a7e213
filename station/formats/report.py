"""report.json: its content, reading, writing and checking (schema ``quickhealth.report/2``).

The one writer of an :class:`~quickhealth.identify.assess.Assessment` (:func:`report_of`,
:func:`write_report_json`): every door's fit writes report.json through it (docs/identify.md,
"report.json").  The assessment's keys (:data:`REQUIRED`); a producer may add ``input`` (the
measurement file) and the report adds its sections (``coverage``, ``diagnosis``, ``trend``,
``iso9283``, ``verdict``) and the ``run`` object (run id, robot name, verdict, threshold):
:func:`with_sections`.  The schema (the one ``REPORT_SCHEMA``) and the one checker,
:func:`check_report`.  Units: mm, degrees, mrad (joint curves), °C, s; SI inside.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...identify.effects import CHANNELS, channels_of
from ...identify.errormodel import MOTIONS
from ...identify.errors import InputError
from ...identify.robot import Nominal, nominal_of
from ..provenance import provenance
from .common import json_plain, load_json_limited, write_text_atomic

if TYPE_CHECKING:  # types only: the fit and the trend load scipy, every reader of files would wait
    from ...identify.assess import Assessment
    from ...identify.fit import FittedModel
    from ...identify.measurements import Measurements
    from ...identify.trend import TrendResult

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


def check_report(doc: object, name: str = "report.json", *, complete: bool = True) -> None:
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
    for eff in doc["effects"]:  # each condition an effect depends on is stated
        try:
            needs = channels_of(str(eff))
        except InputError:
            raise InputError(f"{name}: effects holds {eff!r}, not an effect name") from None
        for key in (CHANNELS[c].condition for c in needs):
            if key is not None and cond.get(key) is None:
                raise InputError(f"{name}: the model has {eff} but the conditions give no {key}")
    if len(doc["residuals"]) != doc["n_poses"]:
        raise InputError(
            f"{name}: {len(doc['residuals'])} residual rows for {doc['n_poses']} poses"
        )
    if doc["n_poses"] and "pos_mm" not in doc["residuals"][0]:
        raise InputError(f"{name}: residual rows need pos_mm")


def report_of(
    a: Assessment, *, source: str | None = None, run: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The report.json content of assessment ``a`` (plain JSON types, file units)."""
    fm = a.fitted
    spec = fm.spec
    meas = a.measurements
    sel = a.selection
    rep: dict[str, Any] = {
        "n_poses": int(fm.n_poses),
        "n_params": int(fm.n_free),
        "n_params_total": int(fm.params.size),
        "bic": float(fm.bic),
        "chi2": float(fm.chi2_data),
        "chi2_with_prior": float(fm.chi2),
        "dof": int(fm.dof),
        "rms_pos_mm": float(fm.rms_pos * 1e3),
        "converged": bool(fm.converged),
        "robot": fm.robot.name,
        "nominal": _nominal(fm.robot),
        "effects": [e.name for e in fm.effects],
        "orders": {
            spec.frame_name(f): dict(zip(MOTIONS, spec.orders[f].tolist(), strict=True))
            for f in range(spec.orders.shape[0])
        },
        "joint_range_deg": {
            "lo": np.degrees(spec.q_lo).tolist(),
            "hi": np.degrees(spec.q_hi).tolist(),
        },
        "unidentifiable": list(fm.unidentifiable),
        "chi2_check": None,
        "search": None,
        "noise": {
            "sigma_pos_mm": a.noise.sigma_pos * 1e3,
            "sigma_rot_deg": float(np.degrees(a.noise.sigma_rot)),
            "sigma_q_deg": float(np.degrees(a.noise.sigma_q)),
            "per_row": meas.sigma_pos is not None,
            "excess_pos_mm": a.noise.excess_pos * 1e3,
            "excess_rot_deg": float(np.degrees(a.noise.excess_rot)),
            "estimated": bool(a.noise.rescaled),
        },
        "summary": a.summary(),
        "workspace": a.workspace.as_dict(),
        "joint_curves": [c.as_dict() for c in a.curves],
        "residuals": _residual_records(fm, meas),
    }
    if sel is not None:
        rep["chi2_check"] = {
            "verdict": sel.chi2_check.verdict,
            "ratio_to_median": sel.chi2_check.ratio_to_median,
            "message": sel.chi2_check.message,
        }
        rep["search"] = {
            "margin": sel.margin,
            "n_fits": sel.n_fits,
            "n_scored": sel.n_scored,
            "steps": [
                {
                    "kind": s.kind,
                    "motion": s.motion,
                    "from": s.from_order,
                    "to": s.to_order,
                    "bic_linear": s.bic_linear,
                    "bic": s.bic,
                    "accepted": s.accepted,
                }
                for s in sel.trace
            ],
            "rescaled": list(sel.rescaled),
        }
        if sel.noise_scale is not None:
            rep["noise_scale"] = sel.noise_scale.as_dict()
    if fm.rms_rot is not None:
        rep["rms_rot_deg"] = float(np.degrees(fm.rms_rot))
    if source is not None:
        rep["input"] = str(source)
    if run is not None:
        rep["run"] = dict(run)
    return rep


def _nominal(robot: Any) -> dict[str, Any]:
    """Which nominal kinematics the figures are against: the robot as named, and the
    controller calibration file (name, SHA-256) when one replaced its nominal kinematics."""
    nom = robot.nominal if robot.nominal is not None else Nominal(robot.name)
    return {**nom.as_dict(), "description": nominal_of(robot)}


def write_report_json(
    path: str | os.PathLike[str],
    a: Assessment,
    *,
    source: str | None = None,
    run: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write report.json of assessment ``a`` (atomically); returns the content written
    (``extra``: more top-level keys, e.g. the accuracy ``spec``)."""
    rep = {**report_of(a, source=source, run=run), **(extra or {})}
    write_report(path, rep)
    return rep


def _residual_records(fm: FittedModel, meas: Measurements) -> list[dict[str, Any]]:
    rp = fm.residual_pos * 1e3
    out = []
    for i in range(fm.n_poses):
        r: dict[str, Any] = {
            "row": i + 1,
            "pose_id": None if meas.pose_id is None else meas.pose_id[i],
            "pos_mm": rp[i].tolist(),
            "norm_mm": float(np.linalg.norm(rp[i])),
        }
        if fm.residual_rot is not None:
            r["rot_deg"] = np.degrees(fm.residual_rot[i]).tolist()
        out.append(r)
    return out


def with_sections(
    doc: Mapping[str, Any],
    sections: Mapping[str, Mapping[str, Any]],
    *,
    run: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> str:
    """report.json ``doc`` with the sections of the report added, as the text to write: each
    section's data, or ``{"missing": why}`` / ``{"not_applicable": why}``; ``run`` (run
    id, robot name, verdict, healthy, spec) when given; ``extra`` top-level keys (``spec``).

    The document keeps its ``schema`` (a version 1 file stays version 1: it lacks keys of
    version 2, and relabelling it would make it claim what it does not hold) and every key
    of the fit; ``provenance`` names the program that wrote the file last, as for any
    writer.  NaN and infinities become null.
    """
    new = dict(doc)
    for key, s in sections.items():
        if s.get("missing"):
            new[key] = {"missing": s["missing"]}
        elif s.get("not_applicable"):
            new[key] = {"not_applicable": s["not_applicable"]}
        else:
            new[key] = s["data"]
    if run is not None:
        new["run"] = dict(run)
    new.update(extra or {})
    new["provenance"] = provenance()
    return json.dumps(json_plain(new), indent=1, allow_nan=False) + "\n"


def trend_to_json(res: TrendResult) -> dict[str, Any]:
    """A trend as JSON-able numbers (mm, s, words): report.json's ``trend``, ``trend --json``."""
    return {
        "run_ids": list(res.run_ids),
        "t_s": list(res.t_s),
        "baseline": res.run_ids[res.baseline_index],
        "figures_mm": {k: list(v) for k, v in res.figures_mm.items()},
        "flags": res.flags(),
        "flagged": res.flagged,
        "hints": res.hints,
        "warnings": list(res.warnings),
        "threshold_mm": res.threshold_mm,
        "prognosis": {
            f: {
                "trend": p.trend,
                "slope_mm_per_day": p.slope_mm_per_day,
                "p_value": p.p_value,
                "crossing_t_s": p.crossing_t_s,
                "crossing_early_t_s": p.crossing_early_t_s,
                "crossing_late_t_s": p.crossing_late_t_s,
                "words": p.words(),
            }
            for f, p in res.prognoses.items()
        },
        "changes": [c.to_json() for c in res.named_changes()],
        "setup_changes": [c.to_json() for c in res.setup_changes()],
        "fault_test": _fault_test_json(res),
        "curve_changes": [
            {
                "joint": c.joint,
                "motion": c.motion,
                "max_change": c.max_change,
                "chi2": c.chi2,
                "dof": c.dof,
                "z_max": c.z_max,
                "p_value": c.p_value,
                "significant": c.significant,
            }
            for c in res.curve_changes[res.latest]
        ],
    }


def _fault_test_json(res: TrendResult) -> dict[str, Any] | None:
    """How the latest run's change was tested along the faults (None: not tested)."""
    t = res.fault_tests[res.latest] if res.latest < len(res.fault_tests) else None
    if t is None:
        return None
    return {
        "faults_tested": t.tested,
        "level_per_fault": t.level,
        "scale": t.scale,
        "chi2": t.chi2,
        "dof": t.dof,
        "residual_chi2": t.residual_chi2,
        "residual_dof": t.residual_dof,
        "residual_p": t.residual_p,
        "next": [c.to_json() for c in t.named if not c.significant],
    }
