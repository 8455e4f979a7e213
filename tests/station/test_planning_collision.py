"""Collision geometry: URDF frames against the DH model, table, obstacles, sight beams."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quickhealth.identify.robot import ur5
from quickhealth.identify.transforms import inv_T, make_T
from quickhealth.station.planning.cell import Obstacle, load_cell
from quickhealth.station.planning.collision import CollisionWorld, read_stl, tool0_frames, ur5_chain
from quickhealth.station.planning.ik_ur import ik_ur
from quickhealth.station.planning.sight import pose_sight, robot_blockers


@pytest.fixture(scope="module")
def cell():
    return load_cell("reference")


def test_urdf_tool0_is_the_dh_flange():
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (200, 6))
    assert np.allclose(tool0_frames(q), ur5().fk(q), atol=1e-9)


def test_meshes_load():
    ch = ur5_chain()
    assert len(ch.mesh_files) == 7
    for f in ch.mesh_files:
        v, t = read_stl(f)
        assert len(t) > 100 and np.all(np.isfinite(v))
        assert np.abs(v).max() < 0.5  # metres, link-local


def test_table_and_free_configurations(cell):
    w = CollisionWorld(cell)
    up = np.array([[0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0]])  # arm straight up
    assert w.contacts(up) == [[]]
    down = np.array([[0.0, 0.6, 0.0, -np.pi / 2, 0.0, 0.0]])  # upper arm 34° below horizontal
    hits = w.contacts(down, first_only=False)[0]
    assert any(h.endswith("|table") for h in hits)
    folded = np.array([[0.0, -1.2, 2.9, -1.7, 0.0, 0.0]])  # elbow folded back on itself
    assert w.collides(folded)[0]


def _aimed(cell, p):
    """Target at world point p with its marker aimed at the stereo midpoint."""
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    p = np.asarray(p, dtype=float)
    z = (mid - p) / np.linalg.norm(mid - p)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return make_T(np.stack([x, np.cross(z, x), z], axis=1), p)


def test_obstacle_at_the_target_is_hit_and_blocks_sight(cell):
    T_wt = _aimed(cell, [0.45, 0.1, 0.4])
    Q, valid = ik_ur(cell.robot, inv_T(cell.T_world_base) @ T_wt @ inv_T(cell.T_flange_target))
    w = CollisionWorld(cell)
    ok = [k for k in np.flatnonzero(valid) if not w.collides(Q[k][None])[0]]
    ok = [k for k in ok if robot_blockers(w, Q[k][None], T_wt[None, :3, 3]) == [None]]
    assert ok, "some configuration sees the target"
    q = Q[ok[0]][None]
    block = Obstacle(
        "block", "box", make_T(np.eye(3), T_wt[:3, 3]), size=np.array([0.05, 0.05, 0.05])
    )
    c2 = dataclasses.replace(cell, obstacles=(block,))
    assert "target|block" in CollisionWorld(c2).contacts(q, first_only=False)[0]
    # a wall between the cameras and the robot blocks both beams
    wall = Obstacle(
        "wall", "box", make_T(np.eye(3), [1.3, 0.0, 0.4]), size=np.array([0.05, 3.0, 3.0])
    )
    c3 = dataclasses.replace(cell, obstacles=(wall,))
    assert robot_blockers(CollisionWorld(c3), q, T_wt[None, :3, 3]) == ["left: wall"]


def test_fov_and_facing(cell):
    # a target at the workspace middle, marker aimed at the cameras, is seen by both
    p = np.array([0.3, 0.0, 0.35])
    R = _aimed(cell, p)[:3, :3]
    s = pose_sight(cell, make_T(R, p)[None])
    assert s.in_fov.all() and s.facing_ok.all() and abs(s.pan[0]) < 1e-9
    # turned 90° about its pan axis: the motor turns it back (pan = -90°)
    Ry = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    s = pose_sight(cell, make_T(R @ Ry, p)[None])
    assert s.facing_ok.all() and np.degrees(s.pan[0]) == pytest.approx(-90.0)
    # turned 90° about its x axis: no pan angle can make it face the cameras
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    assert not pose_sight(cell, make_T(R @ Rx, p)[None]).facing_ok.any()
    # far to the side: outside both images
    assert not pose_sight(cell, make_T(R, [0.3, 1.5, 0.35])[None]).in_fov.any()
