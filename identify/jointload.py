"""What a controller reports about each joint at a pose: the torque its drive exerts and its
temperature, warmed by its duty.

One model for the digital twin (:func:`~quickhealth.identify.twin.joint_schedules`) and the
simulated UR controller (``station/sim/dynamics.py``), and the torque constants the station's
driver turns motor currents into torques with.

Torque.  At rest a joint's drive holds the arm, its payload included, against gravity:
``τ_drive = −τ_gravity`` (:func:`~quickhealth.identify.robot.gravity_torques` of the robot
carrying the payload; N·m about the joint axis).  A controller that reports currents gives
``τ = I · k_t`` with the joint's torque constant at its output (motor constant times gear
ratio: a robot file states them per joint, ``torque_constant`` in each ``[[joint]]``; UR
publishes none for its arms, so the built-in arms use the estimate :data:`TORQUE_CONSTANT`,
13 N·m/A for the three large joints and 9.3 for the wrist joints).  An error in ``k_t`` of joint
K only rescales joint K's torques, which a compliance driven by them absorbs into its ``c``.

Temperature.  Each joint is a first-order thermal system: its winding's ``R · I²``, the
mechanical work ``|τ · q̇|`` its gear turns to heat and the electronics' idle power heat it,
and it cools towards the ambient temperature through :data:`THERMAL_RESISTANCE`::

    T_j(t + dt) = T_ss + (T_j(t) − T_ss) · exp(−dt / τ_j),   T_ss = T_amb + R_th · P_j

with the time constants :data:`THERMAL_TAU_S` (the large joints' greater mass warms and cools
more slowly).  A shoulder that holds 40 N·m and moves half the time warms by about 10 K in
the first twenty minutes of a run.

SYNOPSIS::

    tau = drive_torques(robot, q, payload_kg=np.array([0.0, 1.5, …]))   # (n, nj) N·m
    temps = warm_up(time, q, tau, ambient=np.full(n, 22.0))              # (n, nj) °C
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .robot import RobotModel, gravity_torques, with_payload

F = NDArray[np.float64]

#: Torque constant at each joint's output (N·m per A of motor current): an estimate for the
#: built-in UR arms (three large joints, three wrist joints).
TORQUE_CONSTANT = np.array([13.0, 13.0, 13.0, 9.3, 9.3, 9.3])
WINDING_OHM = 0.25  # Ω, per joint
THERMAL_RESISTANCE = 1.6  # K/W, joint to ambient
#: Time constant (s) of each joint's temperature: base, shoulder, elbow, three wrist joints.
THERMAL_TAU_S = np.array([1500.0, 1500.0, 1200.0, 700.0, 700.0, 700.0])
IDLE_W = 2.5  # W of electronics in every powered joint


def torque_constant(robot: RobotModel | int) -> F:
    """Torque constants (N·m/A) of an arm's joints: those its robot file states
    (:attr:`~quickhealth.identify.robot.RobotModel.torque_constant`), else the estimate
    :data:`TORQUE_CONSTANT` (``robot`` may be just the number of joints)."""
    if isinstance(robot, RobotModel):
        if robot.torque_constant is not None:
            return np.asarray(robot.torque_constant, dtype=float).copy()
        n_joints = robot.n_joints
    else:
        n_joints = int(robot)
    if n_joints == TORQUE_CONSTANT.size:
        return TORQUE_CONSTANT.copy()
    # another arm: the large joints' value for the first half, the wrists' for the rest
    k = np.full(n_joints, TORQUE_CONSTANT[-1])
    k[: (n_joints + 1) // 2] = TORQUE_CONSTANT[0]
    return k


def thermal_tau(n_joints: int) -> F:
    """The time constants (s) of an arm's ``n_joints`` joints (:data:`THERMAL_TAU_S`)."""
    if n_joints == THERMAL_TAU_S.size:
        return THERMAL_TAU_S.copy()
    k = np.full(n_joints, THERMAL_TAU_S[-1])
    k[: (n_joints + 1) // 2] = THERMAL_TAU_S[0]
    return k


def joint_power(current: F, torque: F, qd: F, powered: bool = True) -> F:
    """Heat (W) in each joint: ``R · I² + |τ · q̇|`` plus the idle power when powered."""
    p = WINDING_OHM * np.asarray(current) ** 2 + np.abs(np.asarray(torque) * np.asarray(qd))
    return p + IDLE_W if powered else p


@dataclass
class JointThermal:
    """The joints' temperatures (°C), advanced by :meth:`advance`."""

    temps: F

    @classmethod
    def start(cls, n: int, ambient_c: float, powered: bool = True) -> JointThermal:
        """Joints at the steady temperature of an idle (powered) or unpowered arm."""
        rise = THERMAL_RESISTANCE * IDLE_W if powered else 0.0
        return cls(np.full(n, float(ambient_c) + rise))

    def advance(self, dt: float, power: F, ambient_c: float) -> F:
        """Integrate ``dt`` seconds with ``power`` (W per joint); returns the temperatures."""
        steady = ambient_c + THERMAL_RESISTANCE * np.asarray(power, dtype=float)
        decay = np.exp(-max(dt, 0.0) / thermal_tau(self.temps.size))
        self.temps = steady + (self.temps - steady) * decay
        return self.temps.copy()


def drive_torques(
    robot: RobotModel,
    q: ArrayLike,
    payload_kg: float | ArrayLike = 0.0,
    payload_com: ArrayLike = (0.0, 0.0, 0.05),
) -> F:
    """The torque (N·m) each joint's drive exerts to hold the arm at rest at ``q`` (n, nj),
    carrying ``payload_kg`` (one mass, or one per pose) at ``payload_com`` (m, flange frame):
    minus the gravity torque of arm and payload.  Needs the robot's link masses."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    m = np.broadcast_to(np.asarray(payload_kg, dtype=float), (q.shape[0],))
    if np.any(~np.isfinite(m)) or np.any(m < 0):
        raise ValueError("payload masses must be finite and not negative")
    tau0 = gravity_torques(robot, q)
    if not np.any(m):
        return -tau0
    # gravity torques are linear in the payload's mass at a fixed centre of mass
    unit = gravity_torques(with_payload(robot, 1.0, payload_com), q) - tau0
    return -(tau0 + m[:, None] * unit)


def warm_up(
    time: ArrayLike,
    q: ArrayLike,
    torque: ArrayLike,
    ambient: ArrayLike,
    start: ArrayLike | None = None,
) -> F:
    """Each joint's temperature (°C) at every pose of a run (n, nj).

    ``time`` (n,) s of the poses in execution order, ``q`` (n, nj) rad, ``torque`` (n, nj)
    N·m the drives exert, ``ambient`` (n,) °C.  Between two poses each joint carries the
    torque of the pose it leaves and moves at the mean speed of the leg (``|Δq| / Δt``):
    its heat is :func:`joint_power` with ``I = τ / k_t``.  ``start``: the temperatures at the
    first pose (default: the ambient temperature, a cold arm just powered on).
    """
    t = np.asarray(time, dtype=float).reshape(-1)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    tau = np.atleast_2d(np.asarray(torque, dtype=float))
    amb = np.broadcast_to(np.asarray(ambient, dtype=float), t.shape)
    n, nj = q.shape
    kt = torque_constant(nj)
    first = np.full(nj, amb[0]) if start is None else np.asarray(start, dtype=float)
    th = JointThermal(first.copy())
    out = np.empty((n, nj))
    out[0] = th.temps
    for i in range(1, n):  # a first-order recursion: one step per leg of the run
        dt = t[i] - t[i - 1]
        qd = (q[i] - q[i - 1]) / dt if dt > 0 else np.zeros(nj)
        out[i] = th.advance(dt, joint_power(tau[i - 1] / kt, tau[i - 1], qd), amb[i])
    return out
