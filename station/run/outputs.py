"""A run folder's results from its journal: measurements.csv, run.json, calibration.json."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ...identify.measurements import Measurements
from ...identify.transforms import log_so3
from ..formats.common import write_text_atomic
from ..formats.journal import SelfCheck
from ..formats.measurements import write_measurements
from ..formats.vision import rig_to_json
from ..station import Station
from .journal import JournalState, write_bytes_atomic
from .settings import RunSettings
from .timing import overlap

if TYPE_CHECKING:  # types only: the planner loads the collision library
    from ..planning.planfile import Plan


CALIBRATION = "calibration.json"


def write_calibration(station: Station, run_dir: Path) -> None:
    """The run folder's ``calibration.json``: the stereo calibration of the cameras that take
    its images (the simulated cell's scaled cameras too), so ``quickhealth vision measure
    RUN`` measures the stored images again with the cameras that took them.  A folder that
    already has one (a resumed run) keeps it."""
    cal = run_dir / CALIBRATION
    rig = getattr(station.camera, "rig", None)
    if rig is None or cal.exists():
        return
    doc = rig_to_json(rig, note=f"the cameras of this run: {station.instrument}")
    write_bytes_atomic(cal, (json.dumps(doc, indent=1) + "\n").encode("utf-8"))


def selfcheck_drift(checks: list[SelfCheck]) -> tuple[float, float] | None:
    """The self-check board's drift between the first and the last good check (mm, deg: the
    run's result and run.json give it so)."""
    ok = [c.T_instr_board for c in checks if c.ok and c.T_instr_board is not None]
    if len(ok) < 2:
        return None
    A, B = ok[0], ok[-1]
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3])) * 1e3
    da = float(np.degrees(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T))))
    return dp, da


def journal_measurements(
    state: JournalState, plan: Plan | None, meta: dict[str, str], *, order: str = "plan"
) -> Measurements | None:
    """The measured poses of a journal as :class:`Measurements`, in execution order: plan
    order (a run of the loop), or with ``order="capture"`` the order the journal recorded
    the captures in (a run whose sequence chose its poses, :class:`PoseSequence`)."""
    ok = [i for i, m in state.measured.items() if m.ok and i in state.captured]
    if order == "capture":
        rank = {i: k for k, i in enumerate(state.captured)}
        idx = sorted(ok, key=rank.__getitem__)
    else:
        idx = sorted(ok)
    if not idx:
        return None
    cap = [state.captured[i] for i in idx]
    mea = [state.measured[i] for i in idx]

    def per_joint(
        attr: str,
    ) -> NDArray[np.float64] | None:  # every pose's, or none (a resumed older journal)
        rows = [getattr(c, attr) for c in cap]
        if any(r is None or np.shape(r) != np.shape(cap[0].q) for r in rows):
            return None
        return np.array(rows, dtype=float)

    return Measurements(
        q=np.array([c.q for c in cap]),
        pos=np.array([m.position for m in mea]),
        rpy=np.array([m.rpy for m in mea]),
        time=np.array([c.time_s for c in cap]),
        pan=np.array([c.pan for c in cap]),
        joint_temp=per_joint("joint_temp"),
        joint_torque=per_joint("joint_torque"),
        sigma_pos=np.array([m.sigma_pos for m in mea]),
        sigma_rpy=np.array([m.sigma_rpy for m in mea]),
        pose_id=tuple(c.name for c in cap),
        meta=meta,
    )


def write_outputs(
    run_dir: Path,
    state: JournalState,
    plan: Plan,
    station: Station,
    drift: tuple[float, float] | None,
    settings: RunSettings,
    *,
    order: str = "plan",
) -> Path | None:
    """measurements.csv and run.json from the journal (atomic writes); ``order`` as
    :func:`journal_measurements`."""
    start = state.start or {}
    meta = {
        "run_id": str(start.get("run_id", run_dir.name)),
        "robot": str(start.get("robot", "")),
        "instrument": str(start.get("instrument", "")),
        "cell": str(start.get("cell", "")),
        "plan_hash": str(start.get("plan_hash", "")),
        "started_utc": str(start.get("started_utc", "")),
        "frame": "target frame at pan 0 (plan convention), instrument = left camera",
    }
    if isinstance(start.get("spec_mm"), int | float):  # the cell's accuracy spec, if it has one
        meta["spec_mm"] = f"{float(start['spec_mm']):g}"
    if drift is not None:
        meta["selfcheck_drift_mm"] = f"{drift[0]:.4f}"
        meta["selfcheck_drift_deg"] = f"{drift[1]:.5f}"
    meas = journal_measurements(state, plan, meta, order=order)
    path = None
    if meas is not None:
        path = run_dir / "measurements.csv"
        write_measurements(path, meas)
    summary = {
        "schema": "quickhealth.run/1",
        **meta,
        "n_poses": len(plan.poses),
        "n_captured": len(state.captured),
        "n_measured": 0 if meas is None else meas.n_poses,
        "failed": [
            {"index": i, "name": f.name, "reason": f.reason}
            for i, f in sorted(state.failed.items())
        ]
        + [
            {"index": i, "name": m.name, "reason": m.reason}
            for i, m in sorted(state.measured.items())
            if not m.ok
        ],
        "stopped": state.stops[-1]["reason"] if state.stops and not state.ended else None,
        "complete": state.ended,
        "resumes": state.resumes,
        "cameras": start.get("cameras", []),
        "timing": overlap(state),
        "selfcheck": {
            "drift_mm": None if drift is None else drift[0],
            "drift_deg": None if drift is None else drift[1],
            "limit_mm": settings.selfcheck_limit_mm,
            "limit_deg": settings.selfcheck_limit_deg,
            "ok": None
            if drift is None
            else drift[0] <= settings.selfcheck_limit_mm
            and drift[1] <= settings.selfcheck_limit_deg,
        },
    }
    write_text_atomic(run_dir / "run.json", json.dumps(summary, indent=1) + "\n")
    return path
