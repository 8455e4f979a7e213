"""Planner steps in isolation: sampling, ordering, legs, coverage figures."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from quickhealth.identify.transforms import inv_T, make_T
from quickhealth.station.planning.cell import Obstacle, load_cell
from quickhealth.station.planning.collision import CollisionWorld
from quickhealth.station.planning.ik_ur import ik_ur
from quickhealth.station.planning.planner import (
    joint_coverage,
    joint_leg_ok,
    linear_leg_ok,
    order_tour,
    sample_targets,
    trap_time,
)


@pytest.fixture(scope="module")
def cell():
    return load_cell("reference")


def test_sampled_targets_lie_in_the_volume_and_face_the_cameras(cell):
    T = sample_targets(cell, 2000, np.random.default_rng(1))
    p = T[:, :3, 3]
    assert np.all(p >= cell.work_min) and np.all(p <= cell.work_max)
    R = T[:, :3, :3]
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    u = (mid - p) / np.linalg.norm(mid - p, axis=1, keepdims=True)
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", R[:, :, 2], u), -1, 1)))
    assert tilt.max() <= math.degrees(cell.orientation_spread) + 1e-6
    assert tilt.max() > 0.9 * math.degrees(cell.orientation_spread)  # the whole cap is used
    # uniform over the cap: the median tilt of a uniform cap of 45° is about 31.9°
    c = math.cos(cell.orientation_spread)
    assert np.median(tilt) == pytest.approx(math.degrees(math.acos((1 + c) / 2)), abs=1.5)


def _tour_cost(C, t):
    return sum(C[t[i], t[(i + 1) % len(t)]] for i in range(len(t)))


def test_order_finds_the_short_loop(cell):
    # poses spread along joint 1 only, given in shuffled order: the best loop visits them in
    # sorted order (out and back once)
    rng = np.random.default_rng(0)
    a = rng.permutation(np.linspace(-2.5, 2.5, 25))
    Q = np.zeros((25, 8, 6))
    Q[:, :, 0] = a[:, None]
    feas = np.zeros((25, 8), dtype=bool)
    feas[:, 0] = True
    t = order_tour(cell, Q, feas)
    assert sorted(t) == list(range(25))
    m = cell.motion
    C = trap_time(np.abs(a[:, None] - a[None, :]), m.joint_speed, m.joint_accel)
    best = list(np.argsort(a))
    assert _tour_cost(C, t) <= _tour_cost(C, best) + 1e-9


def _aimed(cell, p):
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    z = (mid - p) / np.linalg.norm(mid - p)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return make_T(np.stack([x, np.cross(z, x), z], axis=1), p)


def test_linear_leg_free_then_blocked_by_an_obstacle(cell):
    world = CollisionWorld(cell)
    T_bw, T_tf = inv_T(cell.T_world_base), inv_T(cell.T_flange_target)
    Ta = T_bw @ _aimed(cell, np.array([0.45, -0.15, 0.35]))
    Tb = T_bw @ _aimed(cell, np.array([0.45, 0.15, 0.35]))
    Qa, va = ik_ur(cell.robot, Ta @ T_tf)
    Qb, vb = ik_ur(cell.robot, Tb @ T_tf)
    ok = [
        k
        for k in np.flatnonzero(va & vb)
        if np.all(np.abs(Qa[k]) <= np.pi)
        and np.all(np.abs(Qb[k]) <= np.pi)
        and linear_leg_ok(cell, world, Ta, Qa[k], Tb, Qb[k])
    ]
    assert ok, "a 30 cm straight move in free space is feasible in some configuration"
    ka = ok[0]
    qa, qb = Qa[ka], Qb[ka]
    # another branch at the end cannot be reached by a continuous straight move
    for other in np.flatnonzero(vb):
        if other != ka:
            assert not linear_leg_ok(cell, world, Ta, qa, Tb, Qb[other])
    # a post in the middle of the path blocks it
    mid_world = cell.T_world_base @ np.r_[(Ta[:3, 3] + Tb[:3, 3]) / 2, 1.0]
    post = Obstacle("post", "cylinder", make_T(np.eye(3), mid_world[:3]), radius=0.03, length=0.3)
    blocked = dataclasses.replace(cell, obstacles=(*cell.obstacles, post))
    assert not linear_leg_ok(blocked, CollisionWorld(blocked), Ta, qa, Tb, qb)
    # joint-space legs: free in the open cell, not through the table
    assert joint_leg_ok(cell, world, qa, qb)
    down = qa.copy()
    down[1] = 0.8  # upper arm pointing into the table
    assert not joint_leg_ok(cell, world, qa, down)


def test_coverage_and_evenness_figures():
    lo, hi = np.zeros(6), np.ones(6)
    q = np.tile(np.linspace(0.0, 1.0, 120)[:, None], (1, 6))
    c = joint_coverage(q, lo, hi, 12)
    assert np.allclose(c.coverage, 1.0) and np.allclose(c.evenness, 1.0, atol=1e-3)
    assert np.allclose(c.occupied, 1.0)
    q2 = np.full((50, 6), 0.3)
    q2[0] = 0.31
    c2 = joint_coverage(q2, lo, hi, 12)
    assert np.allclose(c2.evenness, 0.0) and np.allclose(c2.occupied, 1 / 12)
    assert np.allclose(c2.coverage, 0.01)
    q3 = np.tile(np.linspace(0.0, 0.5, 60)[:, None], (1, 6))
    assert np.allclose(joint_coverage(q3, lo, hi, 12).coverage, 0.5)


def test_one_leg_type_for_the_planner_plan_file_and_driver():
    import subprocess
    import sys

    from quickhealth.station.hardware.legs import Leg
    from quickhealth.station.hardware.robot import Leg as DriverLeg
    from quickhealth.station.planning import planfile, planner

    assert planner.Leg is Leg and planfile.Leg is Leg and DriverLeg is Leg
    assert [str(v) for v in Leg] == ["joint", "linear"]  # plan.json's values
    # the driver imports the leg vocabulary without any of the planner's modules
    code = (
        "import sys, quickhealth.station.hardware.robot as r; "
        "print(sorted(m for m in sys.modules if m.startswith('quickhealth.station.planning')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
