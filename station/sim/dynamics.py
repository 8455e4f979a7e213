"""The simulated arm's dynamics: joint torques, motor currents and joint temperatures.

Torques come from the recursive Newton-Euler algorithm (pinocchio) on a rigid-body model of
the arm built from its published link masses and centres of mass
(:data:`quickhealth.identify.robot.UR_ARMS`), plus the payload, plus joint friction:

    τ = M(q) q̈ + C(q, q̇) q̇ + g(q) + τ_friction(q̇)

UR publishes no link inertia tensors in its DH table: each link's rotational inertia is
taken as that of a uniform sphere about its centre of mass whose radius grows with the
link's mass (:data:`GYRATION_M`), an estimate.  The gravity part equals
:func:`quickhealth.identify.robot.gravity_torques` (with the opposite sign: the motors
hold the arm up against gravity), which a test checks.

What is reported, as on a real controller:

- ``actual_current`` (A): the torque the *real* arm needs (the true payload) divided by the
  joint's torque constant, with a little noise; ``target_current``: the controller's own
  model (the payload it was told, ``set_payload``) along the target motion.
- ``actual_current_as_torque`` (N·m): the real torque.
- ``get_joint_torques()`` (URScript; ur-rtde's ``getJointTorques``): UR's definition, "the
  torque on the joints, corrected by the torque needed to move the robot itself (gravity,
  friction, etc.)": the real torque minus the controller's model, so a payload the
  controller was not told about shows here.
- ``joint_temperatures`` (°C): a first-order thermal model per joint, heated by the
  winding's I²R and the mechanical work |τ q̇|, cooled towards the ambient temperature with
  each joint's time constant (:mod:`quickhealth.identify.jointload`, the digital twin's
  model too: 1500 s for base and shoulder, 1200 s for the elbow, 700 s for the wrists).  An
  arm run N× faster than life (the speed factor) warms as in N× the time, with the loads of
  the motion at life speed.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.jointload import TORQUE_CONSTANT, JointThermal, joint_power
from ...identify.robot import GRAVITY, RobotModel, with_payload

__all__ = ["TORQUE_CONSTANT", "ArmDynamics", "Thermal"]

F = NDArray[np.float64]

GYRATION_M = 0.04  # m, radius of gyration of a 1 kg link; scales with mass^(1/3)
FRICTION_COULOMB = np.array([2.5, 2.5, 2.0, 0.8, 0.8, 0.8])  # N·m
FRICTION_VISCOUS = np.array([3.0, 3.0, 2.0, 0.8, 0.8, 0.8])  # N·m·s/rad
AMBIENT_C = 25.0


def _pin_model(robot: RobotModel):  # type: ignore[no-untyped-def]
    import pinocchio as pin

    if robot.masses is None or robot.coms is None:
        raise ValueError(f"robot {robot.name!r} has no link masses and centres of mass")
    model = pin.Model()
    model.gravity.linear = np.asarray(GRAVITY, dtype=float)
    parent = 0
    links = np.asarray(robot.links, dtype=float)
    for i in range(robot.n_joints):
        P = links[i].copy()
        off = float(robot.q_offset[i])
        if off:
            c, s = np.cos(off), np.sin(off)
            Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            P[:3, :3] = P[:3, :3] @ Rz
        jid = model.addJoint(parent, pin.JointModelRZ(), pin.SE3(P[:3, :3], P[:3, 3]), f"j{i + 1}")
        m = float(robot.masses[i])
        C = links[i + 1]
        com = C[:3, :3] @ np.asarray(robot.coms[i], dtype=float) + C[:3, 3]
        r = GYRATION_M * max(m, 1e-3) ** (1.0 / 3.0)
        inertia = pin.Inertia(m, com, np.eye(3) * 0.4 * m * r * r)
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        parent = jid
    return model


class ArmDynamics:
    """Inverse dynamics of one arm with a payload (pinocchio RNEA, ~10 µs a call)."""

    def __init__(self, robot: RobotModel, payload_kg: float = 0.0, payload_com: F | None = None):
        import pinocchio as pin  # pinocchio (0.3 s) only once an arm carries a payload

        self._pin = pin
        com = np.zeros(3) if payload_com is None else np.asarray(payload_com, float)
        self.robot = with_payload(robot, payload_kg, com)
        self.payload_kg = float(payload_kg)
        self.payload_com = com
        self.model = _pin_model(self.robot)
        self.data = self.model.createData()
        self._lock = threading.Lock()  # pinocchio's data is scratch space: one caller at a time

    def torques(self, q: F, qd: F, qdd: F, friction: bool = True) -> F:
        """Joint torques (N·m) the motors apply to follow ``q, qd, qdd``."""
        with self._lock:
            tau = np.array(self._pin.rnea(self.model, self.data, q, qd, qdd))
        if friction:
            tau += FRICTION_COULOMB * np.tanh(np.asarray(qd) / 0.01) + FRICTION_VISCOUS * qd
        return tau


@dataclass
class Thermal:
    """Joint temperatures (°C): :class:`~quickhealth.identify.jointload.JointThermal` on the
    controller's clock, heated by I²R + |τ q̇| (+ idle) towards :data:`AMBIENT_C`."""

    joints: JointThermal
    t_last: float | None = None

    @classmethod
    def start(cls, n: int = 6, powered: bool = True) -> Thermal:
        return cls(JointThermal.start(n, AMBIENT_C, powered))

    @property
    def temps(self) -> F:
        """The temperatures now (°C)."""
        return self.joints.temps.copy()

    def advance(
        self, t: float, current: F, tau: F, qd: F, powered: bool, time_scale: float = 1.0
    ) -> F:
        """Integrate to controller time ``t`` with the present loads (at life speed) over
        ``time_scale`` × the elapsed time; returns the temperatures."""
        if self.t_last is None or t <= self.t_last:
            self.t_last = t
            return self.temps
        dt = min(t - self.t_last, 1.0) * time_scale
        self.t_last = t
        return self.joints.advance(dt, joint_power(current, tau, qd, powered), AMBIENT_C)
