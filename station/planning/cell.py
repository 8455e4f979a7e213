"""Cell files: the robot, its mounting, the table, obstacles, the stereo camera and the target.

A cell file is TOML (read with :mod:`tomllib`, data only: no tags, no code).  The schema is
documented in docs/plan.md; :func:`load_cell` validates every key and converts mm/deg to SI
exactly once.  Errors are one line, ``file: key: what``, raised as
:class:`~quickhealth.identify.errors.InputError` (exit status 2).

Frames
------
``world``: the table frame (z up, the table top at ``table.top_z_mm``).  ``base``: the robot's
DH base frame (the UR controller's base frame).  ``flange``: the DH flange frame (UR tool
flange).  ``target``: the smart target at pan 0 (z = marker normal, y = pan axis).
``cam_left`` / ``cam_right``: OpenCV camera frames (z = optical axis, x right, y down).
"""

from __future__ import annotations

import hashlib
import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import BUILTIN_ROBOTS, RobotModel, builtin_robot, with_payload
from ...identify.transforms import inv_T, make_T, rpy_to_R
from ..hardware.cameras.config import CameraConfig
from ..hardware.cameras.config import from_cell_table as camera_config

F = NDArray[np.float64]

SCHEMA = "quickhealth.cell/1"
#: Built-in cells by name: the paper's UR5 set-up and a UR10e cell (docs/plan.md).
BUILTIN_CELLS = {"reference": "reference_cell.toml", "ur10e": "ur10e_cell.toml"}
#: Every built-in arm a cell may name (``[robot] model``, any case): its nominal model.
ROBOTS: dict[str, Callable[[], RobotModel]] = {
    name: partial(builtin_robot, name) for name in BUILTIN_ROBOTS
}


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A fixed obstacle: a box (``size``: full edge lengths) or a cylinder (``radius``,
    ``length`` along its local z), centred at ``T_world_obstacle`` (SI)."""

    name: str
    shape: str  # "box" | "cylinder"
    T_world_obstacle: F
    size: F | None = None  # (3,) m, box
    radius: float = 0.0  # m, cylinder
    length: float = 0.0  # m, cylinder


@dataclass(frozen=True, eq=False)
class Camera:
    """Pin-hole intrinsics shared by both cameras of the stereo pair (px)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    margin_px: float
    min_range: float  # m
    max_range: float  # m

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view, degrees."""
        return (
            math.degrees(2 * math.atan(self.width / 2 / self.fx)),
            math.degrees(2 * math.atan(self.height / 2 / self.fy)),
        )


@dataclass(frozen=True, eq=False)
class Motion:
    """Leg speeds and accelerations and the measurement wait at each pose (SI)."""

    linear_speed: float  # m/s
    linear_accel: float  # m/s²
    joint_speed: float  # rad/s
    joint_accel: float  # rad/s²
    settle_s: float
    handshake_register: int  # 0 = no handshake
    measure_timeout_s: float
    passes: int


@dataclass(frozen=True, eq=False)
class PlannerSettings:
    """Planner tolerances (SI)."""

    clearance: float  # m, obstacles and table inflated by this
    leg_step: float  # m, sampling of linear legs
    leg_step_rot: float  # rad
    continuity_max: float  # rad, largest joint change between two leg samples
    joint_step: float  # rad, sampling of joint-space legs
    bins: int  # histogram bins per joint for the evenness criterion
    sight_radius: float  # m, radius of the line-of-sight beam
    sight_stop: float  # m, the beam ends this far before the target centre
    linear_preference: float  # evenness-penalty units a linear leg is worth (step 5)


@dataclass(frozen=True, eq=False)
class Cell:
    """A measurement cell, validated and in SI units.  Built by :func:`load_cell`."""

    name: str
    source: str  # file path or "builtin:reference"
    sha256: str  # of the file's bytes
    robot: RobotModel  # with the cell's planning joint limits
    T_world_base: F
    table_top_z: float
    table_min_xy: F
    table_max_xy: F
    table_thickness: float
    work_min: F  # (3,) world
    work_max: F
    orientation_spread: float  # rad
    T_flange_target: F
    pan_min: float
    pan_max: float
    facing_max: float  # rad
    target_body_size: F  # (3,) m
    T_target_body: F
    camera: Camera
    T_world_cam_left: F
    T_world_cam_right: F
    obstacles: tuple[Obstacle, ...]
    motion: Motion
    planner: PlannerSettings
    home: F | None = None  # (6,) rad: where the loop starts; the first leg is checked from it
    target_mass: float = 0.0  # kg, the smart target on the flange; 0: not stated
    target_com: F | None = None  # (3,) m, its centre of mass in the flange frame
    cameras: CameraConfig | None = None  # the [cameras] section: backend, ids, trigger
    # m: the TCP error the application accepts (``spec_mm``, the workspace maximum); None:
    # not stated (runs are then judged against their baseline only)
    tcp_tolerance: float | None = None

    @property
    def spec_mm(self) -> float | None:
        """The accuracy spec as the cell file states it (mm), None when it states none."""
        return None if self.tcp_tolerance is None else self.tcp_tolerance * 1e3

    def robot_with_target(self, robot: RobotModel | None = None) -> RobotModel:
        """``robot`` (default: the cell's arm) carrying the cell's smart target on its flange:
        the target's mass lumped into the last link (:func:`~quickhealth.identify.robot.with_payload`),
        so gravity compliance uses the arm's masses plus the target's.  Unchanged when the
        cell states no target mass."""
        r = self.robot if robot is None else robot
        if self.target_mass <= 0.0 or self.target_com is None:
            return r
        return with_payload(r, self.target_mass, self.target_com)

    @property
    def T_base_world(self) -> F:
        """World (table) frame seen from the robot base."""
        return inv_T(self.T_world_base)

    @property
    def T_base_cam_left(self) -> F:
        """Left camera in the robot base frame."""
        return self.T_base_world @ self.T_world_cam_left

    @property
    def T_base_cam_right(self) -> F:
        """Right camera in the robot base frame."""
        return self.T_base_world @ self.T_world_cam_right

    @property
    def baseline(self) -> float:
        """Distance between the two optical centres, m."""
        return float(np.linalg.norm(self.T_world_cam_left[:3, 3] - self.T_world_cam_right[:3, 3]))


def load_cell(path_or_name: str | Path) -> Cell:
    """Load and validate a cell file, or a built-in cell by name (``"reference"``).

    Parameters
    ----------
    path_or_name : str or Path
        A TOML cell file, or the name of a built-in cell.

    Returns
    -------
    Cell

    Raises
    ------
    InputError
        One line ``file: key: what`` for anything wrong: not TOML, a YAML file or object tag,
        unknown or missing keys, wrong types, non-finite or out-of-range numbers.
    """
    p = Path(path_or_name)
    if str(path_or_name) in BUILTIN_CELLS and not p.exists():
        ref = resources.files("quickhealth.station").joinpath(
            "data", BUILTIN_CELLS[str(path_or_name)]
        )
        raw = ref.read_bytes()
        label = f"builtin:{path_or_name}"
    else:
        if not p.is_file():
            raise InputError(
                f"{p}: no such cell file (built-in cells: {', '.join(sorted(BUILTIN_CELLS))})"
            )
        raw = p.read_bytes()
        label = str(p)
    return parse_cell(raw, label)


_TAG = re.compile(rb"!![A-Za-z]|!<tag:|^\s*---\s*$", re.M)


def parse_cell(raw: bytes, label: str) -> Cell:
    """Parse the bytes of a cell file (see :func:`load_cell`); ``label`` names it in errors."""
    if label.lower().endswith((".yaml", ".yml")):
        raise InputError(
            f"{label}: YAML cell files are not accepted; write the cell in TOML (docs/plan.md)"
        )
    m = _TAG.search(raw)
    if m is not None:
        line = raw[: m.start()].count(b"\n") + 1
        raise InputError(
            f"{label}:{line}: YAML object tag or document marker refused: a cell file is TOML data (docs/plan.md)"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{label}: not a TOML cell file: not UTF-8 text (byte {exc.start})"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{label}: not a TOML cell file: {exc}") from None
    return _build(_Tab(data, label, ""), label, hashlib.sha256(raw).hexdigest())


class _Tab:
    """A TOML table with its key path, for one-line errors; tracks the keys read."""

    def __init__(self, data: Any, label: str, prefix: str) -> None:
        if not isinstance(data, dict):
            raise InputError(f"{label}: {prefix.rstrip('.') or '(top)'}: expected a table")
        self.d = data
        self.label = label
        self.prefix = prefix
        self.used: set[str] = set()

    def err(self, key: str, what: str) -> InputError:
        return InputError(f"{self.label}: {self.prefix}{key}: {what}")

    def has(self, key: str) -> bool:
        return key in self.d

    def get(self, key: str, default: Any = ...) -> Any:
        self.used.add(key)
        if key not in self.d:
            if default is ...:
                raise self.err(key, "missing")
            return default
        return self.d[key]

    def sub(self, key: str) -> _Tab:
        return _Tab(self.get(key), self.label, f"{self.prefix}{key}.")

    def num(
        self,
        key: str,
        default: Any = ...,
        lo: float = -math.inf,
        hi: float = math.inf,
        strict_lo: bool = False,
    ) -> float:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.err(key, f"expected a number, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v):
            raise self.err(key, "not a finite number")
        if v < lo or (strict_lo and v <= lo) or v > hi:
            rng = f"{'(' if strict_lo else '['}{lo:g}, {hi:g}]"
            raise self.err(key, f"{v:g} outside {rng}")
        return v

    def integer(self, key: str, default: Any = ..., lo: int = -(2**31), hi: int = 2**31) -> int:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"expected an integer, got {type(v).__name__}")
        if not lo <= v <= hi:
            raise self.err(key, f"{v} outside [{lo}, {hi}]")
        return int(v)

    def text(self, key: str, default: Any = ..., pattern: str = r"[\w .,:;()/+\-']{0,200}") -> str:
        v = self.get(key, default)
        if not isinstance(v, str):
            raise self.err(key, f"expected a string, got {type(v).__name__}")
        if not re.fullmatch(pattern, v):
            raise self.err(key, f"{v[:40]!r} has characters that are not allowed")
        return v

    def vec(self, key: str, n: int, default: Any = ...) -> F:
        v = self.get(key, default)
        if not isinstance(v, list) or len(v) != n:
            raise self.err(key, f"expected a list of {n} numbers")
        out = []
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise self.err(key, f"expected a list of {n} finite numbers, got {x!r}")
            out.append(float(x))
        return np.array(out)

    def done(self) -> None:
        extra = sorted(set(self.d) - self.used)
        if extra:
            raise self.err(extra[0], f"unknown key (known here: {', '.join(sorted(self.used))})")


def _pose(t: _Tab, xyz: str, rpy: str) -> F:
    p = t.vec(xyz, 3) / 1000.0
    r = np.radians(t.vec(rpy, 3, [0.0, 0.0, 0.0]))
    return make_T(rpy_to_R(r[0], r[1], r[2]), p)


def look_at(position: F, target: F, up: F | None = None) -> F:
    """``T_world_cam`` of an OpenCV camera at ``position`` looking at ``target`` (y down)."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else up
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), position)


def _build(top: _Tab, label: str, sha: str) -> Cell:
    schema = top.text("schema")
    if schema != SCHEMA:
        raise top.err("schema", f"expected {SCHEMA!r}, got {schema!r}")
    name = top.text("name", pattern=r"[A-Za-z0-9_\-]{1,64}")
    top.text("description", "", pattern=r"[^\x00-\x1f\x7f]{0,500}")
    spec_mm = top.num("spec_mm", lo=0.0, hi=1000.0, strict_lo=True) if top.has("spec_mm") else None
    robot, T_world_base, home = _robot(top.sub("robot"))
    top_z, tmin, tmax, thick = _table(top.sub("table"))
    wmin, wmax, spread = _workspace(top.sub("workspace"), top_z)
    T_flange_target, pan, facing, bsize, T_target_body, mass, com = _target(top.sub("target"))
    cam, Tc = _camera(top.sub("camera"))
    obstacles = _obstacles(top, label)
    motion = _motion(top.sub("motion"))
    planner = _planner(top.sub("planner") if top.has("planner") else _Tab({}, label, "planner."))
    cameras = camera_config(top.sub("cameras")) if top.has("cameras") else None
    top.done()

    return Cell(
        name=name,
        source=label,
        sha256=sha,
        robot=robot,
        T_world_base=T_world_base,
        table_top_z=top_z,
        table_min_xy=tmin,
        table_max_xy=tmax,
        table_thickness=thick,
        work_min=wmin,
        work_max=wmax,
        orientation_spread=spread,
        T_flange_target=T_flange_target,
        pan_min=math.radians(pan[0]),
        pan_max=math.radians(pan[1]),
        facing_max=facing,
        target_body_size=bsize,
        T_target_body=T_target_body,
        camera=cam,
        T_world_cam_left=Tc[0],
        T_world_cam_right=Tc[1],
        obstacles=tuple(obstacles),
        motion=motion,
        planner=planner,
        home=home,
        target_mass=mass,
        target_com=com,
        cameras=cameras,
        tcp_tolerance=None if spec_mm is None else spec_mm / 1000.0,
    )


def _robot(rt: _Tab) -> tuple[RobotModel, F, F | None]:
    """The ``[robot]`` table: the model with the cell's planning limits, its base, home."""
    given = rt.text("model")
    model = given.strip().lower()
    if model not in ROBOTS:
        raise rt.err("model", f"unknown robot {given!r} (known: {', '.join(ROBOTS)})")
    robot = ROBOTS[model]()
    T_world_base = _pose(rt, "base_xyz_mm", "base_rpy_deg")
    qlo = np.radians(rt.vec("q_min_deg", 6, list(np.degrees(robot.q_min))))
    qhi = np.radians(rt.vec("q_max_deg", 6, list(np.degrees(robot.q_max))))
    if np.any(qlo < robot.q_min - 1e-9) or np.any(qhi > robot.q_max + 1e-9):
        raise rt.err("q_min_deg", f"planning limits must lie inside the {model}'s own limits")
    if np.any(qhi - qlo < np.radians(10.0)):
        raise rt.err("q_max_deg", "every joint needs q_max_deg ≥ q_min_deg + 10")
    home = None
    if rt.has("home_deg"):
        home = np.radians(rt.vec("home_deg", 6))
        if np.any(home < qlo - 1e-9) or np.any(home > qhi + 1e-9):
            raise rt.err("home_deg", "outside the planning limits q_min_deg..q_max_deg")
    rt.done()
    return replace(robot, q_min=qlo, q_max=qhi), T_world_base, home


def _table(tt: _Tab) -> tuple[float, F, F, float]:
    """The ``[table]`` table: top height, extent and thickness (m)."""
    top_z = tt.num("top_z_mm") / 1000.0
    tmin = tt.vec("min_xy_mm", 2) / 1000.0
    tmax = tt.vec("max_xy_mm", 2) / 1000.0
    thick = tt.num("thickness_mm", 100.0, lo=1.0, hi=5000.0) / 1000.0
    if np.any(tmax <= tmin):
        raise tt.err("max_xy_mm", "must exceed min_xy_mm on both axes")
    tt.done()
    return top_z, tmin, tmax, thick


def _workspace(wt: _Tab, top_z: float) -> tuple[F, F, float]:
    """The ``[workspace]`` table: the box of target positions (m) and the orientation spread."""
    wmin = wt.vec("min_mm", 3) / 1000.0
    wmax = wt.vec("max_mm", 3) / 1000.0
    spread = math.radians(wt.num("orientation_spread_deg", 30.0, lo=0.0, hi=180.0))
    if np.any(wmax <= wmin):
        raise wt.err("max_mm", "must exceed min_mm on every axis")
    if wmin[2] <= top_z:
        raise wt.err(
            "min_mm", f"z = {wmin[2] * 1000:g} mm is not above the table top ({top_z * 1000:g} mm)"
        )
    wt.done()
    return wmin, wmax, spread


def _target(gt: _Tab) -> tuple[F, F, float, F, F, float, F]:
    """The ``[target]`` table: its mount, pan range (deg), facing limit, body and its frame,
    mass (kg) and centre of mass (flange frame, m)."""
    T_flange_target = _pose(gt, "xyz_mm", "rpy_deg")
    pan = gt.vec("pan_range_deg", 2, [-90.0, 90.0])
    if not -180.0 <= pan[0] <= pan[1] <= 180.0:
        raise gt.err("pan_range_deg", "expected [low, high] with -180 ≤ low ≤ high ≤ 180")
    facing = math.radians(gt.num("facing_max_deg", 45.0, lo=0.0, hi=90.0, strict_lo=True))
    bsize = gt.vec("body_size_mm", 3) / 1000.0
    if np.any(bsize <= 0):
        raise gt.err("body_size_mm", "every edge must be > 0")
    T_target_body = make_T(np.eye(3), gt.vec("body_center_mm", 3, [0.0, 0.0, 0.0]) / 1000.0)
    mass = gt.num("mass_kg", 0.0, lo=0.0, hi=100.0)
    com_target = gt.vec("com_mm", 3, list(T_target_body[:3, 3] * 1000.0)) / 1000.0
    com = (T_flange_target @ np.r_[com_target, 1.0])[:3]
    gt.done()
    return T_flange_target, pan, facing, bsize, T_target_body, mass, com


def _camera(ct: _Tab) -> tuple[Camera, list[F]]:
    """The ``[camera]`` table: the pinhole model and where the left and right cameras are."""
    w = ct.integer("width_px", lo=16, hi=100000)
    h = ct.integer("height_px", lo=16, hi=100000)
    cam = Camera(
        fx=ct.num("fx_px", lo=1.0, hi=1e6),
        fy=ct.num("fy_px", lo=1.0, hi=1e6),
        cx=ct.num("cx_px", w / 2, lo=0.0, hi=w),
        cy=ct.num("cy_px", h / 2, lo=0.0, hi=h),
        width=w,
        height=h,
        margin_px=ct.num("margin_px", 0.0, lo=0.0, hi=min(w, h) / 2 - 1),
        min_range=ct.num("min_range_mm", 300.0, lo=0.0) / 1000.0,
        max_range=ct.num("max_range_mm", 5000.0, lo=1.0) / 1000.0,
    )
    if cam.max_range <= cam.min_range:
        raise ct.err("max_range_mm", "must exceed min_range_mm")
    Tc = []
    for side in ("left", "right"):
        st = ct.sub(side)
        pos = st.vec("position_mm", 3) / 1000.0
        at = st.vec("look_at_mm", 3) / 1000.0
        d = at - pos
        if np.linalg.norm(d) < 1e-3:
            raise st.err("look_at_mm", "coincides with position_mm")
        if np.linalg.norm(np.cross(d / np.linalg.norm(d), [0.0, 0.0, 1.0])) < 1e-3:
            raise st.err("look_at_mm", "camera looks straight up or down; tilt it a little")
        st.done()
        Tc.append(look_at(pos, at))
    ct.done()
    if np.linalg.norm(Tc[0][:3, 3] - Tc[1][:3, 3]) < 1e-3:
        raise ct.err("right.position_mm", "both cameras at the same place (zero baseline)")
    return cam, Tc


def _obstacles(top: _Tab, label: str) -> list[Obstacle]:
    """The ``[[obstacle]]`` tables: boxes and cylinders, each with a unique name."""
    obstacles = []
    raw_obs = top.get("obstacle", [])
    if not isinstance(raw_obs, list):
        raise top.err("obstacle", "expected an array of tables ([[obstacle]])")
    names: set[str] = set()
    for i, o in enumerate(raw_obs):
        ot = _Tab(o, label, f"obstacle[{i}].")
        oname = ot.text("name", pattern=r"[\w .\-]{1,64}")
        if oname in names:
            raise ot.err("name", f"duplicate obstacle name {oname!r}")
        names.add(oname)
        shape = ot.text("shape")
        T = _pose(ot, "center_mm", "rpy_deg")
        if shape == "box":
            size = ot.vec("size_mm", 3) / 1000.0
            if np.any(size <= 0):
                raise ot.err("size_mm", "every edge must be > 0")
            obstacles.append(Obstacle(oname, "box", T, size=size))
        elif shape == "cylinder":
            r = ot.num("radius_mm", lo=0.0, strict_lo=True) / 1000.0
            ln = ot.num("length_mm", lo=0.0, strict_lo=True) / 1000.0
            obstacles.append(Obstacle(oname, "cylinder", T, radius=r, length=ln))
        else:
            raise ot.err("shape", f"expected 'box' or 'cylinder', got {shape!r}")
        ot.done()
    return obstacles


def _motion(mt: _Tab) -> Motion:
    """The ``[motion]`` table: speeds, accelerations, settle time, the RTDE handshake."""
    motion = Motion(
        linear_speed=mt.num("linear_speed_mm_s", lo=1.0, hi=1000.0) / 1000.0,
        linear_accel=mt.num("linear_accel_mm_s2", lo=1.0, hi=5000.0) / 1000.0,
        joint_speed=math.radians(mt.num("joint_speed_deg_s", lo=1.0, hi=180.0)),
        joint_accel=math.radians(mt.num("joint_accel_deg_s2", lo=1.0, hi=800.0)),
        settle_s=mt.num("settle_s", 0.5, lo=0.0, hi=60.0),
        handshake_register=mt.integer("handshake_register", 24, lo=0, hi=47),
        measure_timeout_s=mt.num("measure_timeout_s", 30.0, lo=0.1, hi=3600.0),
        passes=mt.integer("passes", 1, lo=1, hi=100),
    )
    if 0 < motion.handshake_register < 24:
        raise mt.err(
            "handshake_register",
            "RTDE leaves registers 24-47 to external clients; use 24-47 or 0 (none)",
        )
    mt.done()
    return motion


def _planner(pt: _Tab) -> PlannerSettings:
    """The optional ``[planner]`` table: clearances, leg steps, bins, lines of sight."""
    planner = PlannerSettings(
        clearance=pt.num("clearance_mm", 10.0, lo=0.0, hi=500.0) / 1000.0,
        leg_step=pt.num("leg_step_mm", 10.0, lo=0.5, hi=100.0) / 1000.0,
        leg_step_rot=math.radians(pt.num("leg_step_deg", 2.0, lo=0.1, hi=20.0)),
        continuity_max=math.radians(pt.num("continuity_max_deg", 6.0, lo=0.1, hi=45.0)),
        joint_step=math.radians(pt.num("joint_step_deg", 3.0, lo=0.1, hi=20.0)),
        bins=pt.integer("bins", 12, lo=2, hi=360),
        sight_radius=pt.num("sight_radius_mm", 15.0, lo=0.0, hi=200.0) / 1000.0,
        sight_stop=pt.num("sight_stop_mm", 90.0, lo=0.0, hi=1000.0) / 1000.0,
        linear_preference=pt.num("linear_preference", 3.0, lo=0.0, hi=1000.0),
    )
    pt.done()
    return planner
