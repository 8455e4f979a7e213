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


def perturbed_loop_pose(
    robot: RobotModel,
    spec: object,
    coeffs: F,
    T_instr_base0: F,
    T_flange_target0: F,
    q: F,
    pert: object,
) -> F:
    """Model pose ``T_instr_target`` (n, 4, 4) with a :class:`Perturbation` applied.

    ``dq``, ``link_scale`` and ``base_twist`` go through
    :func:`quickhealth.identify.errormodel.loop_pose`; ``instr_scale_z`` scales the position's
    z in the instrument frame, ``p_measured = diag(1, 1, 1 + s) · p`` (the effects package
    docstring).  The orientation is left as it is.
    """
    from ..errormodel import ErrorModelSpec, loop_pose
    from . import Perturbation

    assert isinstance(spec, ErrorModelSpec) and isinstance(pert, Perturbation)
    T = loop_pose(
        robot,
        spec,
        coeffs,
        T_instr_base0,
        T_flange_target0,
        q,
        dq=pert.dq,
        link_scale=None if pert.link_scale is None else 1.0 + pert.link_scale,
        base_twist=pert.base_twist,
    )
    if pert.instr_scale_z is not None:
        T = T.copy()
        T[:, 2, 3] *= 1.0 + pert.instr_scale_z
    return T
