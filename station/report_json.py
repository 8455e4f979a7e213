"""report.json: the one writer of an :class:`~quickhealth.identify.assess.Assessment`.

``identify fit``, the TUI's results, ``reprocess`` and the demo all write report.json through
:func:`write_report_json`; the schema (``SCHEMA``) and its one checker (:func:`check_report`)
live with the file format in :mod:`quickhealth.station.formats.report` and are re-exported
here (docs/identify.md, "report.json").  Schema ``quickhealth.report/2``: the assessment's
keys (``formats.report.REQUIRED``) and ``nominal`` (which nominal kinematics the figures are
against: robot, controller calibration file and its SHA-256); a producer may add a ``run`` object (the station's run
id, robot name, verdict, threshold) and ``input`` (the measurement file), and ``quickhealth
report`` adds ``coverage``, ``diagnosis``, ``trend`` and ``iso9283`` sections.  Units: mm,
degrees, mrad (joint curves), °C, s.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from quickhealth.station.formats.common import json_plain as _plain
from quickhealth.station.formats.report import REPORT_SCHEMA as SCHEMA
from quickhealth.station.formats.report import check_report

__all__ = ["SCHEMA", "check_report", "report_of", "write_report_json"]


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
        "nominal": _nominal(fm.robot),
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


def write_report_json(
    path: str | os.PathLike[str],
    a: Any,
    *,
    source: str | None = None,
    run: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write report.json of assessment ``a`` (atomically); returns the content written."""
    from quickhealth.station.formats.report import write_report

    rep = report_of(a, source=source, run=run)
    write_report(path, rep)
    return rep


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


def _nominal(robot: Any) -> dict[str, Any]:
    """Which nominal kinematics the figures are against: the robot as named, and the
    controller calibration file (name, SHA-256) when one replaced its nominal kinematics."""
    from quickhealth.identify.robot import Nominal, nominal_of

    nom = robot.nominal if robot.nominal is not None else Nominal(robot.name)
    return {**nom.as_dict(), "description": nominal_of(robot)}
