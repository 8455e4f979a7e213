"""plan.json: the frozen plan, its content hash, and validated loading.

Schema ``quickhealth.plan/1`` (docs/plan.md).  The ``hash`` is ``"sha256:" + hex`` of the
canonical JSON (sorted keys, no spaces, UTF-8) of the document without its ``hash`` key; it
identifies the frozen plan, and :func:`load_plan` refuses a file whose content no longer
matches it.  Units at this boundary: mm, degrees, seconds.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import RobotModel
from ...identify.transforms import R_to_rpy, exp_so3, log_so3, make_T
from ..hardware.legs import Leg
from .cell import ROBOTS, Motion
from .planner import DropReason, PlanResult

F = NDArray[np.float64]
SCHEMA = "quickhealth.plan/1"
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}")
HASH_RE = re.compile(r"sha256:[0-9a-f]{64}")
COVERAGE_CRITERION = (
    "coverage = part of the joint's usable range (central 95 % of the joint's values over every"
    " feasible IK configuration of every candidate target) inside the span of the kept poses"
)
EVENNESS_CRITERION = (
    "evenness = Shannon entropy of the kept poses' histogram over the usable range"
    " ({bins} bins) divided by log(bins); 1 = uniform"
)
SELECTION_CRITERION = (
    "per pose choose the feasible configuration and leg with the lowest"
    " sum_j (h_j(bin_j(q)) + 1) / (k/B + 1) - linear_preference*[linear leg]"
)


@dataclass(frozen=True, eq=False)
class PlanPose:
    """One pose of a loaded plan (SI)."""

    name: str
    index: int  # 1-based position in the loop
    q: F  # (6,) rad
    leg: Leg
    pan: float  # rad
    T_base_target: F  # (4, 4), m
    candidate: int


@dataclass(frozen=True, eq=False)
class Plan:
    """A validated plan file (see :func:`load_plan`)."""

    hash: str
    source: str
    cell_name: str
    cell_sha256: str
    robot: RobotModel  # with the plan's joint limits
    poses: tuple[PlanPose, ...]
    return_leg: Leg
    motion: Motion
    T_flange_target: F
    T_world_base: F
    dropped: tuple[dict[str, Any], ...]
    summary: dict[str, Any]
    document: dict[str, Any]
    home: F | None = None  # (6,) rad, the checked start of the loop

    @property
    def q(self) -> F:
        """Joint targets in loop order, (k, 6), rad."""
        return np.array([p.q for p in self.poses])


def content_hash(doc: dict[str, Any]) -> str:
    """``sha256:`` of the canonical JSON of ``doc`` without its ``hash`` key."""
    body = {k: v for k, v in doc.items() if k != "hash"}
    s = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return "sha256:" + hashlib.sha256(s.encode("utf-8")).hexdigest()


def _r(x: Any, nd: int = 6) -> Any:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        return round(float(a), nd)
    return [_r(v, nd) for v in a]


def _T_mm(T: F) -> list[list[float]]:
    M = np.array(T, dtype=float)
    M[:3, 3] *= 1000.0
    return _r(M, 9)  # type: ignore[no-any-return]


def plan_to_dict(res: PlanResult) -> dict[str, Any]:
    """The plan document (mm/deg), with its content hash."""
    cell = res.cell
    m = cell.motion
    c = res.coverage
    poses = []
    for j, p in enumerate(res.poses):
        poses.append(
            {
                "name": p.name or f"P{j + 1:03d}",
                "index": j + 1,
                "candidate": p.candidate,
                "q_deg": _r(np.degrees(p.q), 9),
                "leg": p.leg.value,
                "branch": p.branch,
                "target_base_mm": _r(p.T_base_target[:3, 3] * 1000.0),
                "target_base_rpy_deg": _r(np.degrees(R_to_rpy(p.T_base_target[:3, :3])), 9),
                "target_base_rotvec_deg": _r(np.degrees(log_so3(p.T_base_target[:3, :3])), 9),
                "target_world_mm": _r(p.T_world_target[:3, 3] * 1000.0),
                "pan_deg": _r(math.degrees(p.pan)),
                "facing_deg": _r(np.degrees(p.facing), 3),
                "pixels_left": _r(p.pixels[0], 1),
                "pixels_right": _r(p.pixels[1], 1),
                "leg_time_s": _r(p.leg_time_s, 3),
            }
        )
    n_lin = sum(p.leg == Leg.LINEAR for p in res.poses[1:])
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "cell": {"name": cell.name, "source": cell.source, "sha256": cell.sha256},
        "robot": {
            "model": cell.robot.name,
            "q_min_deg": _r(np.degrees(cell.robot.q_min), 9),
            "q_max_deg": _r(np.degrees(cell.robot.q_max), 9),
            "home_deg": None if res.home is None else _r(np.degrees(res.home), 9),
        },
        "seed": res.seed,
        "n_generated": res.n_generated,
        "frames": {
            "T_world_base_mm": _T_mm(cell.T_world_base),
            "T_flange_target_mm": _T_mm(cell.T_flange_target),
            "T_world_cam_left_mm": _T_mm(cell.T_world_cam_left),
            "T_world_cam_right_mm": _T_mm(cell.T_world_cam_right),
            "pan": "T_flange_target(pan) = T_flange_target · Ry(pan)",
        },
        "motion": {
            "linear_speed_mm_s": _r(m.linear_speed * 1000.0),
            "linear_accel_mm_s2": _r(m.linear_accel * 1000.0),
            "joint_speed_deg_s": _r(math.degrees(m.joint_speed)),
            "joint_accel_deg_s2": _r(math.degrees(m.joint_accel)),
            "settle_s": _r(m.settle_s),
            "handshake_register": m.handshake_register,
            "measure_timeout_s": _r(m.measure_timeout_s),
            "passes": m.passes,
        },
        "poses": poses,
        "return_leg": res.return_leg.value,
        "return_leg_time_s": _r(res.return_leg_time_s, 3),
        "dropped": [
            {
                "candidate": d.candidate,
                "reason": d.reason.value,
                "detail": d.detail,
                "target_world_mm": _r(d.T_world_target[:3, 3] * 1000.0),
            }
            for d in res.dropped
        ],
        "summary": {
            "generated": res.n_generated,
            "kept": len(res.poses),
            "dropped": res.dropped_by_reason,
            "legs": {
                "linear": n_lin,
                "joint": len(res.poses) - 1 - n_lin,
                "return": res.return_leg.value,
            },
            "loop_time_s": _r(res.loop_time_s, 1),
            "joints": {
                "coverage_criterion": COVERAGE_CRITERION,
                "evenness_criterion": EVENNESS_CRITERION.format(bins=c.bins),
                "selection_criterion": SELECTION_CRITERION,
                "bins": c.bins,
                "usable_min_deg": _r(np.degrees(c.usable_min), 3),
                "usable_max_deg": _r(np.degrees(c.usable_max), 3),
                "kept_min_deg": _r(np.degrees(c.kept_min), 3),
                "kept_max_deg": _r(np.degrees(c.kept_max), 3),
                "coverage": _r(c.coverage, 4),
                "evenness": _r(c.evenness, 4),
                "occupied_bins": _r(c.occupied, 4),
                "feasible_min_deg": _r(np.degrees(c.feasible_min), 3),
                "feasible_max_deg": _r(np.degrees(c.feasible_max), 3),
                "coverage_of_feasible_extremes": _r(c.coverage_full, 4),
            },
            **({} if res.design is None else {"design": res.design}),
        },
    }
    doc["hash"] = content_hash(doc)
    return doc


def dumps(doc: dict[str, Any]) -> str:
    """The plan document as indented JSON text (hash unchanged: it is over canonical JSON)."""
    return json.dumps(doc, indent=1, ensure_ascii=False, allow_nan=False) + "\n"


def plan_joints(path: str | Path) -> F | None:
    """The commanded joints of a plan.json (rad, plan order), None when the file is missing or
    holds no poses; for reading a run's plan without validating it whole (the report)."""
    p = Path(path)
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    poses = doc.get("poses") if isinstance(doc, dict) else None
    if not isinstance(poses, list) or not poses:
        return None
    return np.radians(np.array([q["q_deg"] for q in poses], dtype=float))


def load_plan(path: str | Path) -> Plan:
    """Load and validate a plan file.

    Checks the schema, every number (finite, in range), pose names (identifiers only: a
    name can never carry code into the URScript), leg types, joint targets inside the
    plan's and the robot's limits, the target poses against forward kinematics, and the
    content hash.

    Raises
    ------
    InputError
        One line ``file: key: what``.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{p}: cannot read plan file ({exc.strerror})") from None
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as exc:
        raise InputError(f"{p}: not a JSON plan file: {exc}") from None
    return plan_from_dict(doc, str(p))


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not allowed")


def _err(label: str, key: str, what: str) -> InputError:
    return InputError(f"{label}: {key}: {what}")


def _num(label: str, key: str, v: object, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise _err(label, key, f"expected a finite number, got {v!r:.40}")
    if not lo <= v <= hi:
        raise _err(label, key, f"{v:g} outside [{lo:g}, {hi:g}]")
    return float(v)


def _int(label: str, key: str, v: object, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise _err(label, key, f"expected an integer in [{lo}, {hi}], got {v!r:.40}")
    return int(v)


def _vec(label: str, key: str, v: object, n: int) -> F:
    if not isinstance(v, list) or len(v) != n:
        raise _err(label, key, f"expected a list of {n} numbers")
    return np.array([_num(label, f"{key}[{i}]", x) for i, x in enumerate(v)])


def _mat(label: str, key: str, v: object) -> F:
    if not isinstance(v, list) or len(v) != 4:
        raise _err(label, key, "expected a 4×4 matrix")
    M = np.array([_vec(label, f"{key}[{i}]", r, 4) for i, r in enumerate(v)])
    M[:3, 3] /= 1000.0
    R = M[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or not np.allclose(M[3], [0, 0, 0, 1]):
        raise _err(label, key, "not a rigid transform")
    return M


def _obj(label: str, key: str, v: object) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise _err(label, key, "expected an object")
    return v


def plan_from_dict(doc: object, label: str = "plan") -> Plan:
    """Validate a plan document (as parsed from JSON) into a :class:`Plan`; see :func:`load_plan`."""
    doc = _obj(label, "(top)", doc)
    if doc.get("schema") != SCHEMA:
        raise _err(label, "schema", f"expected {SCHEMA!r}, got {str(doc.get('schema'))[:40]!r}")
    h = doc.get("hash")
    if not isinstance(h, str) or not HASH_RE.fullmatch(h):
        raise _err(label, "hash", "missing or not 'sha256:' and 64 hex digits")
    cell = _obj(label, "cell", doc.get("cell"))
    cname = cell.get("name")
    if not isinstance(cname, str) or not re.fullmatch(r"[A-Za-z0-9_\-]{1,64}", cname):
        raise _err(label, "cell.name", "missing or not a plain name")
    csha = cell.get("sha256")
    if not isinstance(csha, str) or not re.fullmatch(r"[0-9a-f]{64}", csha):
        raise _err(label, "cell.sha256", "missing or not 64 hex digits")
    robot, home = _robot(label, _obj(label, "robot", doc.get("robot")))
    fr = _obj(label, "frames", doc.get("frames"))
    T_ft = _mat(label, "frames.T_flange_target_mm", fr.get("T_flange_target_mm"))
    T_wb = _mat(label, "frames.T_world_base_mm", fr.get("T_world_base_mm"))
    motion = _motion(label, _obj(label, "motion", doc.get("motion")))
    poses = _poses(label, doc.get("poses"), robot, T_ft)
    ret = doc.get("return_leg")
    if ret not in ("linear", "joint"):
        raise _err(label, "return_leg", f"expected 'linear' or 'joint', got {str(ret)[:40]!r}")
    dropped = _dropped(label, doc.get("dropped", []))
    summary = _obj(label, "summary", doc.get("summary", {}))
    if content_hash(doc) != h:
        raise _err(
            label, "hash", "content does not match its hash (the plan was edited after planning)"
        )
    return Plan(
        hash=h,
        source=label,
        cell_name=cname,
        cell_sha256=csha,
        robot=robot,
        poses=tuple(poses),
        return_leg=Leg(ret),
        motion=motion,
        T_flange_target=T_ft,
        T_world_base=T_wb,
        dropped=tuple(dropped),
        summary=summary,
        document=doc,
        home=home,
    )


def _robot(label: str, rob: dict[str, Any]) -> tuple[RobotModel, F | None]:
    """The plan's robot with its planning limits, and its home (rad)."""
    model = rob.get("model")
    if not isinstance(model, str) or model not in ROBOTS:
        raise _err(
            label, "robot.model", f"unknown robot {str(model)[:40]!r} (known: {', '.join(ROBOTS)})"
        )
    robot = ROBOTS[model]()
    qlo = np.radians(_vec(label, "robot.q_min_deg", rob.get("q_min_deg"), robot.n_joints))
    qhi = np.radians(_vec(label, "robot.q_max_deg", rob.get("q_max_deg"), robot.n_joints))
    if np.any(qlo < robot.q_min - 1e-9) or np.any(qhi > robot.q_max + 1e-9) or np.any(qhi <= qlo):
        raise _err(label, "robot.q_min_deg", f"limits outside the {model}'s own or empty")
    robot = replace(robot, q_min=qlo, q_max=qhi)
    home = None
    if rob.get("home_deg") is not None:
        home = np.radians(_vec(label, "robot.home_deg", rob.get("home_deg"), robot.n_joints))
        if np.any(home < qlo - 1e-9) or np.any(home > qhi + 1e-9):
            raise _err(label, "robot.home_deg", "outside the joint limits")
    return robot, home


def _motion(label: str, mo: dict[str, Any]) -> Motion:
    """The plan's motion settings (SI)."""
    reg = _int(label, "motion.handshake_register", mo.get("handshake_register"), 0, 47)
    if 0 < reg < 24:
        raise _err(label, "motion.handshake_register", "must be 0 or 24-47")

    def num(key: str, lo: float, hi: float) -> float:
        return _num(label, f"motion.{key}", mo.get(key), lo, hi)

    return Motion(
        linear_speed=num("linear_speed_mm_s", 1.0, 1000.0) / 1000.0,
        linear_accel=num("linear_accel_mm_s2", 1.0, 5000.0) / 1000.0,
        joint_speed=math.radians(num("joint_speed_deg_s", 1.0, 180.0)),
        joint_accel=math.radians(num("joint_accel_deg_s2", 1.0, 800.0)),
        settle_s=num("settle_s", 0.0, 60.0),
        handshake_register=reg,
        measure_timeout_s=num("measure_timeout_s", 0.1, 3600.0),
        passes=_int(label, "motion.passes", mo.get("passes"), 1, 100),
    )


def _poses(label: str, raw_poses: object, robot: RobotModel, T_ft: F) -> list[PlanPose]:
    """The plan's poses, each checked: a unique name, joints inside the limits, a leg, a pan
    angle, and a target the joints reach."""
    if not isinstance(raw_poses, list) or not raw_poses:
        raise _err(label, "poses", "expected a non-empty list")
    qlo, qhi = robot.q_min, robot.q_max
    poses = []
    names: set[str] = set()
    for j, rp in enumerate(raw_poses):
        key = f"poses[{j}]"
        rp = _obj(label, key, rp)
        name = rp.get("name")
        if not isinstance(name, str) or not NAME_RE.fullmatch(name):
            raise _err(
                label,
                f"{key}.name",
                f"{str(name)[:40]!r} is not a plain identifier (letters, digits, _; ≤ 32)",
            )
        if name in names:
            raise _err(label, f"{key}.name", f"duplicate pose name {name!r}")
        names.add(name)
        q = np.radians(_vec(label, f"{key}.q_deg", rp.get("q_deg"), robot.n_joints))
        if np.any(q < qlo - 1e-9) or np.any(q > qhi + 1e-9):
            jbad = int(np.flatnonzero((q < qlo - 1e-9) | (q > qhi + 1e-9))[0])
            raise _err(
                label,
                f"{key}.q_deg[{jbad}]",
                f"{math.degrees(q[jbad]):g}° outside the joint limits",
            )
        leg = rp.get("leg")
        if leg not in ("linear", "joint"):
            raise _err(label, f"{key}.leg", f"expected 'linear' or 'joint', got {str(leg)[:40]!r}")
        pan = math.radians(_num(label, f"{key}.pan_deg", rp.get("pan_deg"), -180.0, 180.0))
        pos = _vec(label, f"{key}.target_base_mm", rp.get("target_base_mm"), 3) / 1000.0
        _vec(label, f"{key}.target_base_rpy_deg", rp.get("target_base_rpy_deg"), 3)
        rv = _vec(label, f"{key}.target_base_rotvec_deg", rp.get("target_base_rotvec_deg"), 3)
        T_bt = make_T(exp_so3(np.radians(rv)), pos)
        T_fk = robot.fk(q) @ T_ft
        if (
            np.linalg.norm(T_fk[:3, 3] - pos) > 1e-5
            or np.linalg.norm(T_fk[:3, :3] - T_bt[:3, :3]) > 1e-5
        ):
            raise _err(
                label,
                f"{key}.q_deg",
                "joint target does not reach target_base_mm / target_base_rotvec_deg",
            )
        cand = _int(label, f"{key}.candidate", rp.get("candidate", -1), -1, 10**7)
        poses.append(PlanPose(name, j + 1, q, Leg(leg), pan, T_bt, cand))
    return poses


def _dropped(label: str, dropped: object) -> list[object]:
    """The plan's dropped candidates, each with a known reason."""
    if not isinstance(dropped, list):
        raise _err(label, "dropped", "expected a list")
    reasons = {r.value for r in DropReason}
    for j, d in enumerate(dropped):
        d = _obj(label, f"dropped[{j}]", d)
        if d.get("reason") not in reasons:
            raise _err(
                label, f"dropped[{j}].reason", f"unknown reason {str(d.get('reason'))[:40]!r}"
            )
    return dropped
