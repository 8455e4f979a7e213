"""``plan --iso9283``: the ISO 9283 test cube's five poses, visited in cycles after the loop.

ISO 9283 (§6.2) measures pose accuracy and repeatability at five points of a cube in the
part of the workspace used most: P1 at the cube's centre, P2–P5 on its diagonal plane
C1–C2–C7–C8, each 10 % of the plane's diagonal in from its corner, all with one tool
orientation, visited in cycles P1 → P2 → … → P5.  Here the cube is centred where the plan's
loop measures (the mean of its target positions; else the middle of the cell's
``[workspace]`` box) with its edges along the world axes; the tool orientation faces the
stereo camera from P1 (the smart target must be seen at every point).  The largest cube
(from half the box's smallest side down to 10 cm) whose five poses are reachable, inside the
limits, collision-free and seen by both cameras, with collision-free joint moves between
them and back into the loop, is kept.

The poses are named ``ISO_P1_C01`` … (point, cycle): the report's ISO 9283 section groups
the visits of each point by that name (:func:`~..reporting.iso9283.iso_point`), on any arm.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.transforms import inv_T, make_T
from ..hardware.legs import Leg
from ..reporting.iso9283 import iso_pose_name
from .cell import Cell
from .collision import CollisionWorld
from .ik_ur import ik_ur, within_limits
from .planner import PlannedPose, PlanResult, feasible_configurations, joint_leg_ok, trap_time
from .sight import pose_sight

F = NDArray[np.float64]

#: ISO 9283 runs 30 cycles; ``plan --iso9283`` without a number runs this many.
DEFAULT_CYCLES = 5


def cube_points(centre: F, side: float) -> F:
    """P1 … P5 (5, 3), world frame: the centre, then the four points of the diagonal plane
    C1–C2–C7–C8, 10 % of its diagonal in from each corner (ISO 9283 §6.2)."""
    h = side / 2
    corners = centre + np.array([[-h, -h, -h], [-h, h, -h], [h, h, h], [h, -h, h]])
    opposite = corners[[2, 3, 0, 1]]
    return np.vstack([centre, corners + 0.1 * (opposite - corners)])


def facing_camera(cell: Cell, point: F) -> F:
    """The target orientation ``R_world_target`` whose marker faces the stereo camera's
    midpoint from ``point``, its x axis horizontal."""
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    z = mid - point
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _targets(R: F, points: F) -> F:
    """The five target poses ``T_world_target``: one orientation ``R`` at every point."""
    return np.stack([make_T(R, p) for p in points])


def with_iso_cycles(res: PlanResult, cycles: int = DEFAULT_CYCLES) -> PlanResult:
    """``res`` with the ISO cube's five poses visited ``cycles`` times after its loop (the
    return leg then closes from P5 of the last cycle).

    Raises
    ------
    InputError
        ``cycles`` outside 2–30, or no cube in the cell's workspace box whose five poses
        and the moves between them are feasible.
    """
    if not 2 <= cycles <= 30:
        raise InputError(f"--iso9283: {cycles} cycles; ISO 9283 needs 2 to 30")
    cell = res.cell
    world = CollisionWorld(cell)
    box = cell.work_max - cell.work_min
    mid = (cell.work_min + cell.work_max) / 2
    # where the loop measures is the part of the workspace in use: cubes centred on its
    # poses nearest the loop's middle, with that pose's orientation (one the arm reaches
    # there and the cameras see), then the box's middle facing the camera
    starts = [(mid, facing_camera(cell, mid))]
    if res.poses:
        P = np.array([p.T_world_target[:3, 3] for p in res.poses])
        near = np.argsort(np.linalg.norm(P - P.mean(axis=0), axis=1))[:12]
        starts = [(P[i], res.poses[i].T_world_target[:3, :3]) for i in near] + starts
    for side in np.arange(box.min() / 2, 0.099, -0.05):
        for centre, R in starts:
            got = _feasible_cube(cell, world, res, _targets(R, cube_points(centre, float(side))))
            if got is not None:
                return _appended(res, got, cycles)
    raise InputError(
        f"--iso9283: no ISO cube in cell {cell.name} (sides {box.min() / 2 * 1e3:.0f} to 100 "
        f"mm, centred at the loop's poses or the workspace box's middle) has all five poses "
        "reachable, collision-free and seen by both cameras"
    )


def _feasible_cube(
    cell: Cell, world: CollisionWorld, res: PlanResult, T_wt: F
) -> list[tuple[int, F, F, F]] | None:
    """The five poses ``T_wt`` as (branch, q, T_base_target, T_world_target), each
    configuration the one nearest to P1's (P1's nearest to the loop's last pose), or None."""
    points = T_wt[:, :3, 3]
    T_bt = inv_T(cell.T_world_base) @ T_wt
    Q, valid = ik_ur(cell.robot, T_bt @ inv_T(cell.T_flange_target))
    inlim = valid & within_limits(np.where(valid[..., None], Q, 0.0), cell.robot)
    sight = pose_sight(cell, T_wt)
    reason, feas = feasible_configurations(
        cell, world, Q, valid, inlim, sight, points, lambda s, i, k: None
    )
    if any(r is not None for r in reason):
        return None
    ref = res.poses[-1].q if res.poses else Q[0][feas[0]][0]
    chosen = []
    for i in range(5):
        ks = np.flatnonzero(feas[i])
        k = int(ks[np.argmin(np.abs(Q[i, ks] - ref).max(axis=1))])
        chosen.append((k, Q[i, k], T_bt[i], T_wt[i]))
        if i == 0:
            ref = Q[0, k]
    q = [c[1] for c in chosen]
    legs = [(q[a], q[b]) for a, b in ((0, 1), (1, 2), (2, 3), (3, 4), (4, 0))]
    if res.poses:
        legs += [(res.poses[-1].q, q[0]), (q[4], res.poses[0].q)]
    if not all(joint_leg_ok(cell, world, a, b) for a, b in legs):
        return None
    return chosen


def _appended(res: PlanResult, cube: list[tuple[int, F, F, F]], cycles: int) -> PlanResult:
    cell = res.cell
    m = cell.motion
    sight = pose_sight(cell, np.stack([c[3] for c in cube]))

    def leg_time(a: F, b: F) -> float:
        return float(trap_time(b - a, m.joint_speed, m.joint_accel).max())

    poses = list(res.poses)
    prev = poses[-1].q if poses else cube[0][1]
    for c in range(1, cycles + 1):
        for i, (k, q, T_bt, T_wt) in enumerate(cube):
            poses.append(
                PlannedPose(
                    candidate=-1,  # not one of the random candidates
                    q=q.copy(),
                    leg=Leg.JOINT,
                    branch=k,
                    T_base_target=T_bt,
                    T_world_target=T_wt,
                    pan=float(sight.pan[i]),
                    facing=sight.facing[i].copy(),
                    pixels=sight.pixels[i].copy(),
                    leg_time_s=leg_time(prev, q),
                    name=iso_pose_name(i + 1, c),
                )
            )
            prev = q
    back = leg_time(prev, poses[0].q)
    return replace(res, poses=tuple(poses), return_leg=Leg.JOINT, return_leg_time_s=back)
