"""Line of sight from both cameras to the smart target (METHOD.md §1, step 2).

A target pose is *seen* when, for each camera of the stereo pair,

1. its centre projects inside the image, ``margin_px`` away from the border, at a depth
   between ``min_range`` and ``max_range`` (pin-hole model of the cell's camera);
2. the marker faces the camera: the pan motor turns the plate about the target's y axis to
   the angle that points its normal at the midpoint of the two cameras (clamped to the pan
   range); the angle between that normal and the direction to each camera is at most
   ``facing_max``;
3. a beam of radius ``sight_radius`` from the camera (starting 50 mm in front of it) to
   ``sight_stop`` before the target centre touches no robot link, obstacle or the table.

Pan convention: ``T_flange_target(pan) = T_flange_target · Ry(pan)``.
Checks 1–2 depend on the target pose only and are vectorised; check 3 needs the robot
configuration and uses :class:`~.collision.CollisionWorld`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.transforms import inv_T
from .cell import Camera, Cell
from .collision import CollisionWorld

F = NDArray[np.float64]
BEAM_START = 0.05  # m in front of the optical centre


@dataclass(frozen=True, eq=False)
class PoseSight:
    """Pose-level visibility of target poses (vectorised over m poses)."""

    in_fov: NDArray[np.bool_]  # (m, 2) left, right
    pixels: F  # (m, 2, 2) u, v per camera
    pan: F  # (m,) rad, the pan angle the motor should take
    facing: F  # (m, 2) rad, angle between marker normal and each camera direction
    facing_ok: NDArray[np.bool_]  # (m,)


def project(T_world_cam: F, camera: Camera, p_world: F) -> tuple[F, F]:
    """Pixel coordinates (m, 2) and depths (m,) of world points (m, 3) in one camera."""
    pc = (inv_T(T_world_cam) @ np.c_[p_world, np.ones(len(p_world))].T).T[:, :3]
    z = pc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    uv = np.c_[camera.fx * pc[:, 0] / zs + camera.cx, camera.fy * pc[:, 1] / zs + camera.cy]
    return uv, z


def pose_sight(cell: Cell, T_world_target: F) -> PoseSight:
    """Field-of-view and facing checks for target poses ``T_world_target`` (m, 4, 4)."""
    cam = cell.camera
    p = T_world_target[:, :3, 3]
    in_fov = np.zeros((len(p), 2), dtype=bool)
    pix = np.zeros((len(p), 2, 2))
    for k, Tc in enumerate((cell.T_world_cam_left, cell.T_world_cam_right)):
        uv, z = project(Tc, cam, p)
        pix[:, k] = uv
        m = cam.margin_px
        in_fov[:, k] = (
            (z >= cam.min_range)
            & (z <= cam.max_range)
            & (uv[:, 0] >= m)
            & (uv[:, 0] <= cam.width - m)
            & (uv[:, 1] >= m)
            & (uv[:, 1] <= cam.height - m)
        )
    pan, facing = facing_angles(cell, T_world_target)
    return PoseSight(in_fov, pix, pan, facing, np.all(facing <= cell.facing_max, axis=1))


def facing_angles(cell: Cell, T_world_target: F) -> tuple[F, F]:
    """Pan angle (m,) and facing angle per camera (m, 2), rad (see module docstring)."""
    R = T_world_target[:, :3, :3]
    p = T_world_target[:, :3, 3]
    cams = np.stack([cell.T_world_cam_left[:3, 3], cell.T_world_cam_right[:3, 3]])
    mid = cams.mean(0)
    d = np.einsum("mji,mj->mi", R, mid - p)  # direction to the midpoint in target coordinates
    pan = np.clip(np.arctan2(d[:, 0], d[:, 2]), cell.pan_min, cell.pan_max)
    n_t = np.stack([np.sin(pan), np.zeros_like(pan), np.cos(pan)], -1)
    n = np.einsum("mij,mj->mi", R, n_t)
    facing = np.empty((len(p), 2))
    for k in range(2):
        dc = cams[k] - p
        dc /= np.linalg.norm(dc, axis=1, keepdims=True)
        facing[:, k] = np.arccos(np.clip(np.einsum("mi,mi->m", n, dc), -1.0, 1.0))
    return pan, facing


def beams(cell: Cell, p_target_world: F) -> tuple[F, F]:
    """Start and end points (m, 2, 3) of the sight beams of both cameras, world."""
    cams = np.stack([cell.T_world_cam_left[:3, 3], cell.T_world_cam_right[:3, 3]])
    d = p_target_world[:, None, :] - cams[None]
    L = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / L
    a = cams[None] + BEAM_START * u
    b = p_target_world[:, None, :] - cell.planner.sight_stop * u
    return a, b


def robot_blockers(world: CollisionWorld, q: F, p_target_world: F) -> list[str | None]:
    """First blocker (link or obstacle name, prefixed with the camera) per configuration.

    Parameters
    ----------
    q : ndarray, shape (m, 6), rad
    p_target_world : ndarray, shape (m, 3), m
    """
    a, b = beams(world.cell, p_target_world)
    r = world.cell.planner.sight_radius
    out: list[str | None] = [None] * len(q)
    for k, side in enumerate(("left", "right")):
        hits = world.sight_blockers(q, a[:, k], b[:, k], r)
        for i, h in enumerate(hits):
            if h is not None and out[i] is None:
                out[i] = f"{side}: {h}"
    return out


def static_blockers(world: CollisionWorld, p_target_world: F) -> list[str | None]:
    """First obstacle (or the table) blocking either camera's beam, robot ignored, per pose."""
    a, b = beams(world.cell, p_target_world)
    r = world.cell.planner.sight_radius
    out: list[str | None] = []
    for i in range(len(p_target_world)):
        hit = None
        for k, side in enumerate(("left", "right")):
            h = world.static_sight_blocker(a[i, k], b[i, k], r)
            if h is not None:
                hit = f"{side}: {h}"
                break
        out.append(hit)
    return out
