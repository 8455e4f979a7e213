"""Collision checking of the UR5 in its cell with python-fcl and the example-robot-data meshes.

The robot's collision geometry is the STL collision meshes of ``ur_description`` (package
example-robot-data).  Its URDF uses the ur_description frames: the URDF ``base_link`` is the
DH base turned 180° about z (notes/ur5.md), and the joint angles are the same.  Link frames are
computed here from the URDF's joint origins, vectorised over configurations, then placed in
the world with ``T_world_base · Rz(π)``.

Checked pairs
-------------
- self collision: every link pair except those the package's SRDF disables (adjacent or
  never-touching links);
- the smart-target body (a box on the flange) against every link but wrist 3, its mount;
- every link and the target body against every obstacle and the table (the base link
  excepted for the table), with obstacles and the table grown by ``planner.clearance``.

:class:`CollisionWorld` is scratch (pinocchio's ``data``): it owns fcl objects whose poses it
sets per query.  Build one per cell and thread.
"""

from __future__ import annotations

import importlib.metadata
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache, lru_cache
from pathlib import Path

import fcl
import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import ur5
from ...identify.transforms import make_T, rot_z, rpy_to_R
from .cell import Cell, Obstacle

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
TARGET = "target"
TABLE = "table"
T_DHBASE_URDFBASE = make_T(rot_z(np.pi), np.zeros(3))


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


@lru_cache(maxsize=1)
def ur5_chain() -> UrdfChain:
    """Parse ur5_robot.urdf and ur5.srdf of example-robot-data (cached)."""
    share = _share()
    desc = share / "example-robot-data" / "robots" / "ur_description"
    root = ET.parse(desc / "urdf" / "ur5_robot.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}  # type: ignore[union-attr]
    links = {lk.get("name"): lk for lk in root.findall("link")}
    origins = np.tile(np.eye(4), (7, 1, 1))
    axes = np.zeros((7, 3))
    meshes = []
    T_mesh = np.tile(np.eye(4), (7, 1, 1))
    for i, name in enumerate(LINKS):
        if i > 0:
            j = joints[name]
            if j.find("parent").get("link") != LINKS[i - 1]:  # type: ignore[union-attr]
                raise InputError(f"ur5_robot.urdf: unexpected parent of {name}")
            origins[i] = _origin(j.find("origin"))
            axes[i] = [float(v) for v in j.find("axis").get("xyz").split()]  # type: ignore[union-attr]
        col = links[name].find("collision")
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


def link_frames(q: F) -> F:
    """``T_dhbase_link`` of the 7 UR5 links for configurations ``q`` (m, 6) rad → (m, 7, 4, 4)."""
    ch = ur5_chain()
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


def tool0_frames(q: F) -> F:
    """``T_dhbase_tool0`` from the URDF chain (for checking it against the DH model)."""
    return link_frames(q)[:, 6] @ ur5_chain().T_wrist3_tool0


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
def _mesh_data(path: str) -> tuple[F, NDArray[np.int32]]:
    return read_stl(Path(path))


def _bvh(path: Path) -> fcl.BVHModel:
    v, t = _mesh_data(str(path))
    m = fcl.BVHModel()
    m.beginModel(len(v), len(t))
    m.addSubModel(v, t)
    m.endModel()
    return m


def _tf(T: F) -> fcl.Transform:
    return fcl.Transform(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def obstacle_geometry(o: Obstacle, grow: float = 0.0) -> fcl.CollisionGeometry:
    """fcl geometry of an obstacle grown by ``grow`` metres on every side."""
    if o.shape == "box":
        assert o.size is not None
        return fcl.Box(*(o.size + 2 * grow))
    return fcl.Cylinder(o.radius + grow, o.length + 2 * grow)


class CollisionWorld:
    """The robot, its target body, the obstacles and the table of one cell, in fcl."""

    def __init__(self, cell: Cell) -> None:
        ch = ur5_chain()
        self.cell = cell
        g = cell.planner.clearance
        self._T_world_dhbase = cell.T_world_base
        self._T_link_mesh = ch.T_link_mesh
        self.moving: list[tuple[str, fcl.CollisionObject]] = [
            (name, fcl.CollisionObject(_bvh(path)))
            for name, path in zip(LINKS, ch.mesh_files, strict=True)
        ]
        self.moving.append((TARGET, fcl.CollisionObject(fcl.Box(*cell.target_body_size))))
        self._T_wrist3_body = (
            ch.T_wrist3_tool0 @ _T_tool0_flange() @ cell.T_flange_target @ cell.T_target_body
        )
        # static: obstacles (grown) and the table, plus exact copies for line-of-sight tests
        self.static: list[tuple[str, fcl.CollisionObject]] = []
        self.sight_static: list[tuple[str, fcl.CollisionObject]] = []
        for o in cell.obstacles:
            self.static.append(
                (o.name, fcl.CollisionObject(obstacle_geometry(o, g), _tf(o.T_world_obstacle)))
            )
            self.sight_static.append(
                (o.name, fcl.CollisionObject(obstacle_geometry(o), _tf(o.T_world_obstacle)))
            )
        size = np.r_[cell.table_max_xy - cell.table_min_xy, cell.table_thickness]
        ctr = np.r_[
            (cell.table_max_xy + cell.table_min_xy) / 2, cell.table_top_z - cell.table_thickness / 2
        ]
        self.static.append(
            (TABLE, fcl.CollisionObject(fcl.Box(*size), _tf(make_T(np.eye(3), ctr + [0, 0, g]))))
        )
        self.sight_static.append(
            (TABLE, fcl.CollisionObject(fcl.Box(*size), _tf(make_T(np.eye(3), ctr))))
        )
        names = [n for n, _ in self.moving]
        self.self_pairs = [
            (i, j)
            for i in range(len(names))
            for j in range(i + 1, len(names))
            if j != i + 1
            and frozenset((names[i], names[j])) not in ch.disabled
            and not (names[j] == TARGET and names[i] == "wrist_3_link")
        ]
        self.static_pairs = [
            (i, k)
            for i in range(len(names))
            for k, (sname, _) in enumerate(self.static)
            if not (sname == TABLE and names[i] == "base_link")
        ]
        self._req = fcl.CollisionRequest()
        # broadphase: a bounding sphere per object, tested for all samples at once in numpy
        centres, radii = [], []
        for path in ch.mesh_files:
            v, _ = _mesh_data(str(path))
            c = (v.min(0) + v.max(0)) / 2
            centres.append(c)
            radii.append(float(np.linalg.norm(v - c, axis=1).max()))
        centres.append(np.zeros(3))
        radii.append(float(np.linalg.norm(cell.target_body_size) / 2))
        self._c_local = np.array(centres)  # (8, 3)
        self._r = np.array(radii) + 1e-3
        s_c, s_r = [], []
        for o in cell.obstacles:
            s_c.append(o.T_world_obstacle[:3, 3])
            if o.shape == "box":
                assert o.size is not None
                s_r.append(float(np.linalg.norm(o.size + 2 * g) / 2))
            else:
                s_r.append(float(np.hypot(o.radius + g, o.length / 2 + g)))
        self._s_c = np.array(s_c).reshape(-1, 3)
        self._s_r = np.array(s_r) + 1e-3
        self._table_lo = np.r_[cell.table_min_xy, cell.table_top_z - cell.table_thickness] - 1e-3
        self._table_hi = np.r_[cell.table_max_xy, cell.table_top_z + g] + 1e-3
        self._pairs: list[tuple[int, fcl.CollisionObject, str]] = [
            (i, self.moving[j][1], f"{names[i]}|{names[j]}") for i, j in self.self_pairs
        ] + [
            (i, self.static[k][1], f"{names[i]}|{self.static[k][0]}") for i, k in self.static_pairs
        ]

    def frames(self, q: F) -> F:
        """``T_world_x`` of the 7 links' meshes and the target body, (m, 8, 4, 4)."""
        L = self._T_world_dhbase @ link_frames(q)
        out = np.empty((L.shape[0], 8, 4, 4))
        out[:, :7] = L @ self._T_link_mesh
        out[:, 7] = L[:, 6] @ self._T_wrist3_body
        return out

    def _candidates(self, Tall: F) -> NDArray[np.bool_]:
        """Pairs whose bounding spheres touch, per sample: (m, n_pairs) bool."""
        C = np.einsum("mkij,kj->mki", Tall[..., :3, :3], self._c_local) + Tall[..., :3, 3]
        out = []
        for i, j in self.self_pairs:
            d = np.linalg.norm(C[:, i] - C[:, j], axis=1)
            out.append(d <= self._r[i] + self._r[j])
        n_obs = len(self._s_c)
        for i, k in self.static_pairs:
            if k < n_obs:
                d = np.linalg.norm(C[:, i] - self._s_c[k], axis=1)
                out.append(d <= self._r[i] + self._s_r[k])
            else:  # the table: exact sphere-to-box distance
                e = np.maximum(np.maximum(self._table_lo - C[:, i], C[:, i] - self._table_hi), 0.0)
                out.append(np.linalg.norm(e, axis=1) <= self._r[i])
        return np.stack(out, axis=1)

    def _check(self, Tm: F, cand: NDArray[np.bool_], first_only: bool) -> list[str]:
        idx = np.flatnonzero(cand)
        if len(idx) == 0:
            return []
        placed: set[int] = set()
        hits: list[str] = []
        for p in idx:
            i, other, label = self._pairs[p]
            for o in (i, self.self_pairs[p][1] if p < len(self.self_pairs) else -1):
                if o >= 0 and o not in placed:
                    self.moving[o][1].setTransform(_tf(Tm[o]))
                    placed.add(o)
            if fcl.collide(self.moving[i][1], other, self._req, fcl.CollisionResult()):
                hits.append(label)
                if first_only:
                    break
        return hits

    def contacts(self, q: F, first_only: bool = True) -> list[list[str]]:
        """Colliding pairs per configuration, as ``"a|b"`` strings (empty list: free).

        Parameters
        ----------
        q : ndarray, shape (m, 6), rad
        first_only : bool
            Stop at the first colliding pair of each configuration.
        """
        Tall = self.frames(np.atleast_2d(q))
        cand = self._candidates(Tall)
        return [self._check(Tm, c, first_only) for Tm, c in zip(Tall, cand, strict=True)]

    def collides(self, q: F) -> NDArray[np.bool_]:
        """True per configuration (m, 6) that collides (self, obstacles or table)."""
        return np.array([bool(h) for h in self.contacts(q)], dtype=bool)

    def first_collision(self, q: F) -> int:
        """Index of a colliding configuration of a sequence (m, 6), or -1 when all are free.

        Samples are visited coarse to fine (every 16th first), so a colliding leg is
        usually refuted after a few checks.
        """
        Tall = self.frames(np.atleast_2d(q))
        cand = self._candidates(Tall)
        rows = np.flatnonzero(cand.any(axis=1))
        if len(rows) == 0:
            return -1
        order = np.argsort((rows % 16 != 0).astype(int), kind="stable")
        for n in rows[order]:
            if self._check(Tall[n], cand[n], True):
                return int(n)
        return -1

    def _place(self, Tm: F) -> None:
        for (_, obj), T in zip(self.moving, Tm, strict=True):
            obj.setTransform(_tf(T))

    def sight_blockers(self, q: F, p_from: F, p_to: F, radius: float) -> list[str | None]:
        """What blocks the beam from ``p_from`` to ``p_to`` (world, m) per configuration.

        The beam is a cylinder of ``radius``; it is tested against every robot link (the
        target body excepted) with the robot at ``q`` (m, 6), the obstacles and the table.

        Parameters
        ----------
        q : ndarray, shape (m, 6), rad
        p_from, p_to : ndarray, shape (m, 3), world, m

        Returns
        -------
        list of str or None
            The name of the first blocker, or None when the line of sight is clear.
        """
        q = np.atleast_2d(q)
        Tall = self.frames(q)
        out: list[str | None] = []
        for Tm, a, b in zip(Tall, p_from, p_to, strict=True):
            beam = _beam(a, b, radius)
            if beam is None:
                out.append(None)
                continue
            self._place(Tm)
            hit = None
            for name, obj in self.moving[:7] + self.sight_static:
                if fcl.collide(beam, obj, self._req, fcl.CollisionResult()):
                    hit = name
                    break
            out.append(hit)
        return out

    def static_sight_blocker(self, a: F, b: F, radius: float) -> str | None:
        """First obstacle or the table blocking the beam ``a``→``b`` (robot ignored)."""
        beam = _beam(a, b, radius)
        if beam is None:
            return None
        for name, obj in self.sight_static:
            if fcl.collide(beam, obj, self._req, fcl.CollisionResult()):
                return name
        return None


def _beam(a: F, b: F, radius: float) -> fcl.CollisionObject | None:
    d = b - a
    length = float(np.linalg.norm(d))
    if length < 1e-6:
        return None
    z = d / length
    x = np.cross(z, [1.0, 0.0, 0.0])
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    return fcl.CollisionObject(fcl.Cylinder(max(radius, 1e-4), length), _tf(make_T(R, (a + b) / 2)))


@lru_cache(maxsize=1)
def _T_tool0_flange_cached() -> bytes:
    """Constant transform from URDF tool0 to the DH flange (computed from both models)."""
    q = np.array([[0.3, -1.1, 1.4, -0.7, 0.9, 0.5]])
    T_flange = ur5().fk(q)[0]
    T_tool0 = tool0_frames(q)[0]
    return (np.linalg.inv(T_tool0) @ T_flange).tobytes()


def _T_tool0_flange() -> F:
    return np.frombuffer(_T_tool0_flange_cached()).reshape(4, 4).copy()
