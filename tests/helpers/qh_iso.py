"""An ISO 9283 cube series at one tool orientation, as a laser tracker measures it (the twin of
the shared UR10's unseen cube series): imported as ``qh_iso`` by the tests and by
``benchmarks/iso_cube.py``."""

from __future__ import annotations

import numpy as np

from quickhealth.identify.transforms import make_T, rot_x, rot_y
from quickhealth.station.planning.ik_ur import ik_ur, within_limits

PROBE = make_T(np.eye(3), [0.0, 0.0, 0.093])  # the T-Mac 93 mm out along the flange axis


def cube_joints(robot, centre, edge: float, grid: int, shift: float = 0.0) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Joint readings of a ``grid``³ cube of flange positions at one orientation (the flange
    pointing down, tilted 0.3 rad so that every joint moves), one IK branch throughout, every
    angle taken near the cube centre's (no 2π jumps)."""
    ax = (np.arange(grid) + shift) / (grid - 1) - 0.5
    pts = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3) * edge + centre
    R = rot_x(np.pi) @ rot_y(0.3)
    T = np.broadcast_to(make_T(R, np.zeros(3)), (len(pts), 4, 4)).copy()
    T[:, :3, 3] = pts
    q, ok = ik_ur(robot, T)
    branch = int(np.argmax(ok.sum(axis=0)))  # the branch that reaches most of the cube
    keep = ok[:, branch]
    qb = q[keep, branch]
    ref = ik_ur(robot, make_T(R, centre))[0][branch]
    qb = ref + (qb - ref + np.pi) % (2 * np.pi) - np.pi  # nearest the centre's angles
    return qb[within_limits(qb, robot)]
