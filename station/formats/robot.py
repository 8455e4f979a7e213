"""Robot descriptions (``--robot``): a built-in name, a DH table (TOML) or a URDF, and the
controller's calibration (``--calibration``) that replaces a robot's nominal kinematics.

- a built-in name, case-insensitive: ``ur3``, ``ur5``, ``ur10`` (CB3), ``ur3e``, ``ur5e``,
  ``ur10e``, ``ur16e``, ``ur20``, ``ur30`` (e-Series);
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
    spec_mm = 1.5            # optional: the accuracy spec, the TCP error (mm, workspace
                             #   maximum) the application accepts; every verdict uses it

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

import hashlib
import math
import os
import re
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import (
    BUILTIN_ROBOTS,
    Nominal,
    RobotModel,
    builtin_robot,
    from_dh,
    with_kinematics,
)
from ...identify.ur_calibration import KEYS, SEGMENTS, UrKinematics
from .common import excerpt, one_line, read_text_limited

F = NDArray[np.float64]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
#: A controller calibration further than this from the arm's nominal kinematics (flange
#: position anywhere in the joint ranges) belongs to another arm model (UR5 vs UR5e: 73 mm;
#: real calibrations differ from nominal by a few mm).
MAX_CALIBRATION_OFFSET = 0.03  # m


def load_robot(spec: str, calibration: str | os.PathLike[str] | None = None) -> RobotModel:
    """A robot from a built-in name (``ur10e``, any case) or a description file path
    (``.toml``, ``.urdf``); with ``calibration``, its kinematics replaced by the controller
    calibration in that UR ROS driver kinematics YAML (:func:`read_ur_calibration`).

    A bare name (no path separator, no file suffix) is only looked up among the built-ins,
    so a name can never reach outside them (``../x`` is a path, never a name).
    """
    s = spec.strip()
    is_path = ("/" in s) or ("\\" in s) or s.lower().endswith((".toml", ".urdf"))
    if not is_path:
        if s.lower() in BUILTIN_ROBOTS and _NAME.fullmatch(s):
            robot = builtin_robot(s)
        else:
            raise InputError(
                f"unknown robot {spec!r}: built-in robots are {', '.join(BUILTIN_ROBOTS)}; "
                "or give a path to a .toml DH table or a .urdf file"
            )
    else:
        p = Path(s)
        if not p.is_file():
            raise InputError(f"{p}: robot description file not found")
        if p.suffix.lower() == ".toml":
            robot = read_dh_toml(p)
        elif p.suffix.lower() == ".urdf":
            robot = read_urdf(p)
        else:
            raise InputError(f"{p}: unknown robot description format (use .toml or .urdf)")
    if calibration is None:
        return robot
    return calibrated_robot(robot, calibration, robot_label=s)


def robot_spec_mm(spec: str) -> float | None:
    """The accuracy spec a robot description file states (``[robot] spec_mm``: the TCP error
    in mm the application accepts), None for a built-in name, a URDF or a file without one.

    Raises
    ------
    InputError
        A ``spec_mm`` that is not a number in (0, 1000] mm.
    """
    p = Path(spec.strip())
    if p.suffix.lower() != ".toml" or not p.is_file():
        return None
    try:
        head = tomllib.loads(read_text_limited(p, "robot")).get("robot", {})
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML: {exc}") from None
    v = head.get("spec_mm") if isinstance(head, dict) else None
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v <= 1000:
        raise InputError(f"{p}: [robot] spec_mm must be a number of mm in (0, 1000], got {v!r}")
    return float(v)


def read_ur_calibration(path: str | os.PathLike[str]) -> tuple[UrKinematics, str]:
    """The ``kinematics`` block of a UR ROS driver calibration YAML (the file ``ur_calibration``
    writes, the layout of ur_description's ``default_kinematics.yaml``) and the file's SHA-256.

    Every segment (``shoulder`` … ``wrist_3``) needs ``x, y, z`` (m) and ``roll, pitch, yaw``
    (rad) as finite numbers; ``hash`` is optional.  One line, naming the file, for anything
    else.
    """
    import yaml  # PyYAML only for a controller calibration file

    p = Path(path)
    text = read_text_limited(p, "robot")  # size, regular file, UTF-8 before YAML sees it
    try:
        sha = hashlib.sha256(p.read_bytes()).hexdigest()  # as `sha256sum FILE` prints it
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror}") from None
    try:
        doc = yaml.load(text, Loader=_loader_without_aliases(yaml))  # noqa: S506 - safe, no aliases
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f":{where.line + 1}:{where.column + 1}" if where is not None else ""
        what = getattr(exc, "problem", None) or "not valid YAML"
        raise InputError(f"{p}{at}: not valid YAML: {what}") from None
    kin = doc.get("kinematics") if isinstance(doc, dict) else None
    if not isinstance(kin, dict):
        raise InputError(
            f"{p}: no 'kinematics:' block (expected the UR ROS driver's calibration YAML, "
            "as ur_calibration writes it)"
        )
    unknown = [excerpt(k, 30) for k in kin if k not in SEGMENTS and k != "hash"][:5]
    missing = [k for k in SEGMENTS if k not in kin]
    if unknown or missing:
        raise InputError(
            f"{p}: kinematics has "
            + "; ".join(
                ([f"no {', '.join(missing)}"] if missing else [])
                + ([f"unknown {', '.join(unknown)}"] if unknown else [])
            )
            + f" (expected the segments {', '.join(SEGMENTS)} and hash)"
        )
    vals = np.empty((6, 6))
    for i, seg in enumerate(SEGMENTS):
        block = kin[seg]
        if not isinstance(block, dict):
            raise InputError(f"{p}: kinematics.{seg} must hold {', '.join(KEYS)}")
        for j, key in enumerate(KEYS):
            v = block.get(key)
            if isinstance(v, str):  # YAML 1.1 reads "1e-05" (no dot) as a string
                try:
                    v = float(v)
                except ValueError:
                    pass
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"{p}: kinematics.{seg}.{key} = {excerpt(v)} is not a number")
            vals[i, j] = float(v)
    if np.abs(vals[:, :3]).max() > 20.0:
        raise InputError(f"{p}: a joint origin is more than 20 m away: not metres?")
    if np.abs(vals[:, 3:]).max() > 4 * math.pi:
        raise InputError(f"{p}: an angle is larger than 4π: not radians?")
    h = kin.get("hash", "")
    h = "" if h is None else h
    if not isinstance(h, str | int) or len(str(h)) > 200:
        raise InputError(
            f"{p}: kinematics.hash = {excerpt(h)} is not the calibration's hash (a short text)"
        )
    h = one_line(h, f"{p}: kinematics.hash")
    return UrKinematics(xyz=vals[:, :3], rpy=vals[:, 3:], hash=h), sha


def _loader_without_aliases(yaml: Any) -> type:
    """PyYAML's safe loader refusing aliases (``*name``): a 2 KB file of nested aliases (a
    "billion laughs") expands to gigabytes, and a calibration file never needs one."""

    class NoAliases(yaml.SafeLoader):  # type: ignore[misc, name-defined]
        def compose_node(self, parent: Any, index: Any) -> Any:
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise yaml.composer.ComposerError(
                    None, None, "an alias (*name) refused: a calibration file has none", mark
                )
            return super().compose_node(parent, index)

    return NoAliases


def calibrated_robot(
    robot: RobotModel, path: str | os.PathLike[str], robot_label: str | None = None
) -> RobotModel:
    """``robot`` whose nominal kinematics are the controller calibration in ``path``.

    The joint readings keep their meaning; inertial data, limits and speeds stay the robot's
    (centres of mass ride on their links, :func:`~quickhealth.identify.robot.with_kinematics`).
    Refused: a robot without six joints, and a calibration further than
    :data:`MAX_CALIBRATION_OFFSET` from the robot's own kinematics (another arm model's file).
    """
    p = Path(path)
    if robot.n_joints != 6:
        raise InputError(
            f"{p}: a UR calibration has 6 joints, robot {robot.name!r} has {robot.n_joints}"
        )
    kin, sha = read_ur_calibration(p)
    label = robot_label if robot_label is not None else robot.name
    if "/" in label or "\\" in label:
        label = Path(label).name
    new = with_kinematics(
        robot,
        kin.links(),
        nominal=Nominal(label, calibration=p.name, calibration_sha256=sha),
        convention="urdf",
    )
    q = np.random.default_rng(0).uniform(robot.q_min, robot.q_max, size=(256, 6))
    off = np.linalg.norm(new.fk(q)[:, :3, 3] - robot.fk(q)[:, :3, 3], axis=1).max()
    if not off <= MAX_CALIBRATION_OFFSET:
        raise InputError(
            f"{p}: these kinematics put the flange up to {off * 1e3:.0f} mm from the "
            f"{robot.name}'s nominal ones (a calibration moves it a few mm): the calibration "
            f"of another arm model? Give the arm it was read from with --robot "
            f"(built-in: {', '.join(BUILTIN_ROBOTS)})"
        )
    return new


def read_dh_toml(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a DH table in TOML (format in the module docstring)."""
    p = Path(path)
    try:
        doc = tomllib.loads(read_text_limited(p, "robot"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML: {exc}") from None
    try:
        robot = _dh_from_doc(p, doc)
    except (TypeError, ValueError, AttributeError, KeyError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{p}: not a DH table: {' '.join(str(exc).split())}") from None
    check_robot(robot, str(p))
    return robot


#: A robot's flange must move at least this much (m) over its joint ranges.
MIN_REACH_M = 0.01


def check_robot(robot: RobotModel, name: str) -> None:
    """Finite link transforms and limits, sane sizes (a robot under 20 m, limits within ±4 turns)."""
    links = np.asarray(robot.links, float)
    if not np.all(np.isfinite(links)) or not np.all(np.isfinite(robot.q_offset)):
        raise InputError(f"{name}: the robot's link transforms are not all finite numbers")
    if np.abs(links[:, :3, 3]).max(initial=0.0) > 20.0:
        raise InputError(f"{name}: a link is longer than 20 m; check length_unit")
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise InputError(f"{name}: joint limits are not all finite numbers")
    if np.any(hi <= lo) or np.abs(np.concatenate([lo, hi])).max() > 8 * math.pi + 1e-9:
        raise InputError(f"{name}: joint limits must satisfy q_min < q_max within ±1440 deg")
    # meaning: the flange must move when the joints do (every length zero, or lengths in km
    # read as mm, makes a "robot" whose every pose is the same point)
    q = np.random.default_rng(0).uniform(lo, hi, (64, robot.n_joints))
    p = robot.fk(q).reshape(-1, 4, 4)[:, :3, 3]
    if np.ptp(p, axis=0).max() < MIN_REACH_M:
        raise InputError(
            f"{name}: the flange moves less than {MIN_REACH_M * 1e3:g} mm over the joint "
            "ranges: every link length is (near) zero; check the lengths and length_unit"
        )


def _dh_from_doc(p: Path, doc: dict[str, Any]) -> RobotModel:
    head = doc.get("robot", {})
    if not isinstance(head, dict):
        raise InputError(f"{p}: [robot] must be a table")
    joints = doc.get("joint")
    if not isinstance(joints, list) or not joints:
        raise InputError(f"{p}: no [[joint]] tables")
    if not all(isinstance(j, dict) for j in joints):
        raise InputError(f"{p}: every joint must be a [[joint]] table")
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
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
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
            if not (
                isinstance(c, list)
                and len(c) == 3
                and all(isinstance(x, int | float) and not isinstance(x, bool) for x in c)
            ):
                raise InputError(f"{p}: joint {i + 1}: com must be a list of 3 numbers")
            coms.append([float(x) * lu for x in c])
    names = tuple(str(j.get("name", f"j{i + 1}")) for i, j in enumerate(joints))
    if any(h <= l for l, h in zip(lo, hi, strict=True)):
        raise InputError(f"{p}: every joint needs q_max > q_min")
    has_kt = ["torque_constant" in j for j in joints]
    kt = None
    if any(has_kt):
        if not all(has_kt):
            raise InputError(f"{p}: give torque_constant (N·m/A) for every joint or for none")
        kt = np.array([get(i, "torque_constant") for i in range(n)])
        if np.any(kt <= 0) or np.any(kt > 1e4):
            i = int(np.flatnonzero((kt <= 0) | (kt > 1e4))[0])
            raise InputError(
                f"{p}: joint {i + 1}: torque_constant = {kt[i]:g} N·m/A is not a motor's "
                "(positive, the motor constant times the gear ratio: about 5-30 on a UR)"
            )
    return replace(
        from_dh(
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
        ),
        torque_constant=kt,
    )


def read_urdf(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a URDF file through pinocchio (serial chain of revolute joints).

    Each joint's axis ``a`` is turned onto z: the joint placement is followed by a constant
    rotation ``R_a`` with ``R_a ẑ = a`` so the joint is ``Rz(θ)`` as the error model expects.
    The flange is the last joint's frame.
    """
    import pinocchio as pin  # a URDF file only (seconds to load): built-in robots need none

    p = Path(path)
    read_text_limited(p, "robot")  # size, regular file, UTF-8 before pinocchio sees it
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
        axis = np.asarray(axis, float)
        if not (np.all(np.isfinite(axis)) and np.linalg.norm(axis) > 1e-9):
            raise InputError(
                f"{p}: joint {model.names[i]!r} has the axis {axis.tolist()}: a revolute joint "
                'needs a direction (e.g. <axis xyz="0 0 1"/>)'
            )
        Ra = _rot_z_onto(axis)
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
        "qd_max": None if robot.qd_max is None else robot.qd_max.tolist(),
        "qdd_max": None if robot.qdd_max is None else robot.qdd_max.tolist(),
        "controller": robot.controller,
        "control_hz": robot.control_hz,
        "nominal": None if robot.nominal is None else robot.nominal.as_dict(),
        "torque_constant": (
            None if robot.torque_constant is None else robot.torque_constant.tolist()
        ),
    }


def _shaped(d: dict[str, Any], key: str, shape: tuple[int, ...], optional: bool = False) -> Any:
    """``d[key]`` as a float array of ``shape`` (-1: any length), or InputError."""
    v = d.get(key)
    if v is None and optional:
        return None
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"robot.{key} is not an array of numbers") from None
    if a.ndim != len(shape) or any(n not in (-1, m) for n, m in zip(shape, a.shape, strict=True)):
        raise InputError(f"robot.{key} has shape {a.shape}, expected {shape}")
    return a


def robot_from_json(d: dict[str, Any]) -> RobotModel:
    """Inverse of :func:`robot_to_json` (shapes checked: InputError without a file name)."""
    if not isinstance(d, dict):
        raise InputError("robot is not a JSON object")
    q_offset = _shaped(d, "q_offset", (-1,))
    nj = q_offset.shape[0]
    if not 1 <= nj <= 12:
        raise InputError(f"robot has {nj} joints (1..12 expected)")
    links = _shaped(d, "links", (nj + 1, 4, 4))
    q_min = _shaped(d, "q_min", (nj,))
    q_max = _shaped(d, "q_max", (nj,))
    masses = _shaped(d, "masses", (nj,), optional=True)
    coms = _shaped(d, "coms", (nj, 3), optional=True)
    names = d.get("joint_names", ())
    if not isinstance(names, list | tuple) or len(names) not in (0, nj):
        raise InputError(f"robot.joint_names must list {nj} names")
    qd_max = _shaped(d, "qd_max", (nj,), optional=True)
    qdd_max = _shaped(d, "qdd_max", (nj,), optional=True)
    kt = _shaped(d, "torque_constant", (nj,), optional=True)
    if kt is not None and not np.all(np.isfinite(kt) & (kt > 0)):
        raise InputError("robot.torque_constant must be positive numbers (N·m/A)")
    hz = d.get("control_hz")
    if hz is not None and (isinstance(hz, bool) or not isinstance(hz, int | float)):
        raise InputError("robot.control_hz is not a number")
    nom = d.get("nominal")
    nominal = None
    if isinstance(nom, dict) and isinstance(nom.get("robot"), str):
        cal, sha = nom.get("calibration"), nom.get("calibration_sha256")
        nominal = Nominal(
            nom["robot"],
            calibration=cal if isinstance(cal, str) else None,
            calibration_sha256=sha if isinstance(sha, str) else None,
        )
    return RobotModel(
        name=str(d["name"]),
        links=links,
        q_offset=q_offset,
        q_min=q_min,
        q_max=q_max,
        masses=masses,
        coms=coms,
        joint_names=tuple(str(n) for n in names),
        dh=d.get("dh") if isinstance(d.get("dh"), dict) else None,
        convention=str(d.get("convention", "generic")),
        qd_max=qd_max,
        qdd_max=qdd_max,
        controller=str(d.get("controller") or ""),
        control_hz=None if hz is None else float(hz),
        nominal=nominal,
        torque_constant=kt,
    )
