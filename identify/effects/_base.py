"""Shared helpers of the built-in effects (joint index parsing, per-joint perturbations)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..robot import RobotModel

F = NDArray[np.float64]


def joint_index(token: str, robot: RobotModel, name: str) -> int:
    """0-based joint index of ``jK`` (1-based K), checked against the robot."""
    k = int(token)
    if not 1 <= k <= robot.n_joints:
        raise InputError(
            f"effect {name!r}: joint j{k} does not exist on {robot.name} "
            f"(joints j1 … j{robot.n_joints})"
        )
    return k - 1


def joint_dq(n: int, nj: int, joint: int, values: F) -> F:
    """A ``dq`` array (n, nj) that is zero except column ``joint``."""
    dq = np.zeros((n, nj))
    dq[:, joint] = values
    return dq
