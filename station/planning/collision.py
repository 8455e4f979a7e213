"""Collision checking of a UR arm in its cell with python-fcl.

The arm's collision shapes come from :mod:`.arm_geometry`: the STL collision meshes of
example-robot-data for the UR3, UR5 and UR10, a capsule model built from the DH table for the
e-Series arms.  Link frames are computed vectorised over configurations in the DH base frame,
then placed in the world with ``T_world_base``.

Checked pairs
-------------
- self collision: every pair of shapes on different links except adjacent links and those
  ur_description's SRDF disables (never-touching links);
- the smart-target body (a box on the flange) against every link but wrist 3, its mount;
- every shape and the target body against every obstacle and the table (the base link
  excepted for the table), with obstacles and the table grown by ``planner.clearance``.

:class:`CollisionWorld` is scratch (pinocchio's ``data``): it owns fcl objects whose poses it
sets per query.  Build one per cell and thread.
"""

from __future__ import annotations

import fcl
import numpy as np
from numpy.typing import NDArray

from ...identify.transforms import make_T
from .arm_geometry import (
    LINKS,
    T_DHBASE_URDFBASE,
    ArmGeometry,
    Shape,
    UrdfChain,
    arm_geometry,
    mesh_data,
    read_stl,
    urdf_chain,
    urdf_link_frames,
    urdf_tool0_frames,
)
from .cell import Cell, Obstacle

F = NDArray[np.float64]

TARGET = "target"
TABLE = "table"

__all__ = [
    "LINKS",
    "T_DHBASE_URDFBASE",
    "TABLE",
    "TARGET",
    "CollisionWorld",
    "UrdfChain",
    "link_frames",
    "obstacle_geometry",
    "read_stl",
    "tool0_frames",
    "ur5_chain",
]


def ur5_chain() -> UrdfChain:
    """The UR5's URDF chain of example-robot-data (:func:`.arm_geometry.urdf_chain`)."""
    return urdf_chain("ur5")


def link_frames(q: F) -> F:
    """``T_dhbase_link`` of the 7 UR5 links for configurations ``q`` (m, 6) rad → (m, 7, 4, 4)."""
    return urdf_link_frames(q, "ur5")


def tool0_frames(q: F) -> F:
    """``T_dhbase_tool0`` of the UR5 from the URDF chain (checked against the DH model)."""
    return urdf_tool0_frames(q, "ur5")


def _bvh(path: str) -> fcl.BVHModel:
    v, t = mesh_data(path)
    m = fcl.BVHModel()
    m.beginModel(len(v), len(t))
    m.addSubModel(v, t)
    m.endModel()
    return m


def _shape_geometry(s: Shape) -> fcl.CollisionGeometry:
    if s.mesh is not None:
        return _bvh(str(s.mesh))
    if s.length < 1e-9:
        return fcl.Sphere(s.radius)
    return fcl.Capsule(s.radius, s.length)


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

    def __init__(self, cell: Cell, geometry: ArmGeometry | None = None) -> None:
        geom = arm_geometry(cell.robot) if geometry is None else geometry
        self.cell = cell
        self.geometry = geom
        g = cell.planner.clearance
        self._T_world_dhbase = cell.T_world_base
        self._link_frames = geom.link_frames
        self._shape_link = np.array([sh.link for sh in geom.shapes])
        self._T_link_shape = np.array([sh.T_link_shape for sh in geom.shapes])
        self._last = len(geom.links) - 1
        self.n_arm = len(geom.shapes)  # the arm's shapes come first in ``moving``
        self.moving: list[tuple[str, fcl.CollisionObject]] = [
            (geom.links[sh.link], fcl.CollisionObject(_shape_geometry(sh))) for sh in geom.shapes
        ]
        self.moving.append((TARGET, fcl.CollisionObject(fcl.Box(*cell.target_body_size))))
        self._T_last_body = geom.T_last_flange @ cell.T_flange_target @ cell.T_target_body
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
        # the link of each moving object (the target counts as the link after the last)
        link = [*self._shape_link.tolist(), self._last + 1]
        self.self_pairs = [
            (i, j)
            for i in range(len(names))
            for j in range(i + 1, len(names))
            if abs(link[j] - link[i]) > 1  # other links, not adjacent (target: not on wrist 3)
            and frozenset((names[i], names[j])) not in geom.disabled
        ]
        self.static_pairs = [
            (i, k)
            for i in range(len(names))
            for k, (sname, _) in enumerate(self.static)
            if not (sname == TABLE and names[i] == "base_link")
        ]
        self._req = fcl.CollisionRequest()
        # broadphase: a bounding sphere per object, tested for all samples at once in numpy
        centres = [sh.centre for sh in geom.shapes]
        radii = [sh.bound for sh in geom.shapes]
        centres.append(np.zeros(3))
        radii.append(float(np.linalg.norm(cell.target_body_size) / 2))
        self._c_local = np.array(centres)  # (n_arm + 1, 3)
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
        """``T_world_x`` of the arm's shapes and the target body, (m, n_arm + 1, 4, 4)."""
        L = self._T_world_dhbase @ self._link_frames(q)
        out = np.empty((L.shape[0], self.n_arm + 1, 4, 4))
        out[:, : self.n_arm] = L[:, self._shape_link] @ self._T_link_shape
        out[:, self.n_arm] = L[:, self._last] @ self._T_last_body
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
            for name, obj in self.moving[: self.n_arm] + self.sight_static:
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
