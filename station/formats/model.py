"""model.json (``quickhealth.model/1``): a fitted model, JSON only (never pickle)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ...identify.effects import parse_effects
from ...identify.errormodel import ErrorModelSpec
from ...identify.errors import InputError
from ...identify.fit import FittedModel, InstrumentNoise, ParameterPrior
from ...identify.sanity import check_plausible
from ..provenance import provenance
from .common import load_json_limited, write_text_atomic
from .robot import check_robot, robot_from_json, robot_to_json

MODEL_SCHEMA = "quickhealth.model/1"


def model_to_json(fitted: FittedModel) -> dict[str, Any]:
    """JSON document of a :class:`~quickhealth.identify.fit.FittedModel` (schema-versioned)."""
    spec = fitted.spec
    return {
        "schema": MODEL_SCHEMA,
        "units": "SI (m, rad); coefficients of the Chebyshev series of each error motion",
        "robot": robot_to_json(fitted.robot),
        "spec": {
            "orders": spec.orders.tolist(),
            "q_lo": spec.q_lo.tolist(),
            "q_hi": spec.q_hi.tolist(),
        },
        "labels": fitted.labels,
        "coeffs": fitted.coeffs.tolist(),
        "effects": [
            {
                "name": e.name,
                "params": np.asarray(p, float).tolist(),
                "param_names": list(e.param_names),
                **e.info(),
            }
            for e, p in zip(fitted.effects, fitted.effect_params, strict=True)
        ],
        "cov": fitted.cov.tolist(),
        "T_instr_base0": np.asarray(fitted.T_instr_base0).tolist(),
        "T_flange_target0": np.asarray(fitted.T_flange_target0).tolist(),
        "residual_pos": fitted.residual_pos.tolist(),
        "residual_rot": None if fitted.residual_rot is None else fitted.residual_rot.tolist(),
        "stats": {
            "chi2": fitted.chi2,
            "chi2_data": fitted.chi2_data,
            "dof": fitted.dof,
            "bic": fitted.bic,
            "rms_pos": fitted.rms_pos,
            "rms_rot": fitted.rms_rot,
            "n_iter": fitted.n_iter,
            "converged": fitted.converged,
            "n_poses": fitted.n_poses,
        },
        "unidentifiable": list(fitted.unidentifiable),
        "held": list(fitted.held),
        "reference_time_s": getattr(fitted, "reference_time", None),
        "noise": {
            "sigma_pos": fitted.noise.sigma_pos,
            "sigma_rot": fitted.noise.sigma_rot,
            "sigma_q": fitted.noise.sigma_q,
            "excess_pos": fitted.noise.excess_pos,
            "excess_rot": fitted.noise.excess_rot,
            "band_factor": fitted.noise.band_factor,
        },
        "prior": {
            "joint_pos": fitted.prior.joint_pos,
            "joint_rot": fitted.prior.joint_rot,
            "setup_pos": fitted.prior.setup_pos,
            "setup_rot": fitted.prior.setup_rot,
        },
    }


def model_from_json(doc: dict[str, Any], name: str = "model.json") -> FittedModel:
    """A :class:`~quickhealth.identify.fit.FittedModel` from its JSON document."""

    if not isinstance(doc, dict) or doc.get("schema") != MODEL_SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(
            f"{name}: not a quickhealth model (schema {got!r}, expected {MODEL_SCHEMA!r})"
        )
    try:
        try:
            robot = robot_from_json(doc["robot"])
        except InputError as exc:
            raise InputError(f"{name}: model file is incomplete or damaged: {exc}") from None
        sp = doc["spec"]
        spec = ErrorModelSpec(np.asarray(sp["orders"], np.int64), sp["q_lo"], sp["q_hi"])
        effects = parse_effects([e["name"] for e in doc["effects"]], robot)
        st = doc["stats"]
        rr = doc.get("residual_rot")
        return FittedModel(
            robot=robot,
            spec=spec,
            coeffs=np.asarray(doc["coeffs"], float),
            cov=np.asarray(doc["cov"], float),
            effects=tuple(effects),
            effect_params=[np.asarray(e["params"], float) for e in doc["effects"]],
            T_instr_base0=np.asarray(doc["T_instr_base0"], float),
            T_flange_target0=np.asarray(doc["T_flange_target0"], float),
            residual_pos=np.asarray(doc["residual_pos"], float).reshape(-1, 3),
            residual_rot=None if rr is None else np.asarray(rr, float).reshape(-1, 3),
            chi2=float(st["chi2"]),
            chi2_data=float(st["chi2_data"]),
            dof=int(st["dof"]),
            bic=float(st["bic"]),
            rms_pos=float(st["rms_pos"]),
            rms_rot=None if st["rms_rot"] is None else float(st["rms_rot"]),
            n_iter=int(st["n_iter"]),
            converged=bool(st["converged"]),
            unidentifiable=tuple(doc["unidentifiable"]),
            noise=InstrumentNoise(**doc["noise"]),
            prior=ParameterPrior(**doc["prior"]),
            n_poses=int(st["n_poses"]),
            held=tuple(doc.get("held", ())),
            reference_time=(
                None if doc.get("reference_time_s") is None else float(doc["reference_time_s"])
            ),
        )
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        if isinstance(exc, InputError):
            raise
        what = " ".join(repr(exc).split())[:200]
        raise InputError(f"{name}: model file is incomplete or damaged: {what}") from None


def check_model(fm: FittedModel, name: str) -> None:
    """Meaning of a model: coefficient count, finite numbers, ranges, and a TCP correction a
    real robot can have (:func:`~quickhealth.identify.sanity.check_plausible`).

    Raises
    ------
    InputError
        One line naming the first offending entry.
    """
    spec = fm.spec
    robot = fm.robot
    check_robot(robot, name)
    nj = robot.n_joints
    if spec.orders.shape[0] < nj:
        raise InputError(
            f"{name}: the error model has orders for {spec.orders.shape[0]} joints, the robot has {nj}"
        )
    if np.any(spec.orders < 0) or np.any(spec.orders > 40):
        raise InputError(f"{name}: Chebyshev orders must be in 0..40")
    c = np.asarray(fm.coeffs, float)
    if c.ndim != 1 or c.size != spec.n_params:
        raise InputError(
            f"{name}: {c.size} coefficients, but the orders need {spec.n_params}: damaged model"
        )
    labels = spec.labels()
    bad = np.flatnonzero(~np.isfinite(c))
    if bad.size:
        raise InputError(
            f"{name}: coefficient {labels[bad[0]]} is {c[bad[0]]}, not a finite number"
        )
    if not (np.all(np.isfinite(spec.q_lo)) and np.all(np.isfinite(spec.q_hi))):
        raise InputError(f"{name}: the model's joint ranges are not finite numbers")
    if (
        np.any(spec.q_hi <= spec.q_lo)
        or np.any(spec.q_lo < robot.q_min - 1e-6)
        or np.any(spec.q_hi > robot.q_max + 1e-6)
    ):
        raise InputError(
            f"{name}: the model's identified joint ranges are empty or outside the robot's limits"
        )
    cov = np.asarray(fm.cov, float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] < c.size:
        raise InputError(
            f"{name}: the covariance has shape {cov.shape}, expected square >= {c.size}"
        )
    if not np.all(np.isfinite(cov)):
        raise InputError(f"{name}: the covariance holds numbers that are not finite")
    for e, prm in zip(fm.effects, fm.effect_params, strict=True):
        if not np.all(np.isfinite(prm)):
            raise InputError(f"{name}: effect {e.name} has parameters that are not finite")
    for key in ("T_instr_base0", "T_flange_target0"):
        T = np.asarray(getattr(fm, key), float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"{name}: {key} is not a finite 4x4 transform")
    # meaning: the TCP correction a real robot can have, judged after registering base and
    # tool (never on coefficients, which depend on the gauge and the Chebyshev ranges)
    try:
        check_plausible(fm, name)
    except InputError as exc:
        raise InputError(f"{exc}: refusing the model") from None


def write_model(path: str | os.PathLike[str], fitted: FittedModel) -> None:
    """Write model.json (JSON only; never pickle), with the writer's ``provenance``."""

    doc = {**model_to_json(fitted), "provenance": provenance()}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def valid_model(doc: Any, name: str) -> FittedModel:
    """The model of a parsed model.json, validated: the one check every reader applies
    (``predict``, ``report``, ``reprocess``, ``trend``, ``compensate`` …: :func:`read_model`;
    structure, finite numbers, ranges, a believable TCP correction: :func:`check_model`).
    Keys the schema does not know are ignored and not kept.

    Raises
    ------
    InputError
        One line naming ``name`` and the first problem.
    """
    try:
        fm = model_from_json(doc, name)
        check_model(fm, name)
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(name) else f"{name}: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - any other failure to interpret it: damaged
        what = " ".join(repr(exc).split())[:200]
        raise InputError(f"{name}: model file is incomplete or damaged: {what}") from None
    return fm


def read_model(path: str | os.PathLike[str]) -> FittedModel:
    """Read model.json back into a validated FittedModel (:func:`valid_model`)."""
    p = Path(path)
    # binary files (e.g. a pickle) are refused as not UTF-8: never loaded as code; a file
    # whose JSON would parse into more values than any model has is refused before parsing
    return valid_model(load_json_limited(p, "model"), str(p))
