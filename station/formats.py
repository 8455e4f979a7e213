"""Files of the identification: measurement CSV v1, model.json, report.json, robot descriptions.

Every unit conversion between the file boundary (mm, degrees) and the library (m, rad)
happens here, once.  Every bad input raises :class:`InputError` with one line
``file:line:column: what`` (line and column 1-based; column = the CSV column).

Robot descriptions (``--robot``)
--------------------------------
- a built-in name: ``ur5``;
- a DH table file ``*.toml`` (format below);
- a URDF file ``*.urdf``, read through pinocchio (revolute joints, any axis).

DH table format (TOML)::

    [robot]
    name = "wam"
    convention = "dh"        # "dh": A_i = Rz(θ_i+o_i) Tz(d_i) Tx(a_i) Rx(α_i)
                             # "mdh" (Craig): A_i = Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i+o_i) Tz(d_i),
                             #   row i holds a_{i-1}, α_{i-1}, d_i
    length_unit = "mm"       # "mm" or "m"
    angle_unit = "deg"       # "deg" or "rad"

    [[joint]]                # one table per joint, base to flange
    name = "j1"
    a = 0.0
    d = 0.0
    alpha = -90.0
    theta_offset = 0.0       # optional
    q_min = -150.0           # optional (default ±360°)
    q_max = 150.0
    mass = 3.7               # optional, kg (all joints or none)
    com = [0.0, -25.6, 1.9]  # optional, length unit, in DH frame i
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.errors import InputError
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import RobotModel, from_dh, ur5

F = NDArray[np.float64]

MODEL_SCHEMA = "quickhealth.model/1"
REPORT_SCHEMA = "quickhealth.report/2"  # station/report_json.py; /1 files still read
REPORT_SCHEMAS_READ = ("quickhealth.report/1", REPORT_SCHEMA)
BUILTIN_ROBOTS = {"ur5": ur5}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")

OPTIONAL_COLUMNS = (
    "pitch",
    "yaw",
    "roll",
    "time",
    "temp",
    "pan",
    "sx",
    "sy",
    "sz",
    "spitch",
    "syaw",
    "sroll",
    "pose_id",
)


# --------------------------------------------------------------------------- CSV v1


def read_measurements(
    path: str | os.PathLike[str],
    n_joints: int | None = None,
    *,
    joints_only: bool = False,
) -> Measurements:
    """Read a measurement file (CSV v1, CONTRACTS.md) into SI :class:`Measurements`.

    Parameters
    ----------
    n_joints : int, optional
        Joint count of the robot; ``q1 … qN`` are then required.  Without it the joint columns
        present (consecutive from ``q1``) are used.
    joints_only : bool
        Accept a file of joint commands without ``x, y, z`` (``pos`` is then NaN).

    Raises
    ------
    InputError
        ``file:line:column: what`` for a missing file, missing or duplicate column, a cell
        that is not a finite number, angles that look like radians, a ragged row.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read: {exc}") from None
    return parse_measurements(text, str(p), n_joints, joints_only=joints_only)


def parse_measurements(
    text: str, name: str = "<text>", n_joints: int | None = None, *, joints_only: bool = False
) -> Measurements:
    """:func:`read_measurements` on the file's text (``name`` is used in messages)."""
    meta: dict[str, str] = {}
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = re.match(r"#\s*([^:]+?)\s*:\s*(.*)$", s)
            if m:
                meta[m.group(1)] = m.group(2).strip()
            continue
        cells = [c.strip() for c in next(csv.reader([line]))]
        if header is None:
            header, header_line = cells, lineno
        else:
            rows.append((lineno, cells))
    if header is None:
        raise InputError(f"{name}:1:1: no header row (expected columns q1…qN, x, y, z)")
    col: dict[str, int] = {}
    for j, h in enumerate(header):
        if not h:
            raise InputError(f"{name}:{header_line}:{j + 1}: empty column name in the header")
        if h in col:
            raise InputError(
                f"{name}:{header_line}:{j + 1}: duplicate column {h!r} (also column {col[h] + 1})"
            )
        col[h] = j
    if n_joints is None:
        n_joints = 0
        while f"q{n_joints + 1}" in col:
            n_joints += 1
        if n_joints == 0:
            raise InputError(f"{name}:{header_line}:1: missing column 'q1' (joint readings, deg)")
    required = [f"q{i + 1}" for i in range(n_joints)]
    if not joints_only:
        required += ["x", "y", "z"]
    for c in required:
        if c not in col:
            raise InputError(
                f"{name}:{header_line}:{len(header) + 1}: missing column {c!r} "
                f"(required: {', '.join(required)})"
            )
    extra_q = f"q{n_joints + 1}"
    if extra_q in col:
        raise InputError(
            f"{name}:{header_line}:{col[extra_q] + 1}: column {extra_q!r}, but the robot has "
            f"{n_joints} joints"
        )
    for group in (("pitch", "yaw", "roll"), ("sx", "sy", "sz"), ("spitch", "syaw", "sroll")):
        present = [g for g in group if g in col]
        if present and len(present) != 3:
            missing = [g for g in group if g not in col]
            raise InputError(
                f"{name}:{header_line}:{col[present[0]] + 1}: column {present[0]!r} needs "
                f"{', '.join(repr(m) for m in missing)} too"
            )
    if not rows:
        raise InputError(f"{name}:{header_line + 1}:1: no data rows")
    for lineno, cells in rows:
        if len(cells) != len(header):
            raise InputError(
                f"{name}:{lineno}:{min(len(cells), len(header)) + 1}: row has {len(cells)} "
                f"cells, the header has {len(header)}"
            )

    def numbers(c: str, positive: bool = False) -> F:
        j = col[c]
        out = np.empty(len(rows))
        for i, (lineno, cells) in enumerate(rows):
            cell = cells[j]
            try:
                v = float(cell)
            except ValueError:
                what = "empty cell" if cell == "" else f"{cell!r} is not a number"
                raise InputError(f"{name}:{lineno}:{j + 1}: column {c!r}: {what}") from None
            if not math.isfinite(v):
                raise InputError(f"{name}:{lineno}:{j + 1}: column {c!r}: {cell} is not finite")
            if positive and v <= 0:
                raise InputError(
                    f"{name}:{lineno}:{j + 1}: column {c!r}: uncertainty {cell} must be > 0"
                )
            out[i] = v
        return out

    def looks_like_radians(cols: Sequence[str], what: str, spread: float) -> None:
        vals = np.stack([numbers(c) for c in cols], axis=1)
        amax = np.abs(vals).max()
        if len(rows) >= 3 and amax <= 2 * math.pi + 1e-6 and np.ptp(vals, axis=0).max() > spread:
            i, j = np.unravel_index(np.argmax(np.abs(vals)), vals.shape)
            raise InputError(
                f"{name}:{rows[i][0]}:{col[cols[j]] + 1}: {what} look like radians (every "
                f"|value| <= {amax:.2f}); the file needs degrees"
            )

    qcols = [f"q{i + 1}" for i in range(n_joints)]
    looks_like_radians(qcols, "joint angles", 0.2)
    q = np.radians(np.stack([numbers(c) for c in qcols], axis=1))
    if joints_only and "x" not in col:
        pos = np.full((len(rows), 3), np.nan)
    else:
        pos = np.stack([numbers(c) for c in ("x", "y", "z")], axis=1) * 1e-3
    rpy = None
    if "pitch" in col:
        looks_like_radians(("pitch", "yaw", "roll"), "orientation angles", 1.0)
        rpy = np.radians(np.stack([numbers(c) for c in ("pitch", "yaw", "roll")], axis=1))
    sig_pos = (
        np.stack([numbers(c, True) for c in ("sx", "sy", "sz")], axis=1) * 1e-3
        if "sx" in col
        else None
    )
    sig_rpy = (
        np.radians(np.stack([numbers(c, True) for c in ("spitch", "syaw", "sroll")], axis=1))
        if "spitch" in col
        else None
    )
    if sig_rpy is not None and rpy is None:
        raise InputError(
            f"{name}:{header_line}:{col['spitch'] + 1}: angle uncertainties without angle columns"
        )
    pose_id = tuple(cells[col["pose_id"]] for _, cells in rows) if "pose_id" in col else None
    return Measurements(
        q=q,
        pos=pos,
        rpy=rpy,
        time=numbers("time") if "time" in col else None,
        temp=numbers("temp") if "temp" in col else None,
        pan=np.radians(numbers("pan")) if "pan" in col else None,
        sigma_pos=sig_pos,
        sigma_rpy=sig_rpy,
        pose_id=pose_id,
        meta=meta,
    )


def format_measurements(meas: Measurements) -> str:
    """CSV v1 text of ``meas`` (mm, deg; full precision)."""
    buf = io.StringIO()
    for k, v in meas.meta.items():
        buf.write(f"# {k}: {v}\n")
    cols: list[tuple[str, F | tuple[str, ...]]] = []
    if meas.pose_id is not None:
        cols.append(("pose_id", meas.pose_id))
    for i in range(meas.n_joints):
        cols.append((f"q{i + 1}", np.degrees(meas.q[:, i])))
    if not np.all(np.isnan(meas.pos)):
        for i, c in enumerate("xyz"):
            cols.append((c, meas.pos[:, i] * 1e3))
    if meas.rpy is not None:
        for i, c in enumerate(("pitch", "yaw", "roll")):
            cols.append((c, np.degrees(meas.rpy[:, i])))
    for c in ("time", "temp"):
        v = getattr(meas, c)
        if v is not None:
            cols.append((c, v))
    if meas.pan is not None:
        cols.append(("pan", np.degrees(meas.pan)))
    if meas.sigma_pos is not None:
        for i, c in enumerate(("sx", "sy", "sz")):
            cols.append((c, meas.sigma_pos[:, i] * 1e3))
    if meas.sigma_rpy is not None:
        for i, c in enumerate(("spitch", "syaw", "sroll")):
            cols.append((c, np.degrees(meas.sigma_rpy[:, i])))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([c for c, _ in cols])
    for r in range(meas.n_poses):
        w.writerow([v[r] if isinstance(v, tuple) else repr(float(v[r])) for _, v in cols])
    return buf.getvalue()


def write_measurements(path: str | os.PathLike[str], meas: Measurements) -> None:
    """Write ``meas`` as CSV v1 (atomically: a half-written file never appears)."""
    write_text_atomic(path, format_measurements(meas))


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


# --------------------------------------------------------------------------- robot descriptions


def load_robot(spec: str) -> RobotModel:
    """A robot from a built-in name (``ur5``) or a description file path (``.toml``, ``.urdf``).

    A bare name (no path separator, no file suffix) is only looked up among the built-ins,
    so a name can never reach outside them (``../x`` is a path, never a name).
    """
    s = spec.strip()
    is_path = ("/" in s) or ("\\" in s) or s.lower().endswith((".toml", ".urdf"))
    if not is_path:
        if s.lower() in BUILTIN_ROBOTS and _NAME.fullmatch(s):
            return BUILTIN_ROBOTS[s.lower()]()
        raise InputError(
            f"unknown robot {spec!r}: built-in robots are {', '.join(BUILTIN_ROBOTS)}; "
            "or give a path to a .toml DH table or a .urdf file"
        )
    p = Path(s)
    if not p.is_file():
        raise InputError(f"{p}: robot description file not found")
    if p.suffix.lower() == ".toml":
        return read_dh_toml(p)
    if p.suffix.lower() == ".urdf":
        return read_urdf(p)
    raise InputError(f"{p}: unknown robot description format (use .toml or .urdf)")


def read_dh_toml(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a DH table in TOML (format in the module docstring)."""
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML: {exc}") from None
    head = doc.get("robot", {})
    joints = doc.get("joint")
    if not isinstance(joints, list) or not joints:
        raise InputError(f"{p}: no [[joint]] tables")
    conv = head.get("convention", "dh")
    if conv not in ("dh", "mdh"):
        raise InputError(f"{p}: [robot] convention must be 'dh' or 'mdh', got {conv!r}")
    lu = {"mm": 1e-3, "m": 1.0}.get(head.get("length_unit", "m"))
    au = {"deg": math.pi / 180, "rad": 1.0}.get(head.get("angle_unit", "deg"))
    if lu is None or au is None:
        raise InputError(f"{p}: length_unit must be 'mm' or 'm', angle_unit 'deg' or 'rad'")

    def get(i: int, key: str, default: float | None = None) -> float:
        v = joints[i].get(key, default)
        if v is None:
            raise InputError(f"{p}: joint {i + 1} has no {key!r}")
        if not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"{p}: joint {i + 1}: {key} = {v!r} is not a number")
        return float(v)

    n = len(joints)
    a = [get(i, "a") * lu for i in range(n)]
    d = [get(i, "d") * lu for i in range(n)]
    alpha = [get(i, "alpha") * au for i in range(n)]
    off = [get(i, "theta_offset", 0.0) * au for i in range(n)]
    lo = [get(i, "q_min", -2 * math.pi / au) * au for i in range(n)]
    hi = [get(i, "q_max", 2 * math.pi / au) * au for i in range(n)]
    has_mass = ["mass" in j for j in joints]
    masses = coms = None
    if any(has_mass):
        if not all(has_mass) or not all("com" in j for j in joints):
            raise InputError(f"{p}: give mass and com for every joint or for none")
        masses = [get(i, "mass") for i in range(n)]
        coms = []
        for i, j in enumerate(joints):
            c = j["com"]
            if not (isinstance(c, list) and len(c) == 3):
                raise InputError(f"{p}: joint {i + 1}: com must be a list of 3 numbers")
            coms.append([float(x) * lu for x in c])
    names = tuple(str(j.get("name", f"j{i + 1}")) for i, j in enumerate(joints))
    if any(h <= l for l, h in zip(lo, hi, strict=True)):
        raise InputError(f"{p}: every joint needs q_max > q_min")
    return from_dh(
        str(head.get("name", p.stem)),
        a,
        d,
        alpha,
        theta_offset=off,
        q_min=lo,
        q_max=hi,
        masses=masses,
        coms=coms,
        modified=conv == "mdh",
        joint_names=names,
    )


def read_urdf(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a URDF file through pinocchio (serial chain of revolute joints).

    Each joint's axis ``a`` is turned onto z: the joint placement is followed by a constant
    rotation ``R_a`` with ``R_a ẑ = a`` so the joint is ``Rz(θ)`` as the error model expects.
    The flange is the last joint's frame.
    """
    import pinocchio as pin

    p = Path(path)
    try:
        model = pin.buildModelFromUrdf(str(p))
    except (ValueError, RuntimeError) as exc:
        raise InputError(f"{p}: pinocchio cannot read this URDF: {exc}") from None
    nj = model.njoints - 1
    if nj < 1 or model.nq != nj:
        raise InputError(
            f"{p}: needs a chain of 1-dof revolute joints (nq={model.nq}, joints={nj})"
        )
    links = np.tile(np.eye(4), (nj + 1, 1, 1))
    Ra_prev = np.eye(3)
    masses, coms = [], []
    for i in range(1, nj + 1):
        jm = model.joints[i]
        short = jm.shortname()
        if model.parents[i] != i - 1:
            raise InputError(f"{p}: joint {model.names[i]!r} does not continue a serial chain")
        if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            axis = {
                "JointModelRX": [1, 0, 0],
                "JointModelRY": [0, 1, 0],
                "JointModelRZ": [0, 0, 1],
            }[short]
        elif short == "JointModelRevoluteUnaligned":
            axis = np.asarray(jm.extract().axis, float)
        else:
            raise InputError(
                f"{p}: joint {model.names[i]!r} is {short}; only revolute joints are supported"
            )
        Ra = _rot_z_onto(np.asarray(axis, float))
        M = model.jointPlacements[i].homogeneous
        prev = np.eye(4)
        prev[:3, :3] = Ra_prev.T
        Rah = np.eye(4)
        Rah[:3, :3] = Ra
        links[i - 1] = prev @ M @ Rah if i > 1 else M @ Rah
        Ra_prev = Ra
        inert = model.inertias[i]
        masses.append(float(inert.mass))
        coms.append(np.asarray(inert.lever, float))
    last = np.eye(4)
    last[:3, :3] = Ra_prev.T
    links[nj] = last
    com_arr = np.empty((nj, 3))
    for i in range(nj):
        # com in the frame after Rz(θ_i)·C_i: C_i⁻¹ · (R_aᵀ c)
        Ra_i = _rot_z_onto(_axis_of(model, i + 1))
        c = Ra_i.T @ coms[i]
        Ci = links[i + 1]
        com_arr[i] = Ci[:3, :3].T @ (c - Ci[:3, 3])
    has_inertia = sum(masses) > 0
    lo = np.asarray(model.lowerPositionLimit, float)
    hi = np.asarray(model.upperPositionLimit, float)
    bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo)
    lo = np.where(bad, -2 * np.pi, lo)
    hi = np.where(bad, 2 * np.pi, hi)
    return RobotModel(
        name=p.stem,
        links=links,
        q_offset=np.zeros(nj),
        q_min=lo,
        q_max=hi,
        masses=np.array(masses) if has_inertia else None,
        coms=com_arr if has_inertia else None,
        joint_names=tuple(model.names[1:]),
        convention="urdf",
    )


def _axis_of(model: Any, i: int) -> F:
    short = model.joints[i].shortname()
    table = {"JointModelRX": [1, 0, 0], "JointModelRY": [0, 1, 0], "JointModelRZ": [0, 0, 1]}
    if short in table:
        return np.array(table[short], float)
    return np.asarray(model.joints[i].extract().axis, float)


def _rot_z_onto(a: F) -> F:
    """A rotation R with ``R ẑ = a / |a|`` (identity for a = ẑ)."""
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, a)
    s, c = np.linalg.norm(v), float(z @ a)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K * ((1 - c) / s**2)


def robot_to_json(robot: RobotModel) -> dict[str, Any]:
    """The robot embedded in model.json (so a model file predicts on its own)."""
    return {
        "name": robot.name,
        "convention": robot.convention,
        "links": robot.links.tolist(),
        "q_offset": robot.q_offset.tolist(),
        "q_min": robot.q_min.tolist(),
        "q_max": robot.q_max.tolist(),
        "masses": None if robot.masses is None else robot.masses.tolist(),
        "coms": None if robot.coms is None else robot.coms.tolist(),
        "joint_names": list(robot.joint_names),
        "dh": robot.dh,
    }


def robot_from_json(d: dict[str, Any]) -> RobotModel:
    """Inverse of :func:`robot_to_json`."""
    return RobotModel(
        name=str(d["name"]),
        links=np.asarray(d["links"], float),
        q_offset=np.asarray(d["q_offset"], float),
        q_min=np.asarray(d["q_min"], float),
        q_max=np.asarray(d["q_max"], float),
        masses=None if d.get("masses") is None else np.asarray(d["masses"], float),
        coms=None if d.get("coms") is None else np.asarray(d["coms"], float),
        joint_names=tuple(d.get("joint_names", ())),
        dh=d.get("dh"),
        convention=str(d.get("convention", "generic")),
    )


# --------------------------------------------------------------------------- model.json


def model_to_json(fitted: Any) -> dict[str, Any]:
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
                **(e.info() if hasattr(e, "info") else {}),
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
        },
        "prior": {
            "joint_pos": fitted.prior.joint_pos,
            "joint_rot": fitted.prior.joint_rot,
            "setup_pos": fitted.prior.setup_pos,
            "setup_rot": fitted.prior.setup_rot,
        },
    }


def model_from_json(doc: dict[str, Any], name: str = "model.json") -> Any:
    """A :class:`~quickhealth.identify.fit.FittedModel` from its JSON document."""
    from quickhealth.identify.effects import parse_effects
    from quickhealth.identify.errormodel import ErrorModelSpec
    from quickhealth.identify.fit import FittedModel, InstrumentNoise, ParameterPrior

    if not isinstance(doc, dict) or doc.get("schema") != MODEL_SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(
            f"{name}: not a quickhealth model (schema {got!r}, expected {MODEL_SCHEMA!r})"
        )
    try:
        robot = robot_from_json(doc["robot"])
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
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{name}: model file is incomplete or damaged: {exc!r}") from None


def write_model(path: str | os.PathLike[str], fitted: Any) -> None:
    """Write model.json (JSON only; never pickle)."""
    write_text_atomic(path, json.dumps(model_to_json(fitted), indent=1) + "\n")


def read_model(path: str | os.PathLike[str]) -> Any:
    """Read model.json back into a FittedModel."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    except UnicodeDecodeError:  # e.g. a pickle: binary files are never loaded as code
        raise InputError(f"{p}: not a model.json file (binary content, not UTF-8 JSON)") from None
    return model_from_json(doc, str(p))


# --------------------------------------------------------------------------- report.json


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
    """Write report.json (``schema`` added; NaN/inf become null)."""
    doc = {"schema": REPORT_SCHEMA, **_jsonable(report)}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def read_report(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read report.json."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    if doc.get("schema") not in REPORT_SCHEMAS_READ:
        raise InputError(f"{p}: not a quickhealth report (schema {doc.get('schema')!r})")
    return doc


# --------------------------------------------------------------------------- URScript


_MOVE = re.compile(r"\b(movej|movel|movep|servoj)\s*\(\s*(p?)\[([^\]]*)\]")


def read_urscript_joints(path: str | os.PathLike[str], n_joints: int) -> tuple[F, list[int]]:
    """Joint targets (rad, shape (n, n_joints)) of every ``movej``/``movel`` with a joint list.

    URScript joint lists are in radians.  A move to a Cartesian pose ``p[...]`` has no joint
    target and is an error (the model predicts from joints).

    Returns
    -------
    q : ndarray, shape (n, n_joints), rad
    lines : list of int, the 1-based line of each target
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    qs: list[list[float]] = []
    lines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        code = line.split("#", 1)[0]
        for m in _MOVE.finditer(code):
            col = m.start() + 1
            if m.group(2):
                raise InputError(
                    f"{p}:{lineno}:{col}: {m.group(1)} to a Cartesian pose p[...] has no joint "
                    "target; use joint lists"
                )
            try:
                vals = [float(v) for v in m.group(3).split(",")]
            except ValueError:
                raise InputError(
                    f"{p}:{lineno}:{col}: {m.group(1)} target is not a list of numbers"
                ) from None
            if len(vals) != n_joints or not all(math.isfinite(v) for v in vals):
                raise InputError(
                    f"{p}:{lineno}:{col}: {m.group(1)} has {len(vals)} joint values, the robot "
                    f"has {n_joints}"
                )
            qs.append(vals)
            lines.append(lineno)
    if not qs:
        raise InputError(f"{p}:1:1: no movej/movel with a joint target found")
    return np.array(qs), lines


# --------------------------------------------------------------------------- WAM data set


def read_wam_csv(path: str | os.PathLike[str], sign: float) -> Measurements:
    """The Barrett WAM laser-tracker files (step_order, x_t…, x_dif…, joint_1…7) as Measurements.

    Position = desired + ``sign`` · difference (mm → m); joints deg → rad.
    """
    p = Path(path)
    try:
        rows = list(csv.reader(p.read_text(encoding="utf-8").splitlines()))
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    head = rows[0]
    need = ["x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 8)]
    for c in need:
        if c not in head:
            raise InputError(f"{p}:1:{len(head) + 1}: missing WAM column {c!r}")
    ix = {c: head.index(c) for c in need}
    data = []
    for lineno, r in enumerate(rows[1:], start=2):
        if not r:
            continue
        try:
            data.append([float(r[ix[c]]) for c in need])
        except (ValueError, IndexError):
            raise InputError(f"{p}:{lineno}:1: row is not numeric") from None
    a = np.array(data)
    pos = (a[:, 0:3] + sign * a[:, 3:6]) * 1e-3
    q = np.radians(a[:, 6:13])
    return Measurements(
        q=q, pos=pos, meta={"source": p.name, "instrument": "GTS3800 laser tracker"}
    )
