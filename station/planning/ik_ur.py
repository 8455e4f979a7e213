"""Analytic inverse kinematics of the Universal Robots geometry: all 8 solutions, vectorised.

The UR arms (UR3/5/10 and their e-Series) share one standard-DH structure::

    a = (0, a2, a3, 0, 0, 0)   d = (d1, 0, 0, d4, d5, d6)   α = (π/2, 0, 0, π/2, −π/2, 0)

with joints 2, 3 and 4 parallel.  For a flange pose there are up to eight joint vectors:
two shoulder solutions (θ1), two wrist solutions (θ5) and two elbow solutions (θ3).  The
closed form follows K. P. Hawkins, "Analytic inverse kinematics for the Universal Robots
UR-5/UR-10 arms" (Georgia Tech, 2013); every solution is checked by forward kinematics and
marked invalid when its residual exceeds ``tol_m`` / ``tol_rad`` (unreachable poses give
NaNs and invalid flags, never exceptions).

Solution index ``k = 4·shoulder + 2·wrist + elbow`` (bits: θ1 branch, θ5 sign, θ3 sign);
:data:`BRANCH_NAMES` names them.  Angles are returned wrapped to (−π, π]; use
:func:`wrap_near` to pick the 2π-equivalent nearest a reference inside the joint limits.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...identify.errors import InputError
from ...identify.robot import RobotModel

F = NDArray[np.float64]
B = NDArray[np.bool_]

BRANCH_NAMES: tuple[str, ...] = tuple(
    f"shoulder-{s}/wrist-{w}/elbow-{e}"
    for s in ("a", "b")
    for w in ("up", "down")
    for e in ("a", "b")
)

_UR_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])


def ur_geometry(robot: RobotModel) -> tuple[float, float, float, float, float, float]:
    """``(d1, a2, a3, d4, d5, d6)`` of a robot with the UR DH structure.

    Raises
    ------
    InputError
        If the robot is not a standard-DH model with the UR structure.
    """
    dh = robot.dh
    if robot.convention != "dh" or dh is None or robot.n_joints != 6:
        raise InputError(
            f"robot {robot.name!r}: analytic UR inverse kinematics needs a 6-joint standard-DH model"
        )
    a, d, al = (np.asarray(dh[k], dtype=float) for k in ("a", "d", "alpha"))
    if (
        not np.allclose(al, _UR_ALPHA, atol=1e-9)
        or np.any(np.abs(a[[0, 3, 4, 5]]) > 1e-12)
        or np.any(np.abs(d[[1, 2]]) > 1e-12)
    ):
        raise InputError(f"robot {robot.name!r}: DH table does not have the UR structure")
    return float(d[0]), float(a[1]), float(a[2]), float(d[3]), float(d[4]), float(d[5])


def ik_ur(
    robot: RobotModel,
    T_base_flange: ArrayLike,
    *,
    tol_m: float = 1e-7,
    tol_rad: float = 1e-7,
) -> tuple[F, B]:
    """All eight inverse-kinematics solutions of a UR arm.

    Parameters
    ----------
    robot : RobotModel
        A UR-structured standard-DH model (``ur5()``); its ``q_offset`` is honoured.  Joint
        limits are *not* applied here (see :func:`within_limits`).
    T_base_flange : array, shape (4, 4) or (n, 4, 4)
        Desired flange poses in the robot base frame (m).
    tol_m, tol_rad : float
        Forward-kinematics residuals above which a solution is marked invalid.

    Returns
    -------
    q : ndarray, shape (8, 6) or (n, 8, 6), rad
        Joint solutions wrapped to (−π, π]; NaN where the pose is out of reach of that branch.
    valid : ndarray of bool, shape (8,) or (n, 8)
        True where the solution exists and reproduces the pose by forward kinematics.
    """
    T = np.asarray(T_base_flange, dtype=float)
    single = T.ndim == 2
    T = T.reshape(-1, 4, 4)
    d1, a2, a3, d4, d5, d6 = ur_geometry(robot)
    th = _ik_theta(T, d1, a2, a3, d4, d5, d6)  # (n, 8, 6) DH angles θ
    q = _wrap(th - robot.q_offset)
    valid = np.all(np.isfinite(q), axis=-1)
    if np.any(valid):
        qq = np.where(valid[..., None], q, 0.0).reshape(-1, 6)
        Tq = robot.fk(qq).reshape(-1, 8, 4, 4)
        dp = np.linalg.norm(Tq[..., :3, 3] - T[:, None, :3, 3], axis=-1)
        dR = np.linalg.norm(Tq[..., :3, :3] - T[:, None, :3, :3], axis=(-2, -1))
        valid &= (dp < tol_m) & (dR < tol_rad)
    if single:
        return q[0], valid[0]
    return q, valid


def _ik_theta(T: F, d1: float, a2: float, a3: float, d4: float, d5: float, d6: float) -> F:
    n = T.shape[0]
    r = T[:, :3, :3]
    p = T[:, :3, 3]
    out = np.full((n, 8, 6), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        # θ1: the wrist centre p5 lies on the plane at distance d4 from the base z axis.
        p5 = p - d6 * r[:, :, 2]
        rho = np.hypot(p5[:, 0], p5[:, 1])
        phi = np.arccos(np.clip(d4 / rho, -1.0, 1.0))
        phi = np.where(rho >= d4 * (1 - 1e-12), phi, np.nan)
        psi = np.arctan2(p5[:, 1], p5[:, 0])
        for si, sgn1 in enumerate((1.0, -1.0)):
            t1 = psi + sgn1 * phi + np.pi / 2
            c1, s1 = np.cos(t1), np.sin(t1)
            # θ5 from the flange position across the arm plane.
            c5 = (p[:, 0] * s1 - p[:, 1] * c1 - d4) / d6
            c5 = np.where(np.abs(c5) <= 1.0 + 1e-9, np.clip(c5, -1.0, 1.0), np.nan)
            for wi, sgn5 in enumerate((1.0, -1.0)):
                t5 = sgn5 * np.arccos(c5)
                s5 = np.sin(t5)
                # θ6 from the base x/y axes seen in the flange frame.
                xs = r[:, 0, 0] * s1 - r[:, 1, 0] * c1
                ys = r[:, 0, 1] * s1 - r[:, 1, 1] * c1
                sing = np.abs(s5) < 1e-10
                ss5 = np.where(sing, 1.0, np.sign(s5))
                t6 = np.where(sing, 0.0, np.arctan2(-ys * ss5, xs * ss5))
                # Planar 3R problem for θ2, θ3, θ4 in the arm plane.
                T1 = _dh(t1, d1, 0.0, np.pi / 2)
                T56 = _dh(t5, d5, 0.0, -np.pi / 2) @ _dh(t6, d6, 0.0, 0.0)
                T14 = np.linalg.inv(T1) @ T @ np.linalg.inv(T56)
                # frame 4 origin in frame 1, minus the d4 offset along frame-1 z (= arm-plane normal)
                px = T14[:, 0, 3]
                py = T14[:, 1, 3]
                c3 = (px**2 + py**2 - a2**2 - a3**2) / (2 * a2 * a3)
                c3 = np.where(np.abs(c3) <= 1.0 + 1e-9, np.clip(c3, -1.0, 1.0), np.nan)
                t234 = np.arctan2(T14[:, 1, 0], T14[:, 0, 0])
                for ei, sgn3 in enumerate((1.0, -1.0)):
                    t3 = sgn3 * np.arccos(c3)
                    t2 = np.arctan2(py, px) - np.arctan2(a3 * np.sin(t3), a2 + a3 * np.cos(t3))
                    t4 = t234 - t2 - t3
                    k = 4 * si + 2 * wi + ei
                    out[:, k] = np.stack([t1, t2, t3, t4, t5, t6], axis=-1)
    return out


def _dh(theta: F, d: float, a: float, alpha: float) -> F:
    c, s = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros((*np.shape(theta), 4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = c, -s * ca, s * sa, a * c
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = s, c * ca, -c * sa, a * s
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
    T[..., 3, 3] = 1.0
    return T


def _wrap(a: F) -> F:
    """Wrap to (−π, π]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def wrap_near(q: ArrayLike, q_ref: ArrayLike, q_min: ArrayLike, q_max: ArrayLike) -> F:
    """The 2π-equivalent of ``q`` nearest ``q_ref`` per joint, kept inside ``[q_min, q_max]``.

    Where the nearest equivalent is outside the limits the next one inside is taken; where
    none is inside, the result is NaN.  Shapes broadcast; rad.
    """
    q = np.asarray(q, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    lo, hi = np.asarray(q_min, dtype=float), np.asarray(q_max, dtype=float)
    base = q_ref + _wrap(q - q_ref)
    cands = base[..., None] + 2 * np.pi * np.array([0.0, -1.0, 1.0, -2.0, 2.0])
    ok = (cands >= lo[..., None] - 1e-12) & (cands <= hi[..., None] + 1e-12)
    cost = np.where(ok, np.abs(cands - q_ref[..., None]), np.inf)
    i = np.argmin(cost, axis=-1)
    pick = np.take_along_axis(cands, i[..., None], -1)[..., 0]
    return np.where(np.isfinite(np.min(cost, axis=-1)), pick, np.nan)


def within_limits(q: ArrayLike, robot: RobotModel, tol: float = 1e-9) -> B:
    """True where every joint of ``q`` (shape (..., 6), rad) lies inside the robot's limits."""
    q = np.asarray(q, dtype=float)
    return np.all((q >= robot.q_min - tol) & (q <= robot.q_max + tol), axis=-1)
