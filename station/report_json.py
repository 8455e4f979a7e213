"""report.json: the one writer of an :class:`~quickhealth.identify.assess.Assessment`.

``identify fit``, the TUI's results, ``reprocess`` and the demo all write report.json through
:func:`write_report_json`; :func:`check_report` checks a document against the schema
(docs/identify.md, "report.json").  Schema ``quickhealth.report/2``: the assessment's keys
below; a producer may add a ``run`` object (the station's run id, robot name, verdict,
threshold) and ``input`` (the measurement file), and ``quickhealth report`` adds
``coverage``, ``diagnosis``, ``trend`` and ``iso9283`` sections.  Units: mm, degrees, mrad
(joint curves), °C, s.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from quickhealth.identify.errors import InputError

SCHEMA = "quickhealth.report/2"

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


def report_of(
    a: Any, *, source: str | None = None, run: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The report.json content of assessment ``a`` (plain JSON types, file units)."""
    import numpy as np

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
        "effects": [e.name for e in fm.effects],
        "orders": {
            spec.frame_name(f): dict(
                zip(("dx", "dy", "dz", "ex", "ey", "ez"), spec.orders[f].tolist(), strict=True)
            )
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
    if fm.rms_rot is not None:
        rep["rms_rot_deg"] = float(np.degrees(fm.rms_rot))
    if source is not None:
        rep["input"] = str(source)
    if run is not None:
        rep["run"] = dict(run)
    return rep


def write_report_json(
    path: str | os.PathLike[str],
    a: Any,
    *,
    source: str | None = None,
    run: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write report.json of assessment ``a`` (atomically); returns the content written."""
    from quickhealth.station import formats

    rep = report_of(a, source=source, run=run)
    formats.write_report(path, rep)
    return rep


def check_report(doc: Mapping[str, Any], name: str = "report.json") -> None:
    """Raise :class:`InputError` (one line) if ``doc`` is not a schema-2 assessment report."""
    if doc.get("schema") != SCHEMA:
        raise InputError(f"{name}: schema is {doc.get('schema')!r}, expected {SCHEMA!r}")
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


def _residual_records(fm: Any, meas: Any) -> list[dict[str, Any]]:
    import numpy as np

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


def with_sections(doc: Mapping[str, Any], sections: Mapping[str, Mapping[str, Any]]) -> str:
    """report.json ``doc`` with the sections of ``quickhealth report`` added, as the text to
    write: each section's data, or ``{"missing": why}`` / ``{"not_applicable": why}``.

    The document keeps its ``schema`` (a version 1 file stays version 1: it lacks keys of
    version 2, and relabelling it would make it claim what it does not hold) and every key
    of the fit; ``provenance`` names the program that wrote the file last, as for any
    writer.  NaN and infinities become null.
    """
    import json

    from .provenance import provenance

    new = dict(doc)
    for key, s in sections.items():
        if s.get("missing"):
            new[key] = {"missing": s["missing"]}
        elif s.get("not_applicable"):
            new[key] = {"not_applicable": s["not_applicable"]}
        else:
            new[key] = s["data"]
    new["provenance"] = provenance()
    return json.dumps(_plain(new), indent=1, allow_nan=False) + "\n"


def _plain(x: Any) -> Any:
    """JSON-able copy: numpy to Python, NaN/inf to None."""
    import math

    import numpy as np

    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        return float(x) if math.isfinite(x) else None
    return x
