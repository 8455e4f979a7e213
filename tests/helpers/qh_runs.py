"""Run folders of a simulated robot for the archive, report and reprocessing tests.

The robot is the digital twin (one seed: the same robot every run); each run measures it
with fresh noise, fits the error model at fixed orders and writes what the station writes:
measurements.csv, model.json, report.json, plan.json and run.json.  Imported as ``qh_runs``
(tests/helpers is on the test path).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.twin import make_twin, random_joints, twin_from_truth
from quickhealth.identify.workspace import all_joint_curves, workspace_error
from quickhealth.station import formats

NOISE = InstrumentNoise(sigma_pos=3e-5, sigma_rot=1e-4)


def make_run(
    folder: Path,
    run_seed: int,
    *,
    n_poses: int = 40,
    repeats: int = 0,
    degrade: dict[str, float] | None = None,
    time_utc: str = "2026-01-01T08:00:00Z",
    meta: dict[str, str] | None = None,
    order: int = 1,
    light: bool = False,
    effects: dict[str, float] | None = None,
) -> Path:
    """Write one run folder; ``degrade`` adds to true coefficients (e.g. ``{"j2.ex.c0": 3e-4}``).

    ``repeats`` > 0 visits the first 5 poses that many extra times (ISO 9283 repeatability).
    ``light``: a smaller workspace sample and no joint curves in report.json (fast fleets).
    ``effects``: physical effects hidden in this run's robot (SI sizes, :func:`make_twin`), not
    in its fitted model (the diagnosis then has a candidate that matters).
    """
    twin = make_twin(seed=1, position_dependent=False, effects=effects)
    if degrade:
        labels = twin.truth.spec.labels()
        c = twin.truth.coeffs.copy()
        for k, v in degrade.items():
            c[labels.index(k)] += v
        twin = twin_from_truth(replace(twin.truth, coeffs=c), twin.robot)
    q = random_joints(twin.robot, n_poses, seed=7, T_instr_base=twin.truth.T_instr_base)
    ids = [f"P{i:03d}" for i in range(n_poses)]
    if repeats:
        q = np.concatenate([q] + [q[:5]] * repeats)
        ids = ids + [f"P{i:03d}" for _ in range(repeats) for i in range(5)]
    meas = twin.measure(q, seed=1000 + run_seed)
    meas = replace(meas, pose_id=tuple(ids))
    spec = ErrorModelSpec.uniform(6, order, twin.robot.q_min, twin.robot.q_max)
    fitted = fit_model(twin.robot, meas, spec, noise=NOISE)
    folder.mkdir(parents=True, exist_ok=True)
    formats.write_measurements(folder / "measurements.csv", meas)
    formats.write_model(folder / "model.json", fitted)
    ws = workspace_error(fitted, n_samples=500 if light else 2000)
    curves = [] if light else [c.as_dict() for c in all_joint_curves(fitted, n_points=31)]
    # a version 1 report: the archive's figures, not every key of version 2 (labelled /2 it
    # would claim keys it lacks, and `quickhealth report` refuses that)
    report = {
        "schema": "quickhealth.report/1",
        "n_poses": fitted.n_poses,
        "n_params": fitted.n_free,
        "bic": fitted.bic,
        "chi2": fitted.chi2_data,
        "rms_pos_mm": fitted.rms_pos * 1e3,
        "converged": fitted.converged,
        "robot": "ur5",
        "summary": fitted.summary(),
        "workspace": ws.as_dict(),
        "joint_curves": curves,
    }
    (folder / "report.json").write_text(json.dumps(report, default=_plain, indent=1))
    plan = {
        "plan_hash": (meta or {}).get("plan_hash", "plan-a"),
        "poses": [{"q_deg": np.degrees(r).tolist(), "leg": "joint"} for r in q],
        "dropped": [],
    }
    (folder / "plan.json").write_text(json.dumps(plan))
    run = {"time_utc": time_utc, "cell": "reference", "calibration_id": "cal-1", **(meta or {})}
    (folder / "run.json").write_text(json.dumps(run))
    return folder


def measurements(folder: Path) -> Measurements:
    return formats.read_measurements(folder / "measurements.csv", 6)


def _plain(x):  # numpy scalars in a report
    return x.item() if hasattr(x, "item") else str(x)
