"""``quickhealth export``: the model as a corrected URDF and as UR-style DH deltas.

quickhealth export MODEL.json [--urdf OUT.urdf] [--ur-calibration OUT.conf] [--json OUT.json]
    Only the constant joint errors go into a URDF or DH deltas; the command says which
    effects of the model neither can express.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ...identify.errors import InputError
from ..formats import read_model, write_text_atomic
from ..fsio import refuse_overwriting_inputs


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``export``."""
    e = subparsers.add_parser("export", help="corrected URDF and UR-style DH deltas from a model")
    e.add_argument("model", help="model.json")
    e.add_argument("--urdf", default=None, help="corrected URDF (joint origins) to write")
    e.add_argument(
        "--ur-calibration",
        default=None,
        help="OUT.yaml: the corrected kinematics as the UR ROS driver's calibration YAML; "
        "any other name: UR-style DH deltas (calibration.conf layout)",
    )
    e.add_argument("--json", default=None, help="the deltas and residuals as JSON")
    e.set_defaults(func=_export)


def _export(args: argparse.Namespace) -> int:
    from ...identify.compensate import (  # scipy.optimize: --help must not wait for it
        corrected_robot,
        dh_deltas,
        export_notes,
        ur_calibration_text,
        ur_kinematics_text,
        urdf_text,
    )

    if not (args.urdf or args.ur_calibration or args.json):
        raise InputError("nothing to export: give --urdf, --ur-calibration and/or --json")
    refuse_overwriting_inputs(
        [("--urdf", args.urdf), ("--ur-calibration", args.ur_calibration), ("--json", args.json)],
        [args.model],
    )
    fm = read_model(args.model)  # validated: finite, sane coefficients (never a URDF of "nan")
    notes = export_notes([e.name for e in fm.effects])
    # every document is computed before the first is written: no half export on a failure
    docs: list[tuple[str, str, str]] = []
    if args.urdf:
        rc = corrected_robot(fm.robot, fm.spec, fm.coeffs)
        if not np.all(np.isfinite(rc.links)):
            raise InputError(f"{args.model}: the corrected kinematics are not finite")
        docs.append(
            (
                args.urdf,
                urdf_text(rc, comments=notes),
                "joint origins with the identified constant joint errors",
            )
        )
    as_yaml = bool(args.ur_calibration) and Path(args.ur_calibration).suffix.lower() in (
        ".yaml",
        ".yml",
    )
    if as_yaml:
        try:
            text, kex = ur_kinematics_text(fm.robot, fm.spec, fm.coeffs, notes)
        except ValueError as exc:
            raise InputError(f"{args.model}: {exc}") from None
        if not np.all(np.isfinite(kex.kinematics.xyz)) or not np.all(
            np.isfinite(kex.kinematics.rpy)
        ):
            raise InputError(f"{args.model}: the corrected kinematics are not finite")
        docs.append((args.ur_calibration, text, "corrected kinematics, UR ROS driver YAML"))
    if (args.ur_calibration and not as_yaml) or args.json:
        try:
            cal = dh_deltas(fm.robot, fm.spec, fm.coeffs)
        except ValueError as exc:
            hint = ""
            if fm.robot.nominal is not None and fm.robot.nominal.calibration is not None:
                hint = (
                    f" (fitted against the controller calibration {fm.robot.nominal.calibration}:"
                    " export --ur-calibration OUT.yaml instead)"
                )
            raise InputError(f"{args.model}: {exc}{hint}") from None
        print(
            f"DH deltas: corrected kinematics differ from nominal by "
            f"{cal.nominal_residual_pos_rms * 1e3:.4f} mm rms; DH cannot express "
            f"{cal.residual_pos_rms * 1e3:.4f} mm rms of it"
        )
        if args.ur_calibration and not as_yaml:
            docs.append(
                (args.ur_calibration, ur_calibration_text(cal, notes), "UR-style DH deltas")
            )
        if args.json:
            doc = {
                "units": "m, rad",
                "effects_left_out": [e.name for e in fm.effects],
                "delta_theta": cal.delta_theta.tolist(),
                "delta_a": cal.delta_a.tolist(),
                "delta_d": cal.delta_d.tolist(),
                "delta_alpha": cal.delta_alpha.tolist(),
                "residual_pos_rms_mm": cal.residual_pos_rms * 1e3,
                "residual_rot_rms_mrad": cal.residual_rot_rms * 1e3,
            }
            docs.append((args.json, json.dumps(doc, indent=1, allow_nan=False) + "\n", "deltas"))
    if fm.effects:
        print(notes[0])
    for path, text, what in docs:
        write_text_atomic(path, text)
        print(f"wrote {path} ({what})")
    return 0
