"""The simulated arm: timed joint motion, straight-line path planning, ringing and noise.

Shared by the controller simulator and :class:`~.fake_robot.FakeRobot`.

Motion
------
moveJ: synchronised trapezoidal joint profile (speed rad/s, acceleration rad/s²).  moveL and
moveL_FK: straight line of the TCP (position linear, orientation along the geodesic) sampled
every 5 mm / 0.02 rad (2 to 400 samples) and solved by the analytic UR inverse kinematics
(:mod:`quickhealth.station.planning.ik_ur`) for all samples at once, keeping for each
sample the solution nearest the previous one.  Where that is not possible (a robot without
the UR structure, a sample out of reach, a branch switch near a singularity) the path falls
back to damped least-squares IK from the previous sample (:func:`linear_path_dls`, the
reference the analytic path is tested against).  Planning is a pure function of the start
joints and the goal: the controller runs it in its planner thread, outside its lock.

After every stop the actual joints ring with a small damped oscillation (amplitude ~1e-4 rad,
time constant 60 ms) plus encoder noise (1 µrad), so settle detection on the joint stream has
something real to detect.

The arm's ``robot`` is the kinematics the controller computes with: its factory calibration
(:mod:`.kinematics`), which differs from nominal; ``ik_model`` is the nominal UR model whose
closed-form IK seeds it; ``truth`` (the digital twin) says where the target really is.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.robot import BUILTIN_ROBOTS, RobotModel, builtin_robot
from ...identify.transforms import exp_so3, log_so3, make_T
from ..planning.ik_ur import ik_ur as _ik_ur

F = NDArray[np.float64]

HOME_Q_DEG = [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]

LINEAR_STEP_M = 0.005  # path sample spacing along the line, m
LINEAR_STEP_RAD = 0.02  # … and in orientation, rad
LINEAR_MAX_SAMPLES = 400
MAX_JOINT_STEP = 0.25  # rad between two samples; more means a branch switch: use DLS
REFINE_TOL = 1e-10  # m / rad: analytic samples worse than this get a few DLS steps


def pose_from_T(T: np.ndarray) -> list[float]:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) of a transform."""
    return [*map(float, T[:3, 3]), *map(float, log_so3(T[:3, :3]))]


def T_from_pose(p: Any) -> F:
    """Transform from a UR pose vector."""
    p = np.asarray(p, dtype=float)
    return make_T(exp_so3(p[3:6]), p[:3])


class PoseFK:
    """Forward kinematics of one joint vector to a UR pose vector, fast (tens of µs).

    Gives exactly what ``pose_from_T(robot.fk(q) @ tcp)`` gives (the same products in the
    same order) without the batch machinery, because the RTDE stream needs two poses per
    packet at up to 500 Hz.
    """

    def __init__(self, robot: RobotModel) -> None:
        self.links = [np.array(L, dtype=float) for L in robot.links]
        self.offset = [float(v) for v in robot.q_offset]

    def __call__(self, q: Any, tcp: np.ndarray) -> list[float]:
        T = self.links[0]
        for i, off in enumerate(self.offset):
            th = float(q[i]) + off
            c, s = math.cos(th), math.sin(th)
            Rz = np.array(((c, -s, 0.0, 0.0), (s, c, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), _W))
            T = T @ Rz @ self.links[i + 1]
        T = T @ tcp
        return [float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), *_log_rotation(T[:3, :3].tolist())]


def _log_rotation(r: list[list[float]]) -> list[float]:
    """Rotation vector of a 3×3 rotation (nested lists): :func:`log_so3` in scalar arithmetic."""
    cs = min(1.0, max(-1.0, (r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0))
    th = math.acos(cs)
    v = (r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1])
    if th > math.pi - 1e-3:  # near π the antisymmetric part vanishes: use the symmetric one
        B = [
            [(r[i][j] + r[j][i]) / 2.0 - (cs if i == j else 0.0) for j in range(3)]
            for i in range(3)
        ]
        i = max(range(3), key=lambda k: B[k][k])
        n = math.sqrt(B[i][0] ** 2 + B[i][1] ** 2 + B[i][2] ** 2)
        ax = [B[i][0] / n, B[i][1] / n, B[i][2] / n]
        dot = ax[0] * v[0] + ax[1] * v[1] + ax[2] * v[2]
        sign = -1.0 if dot < 0 else 1.0
        return [a * th * sign for a in ax]
    sn = math.sin(th)
    k = 0.5 + th * th / 12.0 if sn < 1e-6 else th / (2.0 * sn)
    return [v[0] * k, v[1] * k, v[2] * k]


_W = (0.0, 0.0, 0.0, 1.0)


def ik_dls(
    robot: RobotModel,
    T_goal: np.ndarray,
    q0: np.ndarray,
    *,
    iters: int = 60,
    tol: float = 1e-10,
    damping: float = 1e-4,
) -> tuple[F, bool]:
    """Damped least-squares IK of ``T_base_flange = T_goal`` from ``q0``; returns (q, converged)."""
    q = np.array(q0, dtype=float)
    eps = 1e-7
    for _ in range(iters):
        Q = np.vstack([q, q + eps * np.eye(len(q))])
        T = robot.fk(Q)
        err = _pose_error(T_goal, T[0])
        if float(err @ err) < tol**2:
            return q, True
        J = np.stack([_pose_error(T[i + 1], T[0]) for i in range(len(q))], axis=1) / eps
        dq = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), err)
        q = q + dq
    err = _pose_error(T_goal, robot.fk(q))
    return q, bool(np.linalg.norm(err) < 1e-7)


def _pose_error(T_goal: np.ndarray, T: np.ndarray) -> F:
    dp = T_goal[:3, 3] - T[:3, 3]
    dr = log_so3(T_goal[:3, :3] @ T[:3, :3].T)
    return np.concatenate([dp, dr])


def _wrap(a: F) -> F:
    """Angles wrapped to (−π, π]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def trapezoid_duration(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest trapezoidal (or triangular) profile over ``distance``."""
    if distance <= 0.0:
        return 0.0
    if distance <= speed * speed / accel:
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


def trapezoid_fraction(t: float, duration: float, distance: float, accel: float) -> float:
    """Fraction of the path covered at time ``t`` of a trapezoidal profile."""
    if duration <= 0.0 or t >= duration:
        return 1.0
    if t <= 0.0:
        return 0.0
    # Recover the cruise speed from the duration: D = v (T - v/a)  ->  v = (aT - sqrt(a²T² - 4aD))/2
    disc = accel * accel * duration * duration - 4.0 * accel * distance
    vmax = (accel * duration - math.sqrt(max(disc, 0.0))) / 2.0
    ta = vmax / accel
    if t < ta:
        s = 0.5 * accel * t * t
    elif t < duration - ta:
        s = 0.5 * accel * ta * ta + vmax * (t - ta)
    else:
        tr = duration - t
        s = distance - 0.5 * accel * tr * tr
    return min(max(s / distance, 0.0), 1.0)


@dataclass(frozen=True)
class Path:
    """A planned joint path, not yet timed: samples for s = linspace(0, 1, m) and its length."""

    q: F  # (m, 6) rad; q[0] is the start
    distance: float  # path length in the profile's unit (rad for joint moves, m for linear)
    method: str = "joint"  # "joint", "analytic" or "dls": how the samples were solved


@dataclass
class Motion:
    """One commanded motion: a joint path sampled over normalised path parameter ``s``."""

    t0: float
    duration: float
    path: np.ndarray  # (m, 6) joint samples for s = linspace(0, 1, m)
    distance: float  # path length in the profile's own unit
    accel: float

    @classmethod
    def timed(
        cls, path: Path, speed: float, accel: float, t0: float, qd_max: F | None = None
    ) -> Motion:
        """The motion along ``path`` starting at ``t0`` with a trapezoidal profile.

        ``qd_max`` (rad/s per joint): the arm's joint speed limits; the cruise speed is
        lowered until no joint exceeds its limit anywhere on the path (:func:`speed_cap`),
        as the controller scales a move down rather than overspeed a joint.
        """
        d = max(path.distance, 1e-12)
        if qd_max is not None:
            speed = min(speed, speed_cap(path, qd_max))
        return cls(t0, trapezoid_duration(d, speed, accel), path.q, d, accel)

    def fraction(self, t: float) -> float:
        """Fraction of the path covered at controller time ``t``."""
        return trapezoid_fraction(t - self.t0, self.duration, self.distance, self.accel)

    def q_at(self, t: float) -> tuple[np.ndarray, bool]:
        """Joint target at time ``t`` and whether the motion is finished."""
        f = self.fraction(t)
        m = self.path.shape[0]
        if m == 1:
            return self.path[0].copy(), True
        x = f * (m - 1)
        i = min(int(x), m - 2)
        w = x - i
        return (1.0 - w) * self.path[i] + w * self.path[i + 1], f >= 1.0


def speed_cap(path: Path, qd_max: F) -> float:
    """The highest path speed (the profile's unit per s) at which no joint of ``path`` moves
    faster than its limit ``qd_max`` (rad/s): joint k turns by ``|Δq_k|`` while the path
    advances by ``distance / (m − 1)`` between two samples."""
    dq = np.abs(np.diff(path.q, axis=0))  # (m - 1, nj)
    if dq.size == 0 or path.distance <= 0.0:
        return math.inf
    ds = path.distance / dq.shape[0]
    rate = dq.max(axis=0) / ds  # rad per unit of path, worst segment, per joint
    with np.errstate(divide="ignore"):
        caps = np.where(rate > 0.0, np.asarray(qd_max, dtype=float) / rate, np.inf)
    return float(caps.min())


def controller_arm(robot: RobotModel) -> RobotModel:
    """The arm as its controller knows it: ``robot``'s kinematics with the arm's own joint
    limits (a built-in arm's, ±360° on a UR; not a cell's planning limits)."""
    if robot.name not in BUILTIN_ROBOTS:
        return robot
    own = builtin_robot(robot.name)
    return replace(robot, q_min=own.q_min, q_max=own.q_max)


def joint_path(q0: np.ndarray, q1: np.ndarray) -> Path:
    """The synchronised joint move from ``q0`` to ``q1`` (distance: the largest joint travel)."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    return Path(np.stack([q0, q1]), float(np.max(np.abs(q1 - q0))), "joint")


def linear_targets(
    robot: RobotModel, tcp: np.ndarray, q0: np.ndarray, T_goal: np.ndarray
) -> tuple[F, float]:
    """Flange poses along the straight TCP line from ``q0`` to ``T_goal``, and its distance.

    Returns the flange poses of the samples after the start, shape (m − 1, 4, 4), and the
    profile distance in metres (rotation-only moves count 0.1 m per rad).
    """
    T0 = robot.fk(q0) @ tcp
    dp = T_goal[:3, 3] - T0[:3, 3]
    dr = log_so3(T_goal[:3, :3] @ T0[:3, :3].T)
    L = float(np.linalg.norm(dp))
    n = int(np.clip(max(L / LINEAR_STEP_M, np.linalg.norm(dr) / LINEAR_STEP_RAD), 2, 400))
    s = np.linspace(0.0, 1.0, n)[1:, None]
    T = make_T(exp_so3(s * dr) @ T0[:3, :3], T0[:3, 3] + s * dp) @ np.linalg.inv(tcp)
    D = max(L, 0.1 * float(np.linalg.norm(dr)), 1e-12)
    return T, D


def _snap_goal(path: F, q_goal: np.ndarray | None) -> F:
    # moveL_FK: end exactly at the commanded joints when the line arrives at their pose.
    if q_goal is not None and np.max(np.abs(path[-1] - q_goal)) < 1e-3:
        path = path.copy()
        path[-1] = q_goal
    return path


def linear_path_dls(
    robot: RobotModel,
    tcp: np.ndarray,
    q0: np.ndarray,
    T_goal: np.ndarray,
    q_goal: np.ndarray | None = None,
) -> Path:
    """The straight TCP line solved by damped least squares from sample to sample (slow)."""
    Ts, D = linear_targets(robot, tcp, q0, T_goal)
    path = [np.asarray(q0, dtype=float)]
    q = path[0]
    for T in Ts:
        q, _ = ik_dls(robot, T, q, iters=30)
        path.append(q)
    return Path(_snap_goal(np.stack(path), q_goal), D, "dls")


def refine_batch(robot: RobotModel, Ts: F, Q: F, iters: int = 4) -> tuple[F, NDArray[np.bool_]]:
    """Newton steps on every sample at once: joints ``Q`` (m, n) whose flange poses under
    ``robot`` are ``Ts`` (m, 4, 4).  Returns the refined joints and which converged (1e-10).

    For a controller whose calibrated kinematics differ from the nominal UR structure by
    sub-millimetre link deltas: the nominal analytic solution is a start a few Newton steps
    from the calibrated one."""
    Q = np.array(Q, dtype=float)
    m, n = Q.shape
    eps = 1e-7
    eye = np.eye(n) * eps
    ok = np.zeros(m, dtype=bool)
    for _ in range(iters + 1):
        Qe = np.concatenate([Q[:, None, :], Q[:, None, :] + eye[None]], axis=1)  # (m, n+1, n)
        T = robot.fk(Qe.reshape(-1, n)).reshape(m, n + 1, 4, 4)
        err = _pose_errors(Ts, T[:, 0])  # (m, 6)
        ok = np.einsum("mi,mi->m", err, err) < REFINE_TOL**2
        if np.all(ok):
            break
        J = np.stack([_pose_errors(T[:, k + 1], T[:, 0]) for k in range(n)], axis=-1) / eps
        JJt = J @ np.swapaxes(J, 1, 2) + 1e-12 * np.eye(6)
        dq = np.einsum("mji,mj->mi", J, np.linalg.solve(JJt, err[..., None])[..., 0])
        Q = np.where(ok[:, None], Q, Q + dq)
    return Q, ok


def _pose_errors(T_goal: F, T: F) -> F:
    """:func:`_pose_error` of stacks of transforms, shape (m, 6)."""
    dp = T_goal[:, :3, 3] - T[:, :3, 3]
    R = T_goal[:, :3, :3] @ np.swapaxes(T[:, :3, :3], 1, 2)
    return np.concatenate([dp, log_so3(R)], axis=-1)


def _track_analytic(
    robot: RobotModel, q0: np.ndarray, Ts: F, ik_model: RobotModel | None = None
) -> F | None:
    """Joint samples for flange poses ``Ts`` continuing from ``q0``, or None if not analytic.

    All eight solutions of every sample come from one vectorised call; each branch is made
    continuous from the start (2π steps removed).  The branch taken is the one that starts
    nearest ``q0``; it must be the solution nearest the previous sample at every sample
    (what sample-to-sample DLS converges to), else None.
    """
    try:
        Q, valid = ik_ur(ik_model or robot, Ts)  # (m, 8, 6), (m, 8)
    except InputError:
        return None
    if not np.all(np.any(valid, axis=1)):
        return None  # a sample out of reach: DLS does what the old controller did
    Qz = np.where(valid[..., None], Q, 0.0)
    # Each branch made continuous and anchored at q0.
    first = q0 + _wrap(Qz[0] - q0)  # (8, 6)
    steps = _wrap(np.diff(Qz, axis=0))  # (m-1, 8, 6)
    C = np.concatenate([first[None], first[None] + np.cumsum(steps, axis=0)])  # (m, 8, 6)
    jump = np.max(
        np.abs(np.diff(np.concatenate([np.broadcast_to(q0, (1, 8, 6)), C]), axis=0)), axis=(0, 2)
    )
    usable = np.all(valid, axis=0) & (jump < MAX_JOINT_STEP)
    if not np.any(usable):
        return None
    start = np.where(usable, np.max(np.abs(C[0] - q0), axis=-1), np.inf)
    k = int(np.argmin(start))
    path = C[:, k]  # (m, 6)
    prev = np.concatenate([q0[None], path[:-1]])
    dist = np.where(valid, np.max(np.abs(_wrap(Q - prev[:, None])), axis=-1), np.inf)
    if not np.all(np.argmin(dist, axis=1) == k):
        return None  # another branch is nearer somewhere: near a singularity
    # Residual check; Newton steps where the closed form is not exact enough (the nominal
    # solution of a calibrated controller, a sample near a singularity).
    T = robot.fk(path)
    dp = np.linalg.norm(T[:, :3, 3] - Ts[:, :3, 3], axis=-1)
    dR = np.linalg.norm(T[:, :3, :3] - Ts[:, :3, :3], axis=(-2, -1))
    bad = np.flatnonzero((dp > REFINE_TOL) | (dR > REFINE_TOL))
    if bad.size:
        path = path.copy()
        path[bad], ok = refine_batch(robot, Ts[bad], path[bad], iters=5)
        if not np.all(ok):
            return None
    return path


def linear_path(
    robot: RobotModel,
    tcp: np.ndarray,
    q0: np.ndarray,
    T_goal: np.ndarray,
    q_goal: np.ndarray | None = None,
    ik_model: RobotModel | None = None,
) -> Path:
    """The straight TCP line from joints ``q0`` to the TCP pose ``T_goal`` (base frame).

    ``q_goal`` (moveL_FK): the joints the move must end at (the same TCP pose).  Analytic IK
    for all samples at once; DLS from sample to sample where that is not possible.
    ``ik_model``: the nominal UR model whose closed form seeds a calibrated ``robot``.
    """
    q0 = np.asarray(q0, dtype=float)
    Ts, D = linear_targets(robot, tcp, q0, T_goal)
    track = _track_analytic(robot, q0, Ts, ik_model)
    if track is None:
        return linear_path_dls(robot, tcp, q0, T_goal, q_goal)
    return Path(_snap_goal(np.concatenate([q0[None], track]), q_goal), D, "analytic")


def ik_near(
    robot: RobotModel,
    tcp: np.ndarray,
    T_tcp: np.ndarray,
    q_ref: np.ndarray,
    ik_model: RobotModel | None = None,
) -> tuple[F, bool]:
    """Joints reaching TCP pose ``T_tcp`` nearest ``q_ref`` (moveJ_IK); returns (q, found)."""
    q_ref = np.asarray(q_ref, dtype=float)
    T = T_tcp @ np.linalg.inv(tcp)
    try:
        Q, valid = ik_ur(ik_model or robot, T)
    except InputError:
        return ik_dls(robot, T, q_ref)
    if not np.any(valid):
        return ik_dls(robot, T, q_ref)
    cand = q_ref + _wrap(np.where(valid[:, None], Q, 0.0) - q_ref)
    cost = np.where(valid, np.max(np.abs(cand - q_ref), axis=-1), np.inf)
    q = cand[int(np.argmin(cost))]
    return ik_dls(robot, T, q, iters=8)


def ik_ur(robot: RobotModel, T: F) -> tuple[F, NDArray[np.bool_]]:
    """The analytic UR IK (:func:`~quickhealth.station.planning.ik_ur.ik_ur`)."""
    return _ik_ur(robot, T)


# (q, approach, joint_temp=, joint_torque=) -> T_instr_target: the arm's state at the pose
Truth = Callable[..., np.ndarray]


class Arm:
    """Simulated joint state with timed motion, ringing after stops and encoder noise.

    Thread-safe: every method takes the arm's own lock for a few microseconds.  Planning a
    path (:func:`linear_path`) is not a method: callers plan outside any lock and
    :meth:`start` the timed result.
    """

    RING_AMPLITUDE = 1.5e-4  # rad
    RING_TAU = 0.06  # s
    RING_FREQ = 8.0  # Hz
    NOISE = 1e-6  # rad

    def __init__(
        self,
        robot: RobotModel,
        q0: np.ndarray,
        truth: Truth | None = None,
        ik_model: RobotModel | None = None,
    ) -> None:
        self.robot = robot  # the kinematics the controller computes with (its calibration)
        self.ik_model = ik_model  # the nominal UR model whose closed-form IK seeds it
        self.truth = truth
        self.q_cmd = np.array(q0, dtype=float)
        self.motion: Motion | None = None
        self.stop_time = -10.0
        self.ring_dir = np.zeros(6)
        self.rng = np.random.default_rng(7)
        self.lock = threading.RLock()
        self.tcp = np.eye(4)
        self.approach = np.ones(len(q0))  # direction each joint last moved in (+1 / -1)
        self._pose_fk = PoseFK(robot)

    def target(self, now: float) -> tuple[np.ndarray, bool]:
        """Commanded joints now and whether the current motion (if any) is finished."""
        with self.lock:
            if self.motion is None:
                return self.q_cmd.copy(), True
            q, done = self.motion.q_at(now)
            if done:
                self.q_cmd = self.motion.path[-1].copy()
                self._start_ringing(now, self.motion)
                self.motion = None
                return self.q_cmd.copy(), True
            return q, False

    def _set_approach(self, q0: np.ndarray, q1: np.ndarray) -> None:
        d = np.asarray(q1) - np.asarray(q0)
        self.approach = np.where(np.abs(d) > 1e-9, np.sign(d), self.approach)

    def _start_ringing(self, now: float, motion: Motion) -> None:
        d = motion.path[-1] - motion.path[max(0, motion.path.shape[0] - 2)]
        n = np.linalg.norm(d)
        self.ring_dir = d / n if n > 0 else np.zeros(6)
        self.stop_time = now

    def actual(self, now: float) -> np.ndarray:
        """Actual (encoder) joints: the target plus post-stop ringing and noise."""
        with self.lock:
            q, _ = self.target(now)
            dt = now - self.stop_time
            ring_dir = self.ring_dir
        if 0.0 <= dt < 8 * self.RING_TAU:
            q = q + ring_dir * (
                self.RING_AMPLITUDE
                * math.exp(-dt / self.RING_TAU)
                * math.sin(2 * math.pi * self.RING_FREQ * dt)
            )
        return q + self.rng.normal(0.0, self.NOISE, 6)

    def derivatives(self, now: float, h: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Commanded joint velocity and acceleration now (rad/s, rad/s²) from the timed motion
        (central differences over ±``h``; zeros at rest).  No side effects."""
        with self.lock:
            m = self.motion
        if m is None:
            return np.zeros(self.q_cmd.shape), np.zeros(self.q_cmd.shape)
        qa, _ = m.q_at(now - h)
        qb, _ = m.q_at(now)
        qc, _ = m.q_at(now + h)
        return (qc - qa) / (2.0 * h), (qc - 2.0 * qb + qa) / (h * h)

    def moving(self, now: float) -> bool:
        """True while a motion runs."""
        return not self.target(now)[1]

    def hold(self, now: float) -> np.ndarray:
        """Stop the current motion where it is, without ringing (a new motion starts here)."""
        with self.lock:
            q, _ = self.target(now)
            self.motion = None
            self.q_cmd = q
            return q.copy()

    def start(self, motion: Motion) -> None:
        """Run ``motion`` (planned from the joints :meth:`hold` returned)."""
        with self.lock:
            self.q_cmd = np.array(motion.path[0], dtype=float)
            p = motion.path
            self._set_approach(p[-2] if len(p) > 1 else p[0], p[-1])
            self.motion = motion

    def move_joint(self, q: np.ndarray, speed: float, accel: float, now: float) -> Motion:
        """Start a synchronised trapezoidal joint move (within the joint speed limits)."""
        with self.lock:
            m = Motion.timed(joint_path(self.hold(now), q), speed, accel, now, self.robot.qd_max)
            self.start(m)
            return m

    def move_linear(
        self,
        T_goal: np.ndarray,
        speed: float,
        accel: float,
        now: float,
        q_goal: np.ndarray | None = None,
    ) -> Motion:
        """Plan (in this thread) and start a straight-line TCP move to ``T_goal`` (base frame).

        ``q_goal`` (moveL_FK): the joints the move must end at (the same TCP pose).  The
        controller simulator does not use this: it plans in its planner thread.
        """
        q0 = self.hold(now)
        path = linear_path(self.robot, self.tcp, q0, T_goal, q_goal, self.ik_model)
        m = Motion.timed(path, speed, accel, now, self.robot.qd_max)
        self.start(m)
        return m

    def halt(self, now: float) -> None:
        """Stop where the arm is now (protective stop, stopJ)."""
        with self.lock:
            q, done = self.target(now)
            if not done and self.motion is not None:
                self._start_ringing(now, self.motion)
            self.motion = None
            self.q_cmd = q

    def tcp_pose(self, q: np.ndarray) -> list[float]:
        """The controller's TCP report: its kinematics (``robot``) of the joints ``q``."""
        return self._pose_fk(q, self.tcp)
