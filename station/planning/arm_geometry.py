"""The collision geometry of every built-in UR arm: meshes where they exist, else capsules.

:func:`arm_geometry` gives, for a built-in arm, its links' collision shapes as placed by the
joint angles (frames in the robot's DH base frame, the controller's base frame):

- **Meshes** (``ur3``, ``ur5``, ``ur10``): the STL collision meshes of ``ur_description`` in
  the package example-robot-data, placed by the URDF's joint origins.  The URDF's
  ``base_link`` is the DH base turned 180° about z (notes/ur5.md); the joint angles are the
  same.  The flange is ``tool0``, whose constant offset from the DH flange is computed from
  the two models (zero up to rounding: ``tests/identify/test_ur_models.py``).
- **Capsules** (the e-Series: ``ur3e``, ``ur5e``, ``ur10e``, ``ur16e``, ``ur20``, ``ur30``,
  whose meshes example-robot-data does not carry): one capsule per link part, on lines built
  from the arm's DH table (:data:`UR_CAPSULES` says which parts and which radii).

Both name their links as ur_description does (``base_link`` … ``wrist_3_link``), so the
pairs ur_description's SRDF never checks (adjacent links and the wrist links among
themselves, ``ur5.srdf``; the same structure on every UR arm) apply to either.

The capsule model
-----------------
A UR arm's links lie off the DH lines: the upper arm runs beside the plane of the base axis
at the *shoulder offset*, the forearm at the *elbow offset* (both along the parallel axes 2–4,
which the DH table folds into ``d4``).  ``UR_CAPSULES`` takes them from UR's own
``Universal_Robots_ROS2_Description`` (``config/<arm>/physical_parameters.yaml``,
``offsets``), where they place the arm's meshes.  The parts, each a segment with a radius:

====================  =========================================================  ==========
link                  segment                                                    radius
====================  =========================================================  ==========
base_link             the base axis from the table to the shoulder (z 0 … d1)    ``base``
shoulder_link         axis 2 from the base axis to the shoulder offset           ``upper``
upper_arm_link        axis 2 (the same, turning with joint 2), the tube from     ``upper``
                      shoulder to elbow at the shoulder offset; axis 3 from the
                      shoulder offset to the elbow offset (the elbow housing)    ``elbow``
forearm_link          the elbow housing again (turning with joint 3);            ``elbow``
                      the tube from elbow to wrist 1 at the elbow offset         ``wrist``
wrist_1_link          axis 4 from the elbow offset to axis 5 (d4)                ``wrist``
wrist_2_link          axis 5 from axis 4 to axis 6 (d5)                          ``wrist``
wrist_3_link          axis 6 from axis 5 to the flange (d6)                      ``flange``
====================  =========================================================  ==========

The radii are *stated*, not measured on the e-Series arms (their meshes are not here): for
the CB3 arms they are the smallest 5 mm step that holds every vertex of the link's
example-robot-data collision mesh in the link's own capsules (measured, and checked by
``tests/station/test_planning_arms.py``); an e-Series arm takes those of the CB3 arm with the
same footprint (UR3e ← UR3, UR5e ← UR5, UR10e and UR16e ← UR10: base Ø 128, 149, 190 mm) plus
10 mm, and the UR20 and UR30 (base Ø 245 mm) those of the UR10 scaled by 245/190, plus 10 mm.
A capsule model is conservative where the arm is thinner than its capsules.

:class:`ArmGeometry` holds no fcl objects (those are scratch of each
:class:`~.collision.CollisionWorld`); it is cached per arm.
"""

from __future__ import annotations

import importlib.metadata
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import BUILTIN_ROBOTS, RobotModel, builtin_robot, chain
from ...identify.transforms import make_T, rot_z, rpy_to_R

F = NDArray[np.float64]

LINKS = (
    "base_link",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
T_DHBASE_URDFBASE = make_T(rot_z(np.pi), np.zeros(3))
#: The arms example-robot-data has URDFs with collision meshes of.
MESH_ARMS = ("ur3", "ur5", "ur10")


@dataclass(frozen=True)
class CapsuleArm:
    """The capsule model's numbers for one arm (m): offsets of the links from the DH lines
    and the stated radii (see the module docstring for where each comes from)."""

    shoulder_offset: float  # upper arm beside the base axis' plane, along axis 2
    elbow_offset: float  # forearm, along axis 3
    base: float  # the base column
    upper: float  # shoulder housing and upper arm
    elbow: float  # elbow housing
    wrist: float  # forearm tube, wrists 1 and 2
    flange: float  # wrist 3
    radii_source: str


_CB3 = "covers every vertex of example-robot-data's collision mesh of the link (measured)"
_E = "the radii of the CB3 {} (same footprint, base Ø {} mm) + 10 mm"
_BIG = "the UR10's radii × 245/190 (base Ø 245 mm against 190 mm) + 10 mm"

#: The capsule model of every built-in arm: ``shoulder_offset`` and ``elbow_offset`` from UR's
#: Universal_Robots_ROS2_Description (``config/<arm>/physical_parameters.yaml``), radii
#: stated as ``radii_source`` says.  The CB3 arms plan with their meshes; their capsules are
#: the reference the e-Series radii are derived from.
UR_CAPSULES: dict[str, CapsuleArm] = {
    "ur3": CapsuleArm(0.1198, 0.0275, 0.105, 0.080, 0.065, 0.055, 0.040, _CB3),
    "ur5": CapsuleArm(0.13585, 0.0165, 0.115, 0.090, 0.065, 0.065, 0.045, _CB3),
    "ur10": CapsuleArm(0.220941, 0.049042, 0.100, 0.120, 0.090, 0.085, 0.050, _CB3),
    "ur3e": CapsuleArm(0.120, 0.027, 0.115, 0.090, 0.075, 0.065, 0.050, _E.format("UR3", 128)),
    "ur5e": CapsuleArm(0.138, 0.007, 0.125, 0.100, 0.075, 0.075, 0.055, _E.format("UR5", 149)),
    "ur10e": CapsuleArm(0.1762, 0.0393, 0.110, 0.130, 0.100, 0.095, 0.060, _E.format("UR10", 190)),
    "ur16e": CapsuleArm(0.176, 0.040, 0.110, 0.130, 0.100, 0.095, 0.060, _E.format("UR10", 190)),
    "ur20": CapsuleArm(0.260, 0.043, 0.140, 0.165, 0.130, 0.120, 0.075, _BIG),
    "ur30": CapsuleArm(0.260, 0.043, 0.140, 0.165, 0.130, 0.120, 0.075, _BIG),
}


@dataclass(frozen=True, eq=False)
class Shape:
    """One collision shape of a link: a mesh file, or a capsule (``radius``, ``length`` along
    its local z, centred), placed at ``T_link_shape`` in its link's frame; ``centre`` and
    ``bound`` (m) are a sphere around it in the shape's frame, for the broad phase."""

    link: int  # index into ArmGeometry.links
    T_link_shape: F
    centre: F
    bound: float
    mesh: Path | None = None
    radius: float = 0.0
    length: float = 0.0


@dataclass(frozen=True, eq=False)
class ArmGeometry:
    """The collision shapes of one arm and how the joint angles place its links.

    ``link_frames(q)`` maps joints (m, 6) rad to ``T_dhbase_link`` (m, 7, 4, 4);
    ``T_last_flange`` is the DH flange in the last link's frame.
    """

    robot: str
    kind: str  # "meshes" or "capsules"
    links: tuple[str, ...]
    shapes: tuple[Shape, ...]
    disabled: frozenset[frozenset[str]]
    link_frames: Callable[[F], F]
    T_last_flange: F
    source: str  # one line: where the shapes come from

    def describe(self) -> str:
        """One line for documents and summaries."""
        return f"{self.robot}: {self.kind} ({self.source})"


def arm_geometry(robot: RobotModel | str) -> ArmGeometry:
    """The collision geometry of a built-in UR arm (by model or name; cached).

    Raises
    ------
    InputError
        Not a built-in arm.
    """
    name = (robot if isinstance(robot, str) else robot.name).strip().lower()
    if name not in BUILTIN_ROBOTS:
        raise InputError(
            f"robot {name!r}: no collision geometry (built-in arms: {', '.join(BUILTIN_ROBOTS)})"
        )
    return _mesh_geometry(name) if name in MESH_ARMS else capsule_geometry(name)


# ------------------------------------------------------------------ meshes (example-robot-data)


@dataclass(frozen=True, eq=False)
class UrdfChain:
    """The serial chain of the URDF: per link, its parent joint's origin and axis."""

    origins: F  # (7, 4, 4): T_parent_joint at q = 0 (origins[0] = identity for base_link)
    axes: F  # (7, 3): joint axes in the joint frame (axes[0] unused)
    mesh_files: tuple[Path, ...]  # collision mesh per link
    T_link_mesh: F  # (7, 4, 4): collision origin inside each link
    disabled: frozenset[frozenset[str]]  # SRDF pairs never checked
    T_wrist3_tool0: F  # (4, 4)


def _share() -> Path:
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        raise InputError(
            "example-robot-data is not installed: pip install example-robot-data"
        ) from None
    for f in files:
        s = str(f)
        if s.endswith("ur_description/urdf/ur5_robot.urdf"):
            urdf = Path(str(f.locate()))
            return urdf.parents[4]  # …/cmeel.prefix/share
    raise InputError("example-robot-data has no ur_description/urdf/ur5_robot.urdf")


def _origin(el: ET.Element | None) -> F:
    if el is None:
        return np.eye(4)
    xyz = np.array([float(v) for v in el.get("xyz", "0 0 0").split()])
    rpy = np.array([float(v) for v in el.get("rpy", "0 0 0").split()])
    return make_T(rpy_to_R(rpy[0], rpy[1], rpy[2]), xyz)


@cache
def urdf_chain(name: str = "ur5") -> UrdfChain:
    """Parse ``<name>_robot.urdf`` of example-robot-data and ``ur5.srdf`` (cached).

    ur_description ships an SRDF for the UR5 only; its pairs (adjacent links, the wrist links
    among themselves) are the same structure on the UR3 and the UR10.
    """
    if name not in MESH_ARMS:
        raise InputError(f"example-robot-data has no collision meshes of the {name}")
    share = _share()
    desc = share / "example-robot-data" / "robots" / "ur_description"
    root = ET.parse(desc / "urdf" / f"{name}_robot.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}  # type: ignore[union-attr]
    links = {lk.get("name"): lk for lk in root.findall("link")}
    origins = np.tile(np.eye(4), (7, 1, 1))
    axes = np.zeros((7, 3))
    meshes = []
    T_mesh = np.tile(np.eye(4), (7, 1, 1))
    for i, lname in enumerate(LINKS):
        if i > 0:
            j = joints[lname]
            if j.find("parent").get("link") != LINKS[i - 1]:  # type: ignore[union-attr]
                raise InputError(f"{name}_robot.urdf: unexpected parent of {lname}")
            origins[i] = _origin(j.find("origin"))
            axes[i] = [float(v) for v in j.find("axis").get("xyz").split()]  # type: ignore[union-attr]
        col = links[lname].find("collision")
        mesh = col.find("geometry/mesh")  # type: ignore[union-attr]
        uri = mesh.get("filename")  # type: ignore[union-attr]
        meshes.append(share / uri.removeprefix("package://"))  # type: ignore[union-attr]
        T_mesh[i] = _origin(col.find("origin"))  # type: ignore[union-attr]
    tool = next(j for j in root.findall("joint") if j.find("child").get("link") == "tool0")  # type: ignore[union-attr]
    srdf = ET.parse(desc / "srdf" / "ur5.srdf").getroot()
    disabled = frozenset(
        frozenset((d.get("link1"), d.get("link2"))) for d in srdf.iter("disable_collisions")
    )
    return UrdfChain(origins, axes, tuple(meshes), T_mesh, disabled, _origin(tool.find("origin")))  # type: ignore[arg-type]


def urdf_link_frames(q: F, name: str = "ur5") -> F:
    """``T_dhbase_link`` of the 7 URDF links for configurations ``q`` (m, 6) rad → (m, 7, 4, 4)."""
    ch = urdf_chain(name)
    q = np.atleast_2d(q)
    m = q.shape[0]
    out = np.empty((m, 7, 4, 4))
    T = np.broadcast_to(T_DHBASE_URDFBASE, (m, 4, 4)).copy()
    out[:, 0] = T
    for i in range(1, 7):
        R = _axis_rot(ch.axes[i], q[:, i - 1])
        T = T @ ch.origins[i] @ R
        out[:, i] = T
    return out


def urdf_tool0_frames(q: F, name: str = "ur5") -> F:
    """``T_dhbase_tool0`` from the URDF chain (for checking it against the DH model)."""
    return urdf_link_frames(q, name)[:, 6] @ urdf_chain(name).T_wrist3_tool0


def _axis_rot(axis: F, a: F) -> F:
    k = axis / np.linalg.norm(axis)
    c, s = np.cos(a), np.sin(a)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + s[:, None, None] * K + (1 - c)[:, None, None] * (K @ K)
    return make_T(R, np.zeros(3))


def read_stl(path: Path) -> tuple[F, NDArray[np.int32]]:
    """Vertices (3k, 3) and triangles (k, 3) of a binary or ASCII STL file."""
    raw = path.read_bytes()
    if len(raw) >= 84:
        n = int(np.frombuffer(raw, dtype="<u4", count=1, offset=80)[0])
        if 84 + 50 * n == len(raw):
            rec = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            tri = np.frombuffer(raw, dtype=rec, count=n, offset=84)["v"].astype(float)
            return tri.reshape(-1, 3), np.arange(3 * n, dtype=np.int32).reshape(-1, 3)
    words = raw.decode("ascii", errors="replace").split()
    idx = [i for i, w in enumerate(words) if w == "vertex"]
    vs = np.array([[float(words[i + 1]), float(words[i + 2]), float(words[i + 3])] for i in idx])
    if len(vs) == 0 or len(vs) % 3:
        raise InputError(f"{path}: not a readable STL mesh")
    return vs, np.arange(len(vs), dtype=np.int32).reshape(-1, 3)


@cache
def mesh_data(path: str) -> tuple[F, NDArray[np.int32]]:
    """:func:`read_stl` of ``path``, read once per process."""
    return read_stl(Path(path))


@cache
def _T_tool0_flange_cached(name: str) -> bytes:
    """Constant transform from URDF tool0 to the DH flange (computed from both models)."""
    q = np.array([[0.3, -1.1, 1.4, -0.7, 0.9, 0.5]])
    T_flange = builtin_robot(name).fk(q)[0]
    T_tool0 = urdf_tool0_frames(q, name)[0]
    return (np.linalg.inv(T_tool0) @ T_flange).tobytes()


def T_tool0_flange(name: str = "ur5") -> F:
    """The DH flange in the URDF's ``tool0`` frame of arm ``name``."""
    return np.frombuffer(_T_tool0_flange_cached(name)).reshape(4, 4).copy()


@cache
def _mesh_geometry(name: str) -> ArmGeometry:
    ch = urdf_chain(name)
    shapes = []
    for i, path in enumerate(ch.mesh_files):
        v, _ = mesh_data(str(path))
        c = (v.min(0) + v.max(0)) / 2
        shapes.append(
            Shape(i, ch.T_link_mesh[i], c, float(np.linalg.norm(v - c, axis=1).max()), mesh=path)
        )
    return ArmGeometry(
        robot=name,
        kind="meshes",
        links=LINKS,
        shapes=tuple(shapes),
        disabled=ch.disabled,
        link_frames=lambda q: urdf_link_frames(q, name),
        T_last_flange=ch.T_wrist3_tool0 @ T_tool0_flange(name),
        source=f"example-robot-data ur_description {name}_robot.urdf collision meshes",
    )


# ------------------------------------------------------------------ capsules from the DH table


def capsule_segments(name: str) -> list[tuple[int, F, F, float]]:
    """The capsule model of arm ``name``: ``(link, p0, p1, radius)`` per part, the segment's
    ends in the link's DH frame (link 0: the base frame, link i: DH frame i), m."""
    r = builtin_robot(name)
    caps = UR_CAPSULES[name]
    assert r.dh is not None
    d1, d4, d5, d6 = (r.dh["d"][k] for k in (0, 3, 4, 5))
    a2, a3 = r.dh["a"][1], r.dh["a"][2]
    so, eo = caps.shoulder_offset, caps.elbow_offset
    parts = [
        (0, (0, 0, 0), (0, 0, d1), caps.base),
        (1, (0, 0, 0), (0, 0, so), caps.upper),
        (2, (-a2, 0, 0), (-a2, 0, so), caps.upper),
        (2, (-a2, 0, so), (0, 0, so), caps.upper),
        (2, (0, 0, eo), (0, 0, so), caps.elbow),
        (3, (-a3, 0, eo), (-a3, 0, so), caps.elbow),
        (3, (-a3, 0, eo), (0, 0, eo), caps.wrist),
        (4, (0, -(d4 - eo), 0), (0, 0, 0), caps.wrist),
        (5, (0, d5, 0), (0, 0, 0), caps.wrist),
        (6, (0, 0, -d6), (0, 0, 0), caps.flange),
    ]
    return [(k, np.array(a, float), np.array(b, float), float(rad)) for k, a, b, rad in parts]


def dh_link_frames(robot: RobotModel, q: F) -> F:
    """``T_base_link`` of the base (identity) and DH frames 1…6 for joints ``q`` (m, 6)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    _, frames = chain(robot, q, return_frames=True)
    out = np.empty((q.shape[0], robot.n_joints + 1, 4, 4))
    out[:, 0] = np.eye(4)
    out[:, 1:] = frames @ robot.links[1:]
    return out


def _segment_pose(p0: F, p1: F) -> tuple[F, float]:
    """Pose of a capsule on segment p0→p1 (centred, local z along it) and its length."""
    d = p1 - p0
    length = float(np.linalg.norm(d))
    z = d / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0.0, 0.0])
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    return make_T(np.stack([x, np.cross(z, x), z], axis=1), (p0 + p1) / 2), length


@cache
def capsule_geometry(name: str) -> ArmGeometry:
    """The capsule model of arm ``name`` (any built-in arm; the e-Series plan with it)."""
    robot = builtin_robot(name)
    caps = UR_CAPSULES[name]
    shapes = []
    for link, p0, p1, rad in capsule_segments(name):
        T, length = _segment_pose(p0, p1)
        shapes.append(Shape(link, T, np.zeros(3), length / 2 + rad, radius=rad, length=length))
    return ArmGeometry(
        robot=name,
        kind="capsules",
        links=LINKS,
        shapes=tuple(shapes),
        disabled=urdf_chain("ur5").disabled,
        link_frames=lambda q: dh_link_frames(robot, q),
        T_last_flange=np.eye(4),
        source=(
            f"capsules on the DH lines, shoulder/elbow offsets {caps.shoulder_offset * 1000:g}/"
            f"{caps.elbow_offset * 1000:g} mm, radii base {caps.base * 1000:g}, upper arm "
            f"{caps.upper * 1000:g}, elbow {caps.elbow * 1000:g}, forearm and wrist "
            f"{caps.wrist * 1000:g}, flange {caps.flange * 1000:g} mm: {caps.radii_source}"
        ),
    )


__all__ = [
    "ArmGeometry",
    "CapsuleArm",
    "LINKS",
    "MESH_ARMS",
    "Shape",
    "UR_CAPSULES",
    "arm_geometry",
    "capsule_geometry",
    "capsule_segments",
]
