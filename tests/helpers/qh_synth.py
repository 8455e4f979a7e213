"""Synthetic measurements of the paper's use case, made with ``loop_pose`` and known coefficients.

Imported as ``qh_synth`` by the identify and station tests (pytest puts ``tests/helpers`` on
``sys.path``, see pyproject.toml) and by the benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.linearize import loop_pose
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import RobotModel, ur5
from quickhealth.identify.transforms import R_to_rpy, exp_so3, make_T, rpy_to_R

Q_LO = np.array([-np.pi, -np.pi, -2.6, -np.pi, -np.pi, -np.pi])
Q_HI = np.array([np.pi, 0.0, 2.6, np.pi, np.pi, np.pi])


@dataclass(frozen=True, eq=False)
class Truth:
    robot: RobotModel
    spec: ErrorModelSpec
    coeffs: np.ndarray
    T_instr_base: np.ndarray
    T_flange_target: np.ndarray


def camera_setup(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Camera ~2 m in front of the robot, looking back at it, rotated; a target 60 mm off the flange."""
    rng = np.random.default_rng(seed)
    R = exp_so3(np.array([0.3, -2.0, 0.5]) + rng.normal(0, 0.05, 3))
    T_ib = make_T(R, np.array([0.4, -0.3, 2.1]))
    T_ft = make_T(exp_so3(np.array([0.1, 0.2, -0.3])), np.array([0.01, -0.02, 0.06]))
    return T_ib, T_ft


def paper_truth(seed: int = 0, geometric_sigma: float = 1e-4, orders_j1=None) -> Truth:
    """Joint 1: encoder offset plus position-dependent terms; small geometric errors elsewhere."""
    rng = np.random.default_rng(seed)
    robot = ur5()
    o = np.zeros((8, 6), dtype=np.int64)
    o[1] = [2, 0, 0, 0, 3, 3] if orders_j1 is None else orders_j1
    spec = ErrorModelSpec(o, Q_LO, Q_HI)
    c = np.zeros(spec.n_params)
    idx = spec.index()
    joint = (idx[:, 0] >= 1) & (idx[:, 0] <= 6) & (idx[:, 2] == 0)
    rot = idx[:, 1] >= 3
    c[joint & ~rot] = rng.normal(0, geometric_sigma, (joint & ~rot).sum())
    c[joint & rot] = rng.normal(0, geometric_sigma * 3, (joint & rot).sum())
    lab = spec.labels()

    def setc(name, v):
        if name in lab:
            c[lab.index(name)] = v

    setc("j1.ez.c0", 8e-4)  # encoder zero offset
    setc("j1.ez.c2", 1.5e-4)
    setc("j1.ez.c3", 2.0e-4)
    setc("j1.dx.c1", 6e-5)
    setc("j1.dx.c2", -8e-5)
    setc("j1.ey.c2", 1.2e-4)
    setc("j1.ey.c3", -1.5e-4)
    T_ib, T_ft = camera_setup(seed)
    return Truth(robot, spec, c, T_ib, T_ft)


def random_q(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(Q_LO + 0.05, Q_HI - 0.05, (n, 6))


def measure(
    truth: Truth,
    q: np.ndarray,
    seed: int,
    sigma_pos: float = 3e-5,
    sigma_rot: float = 1e-4,
    full_pose: bool = True,
) -> Measurements:
    """Noisy measurements of the truth at joints ``q`` (noise per axis and per angle)."""
    rng = np.random.default_rng(seed)
    T = loop_pose(
        truth.robot, truth.spec, truth.coeffs, truth.T_instr_base, truth.T_flange_target, q
    )
    pos = T[:, :3, 3] + rng.normal(0, sigma_pos, (len(q), 3))
    rpy = None
    if full_pose:
        rpy = R_to_rpy(T[:, :3, :3]) + rng.normal(0, sigma_rot, (len(q), 3))
        assert np.allclose(rpy_to_R(*(R_to_rpy(T[:, :3, :3]).T)), T[:, :3, :3])
    return Measurements(q=q, pos=pos, rpy=rpy)


def truth_pose(truth: Truth, q: np.ndarray) -> np.ndarray:
    return loop_pose(
        truth.robot, truth.spec, truth.coeffs, truth.T_instr_base, truth.T_flange_target, q
    )
