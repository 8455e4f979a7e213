"""Measurements: what the instrument saw at each pose, in execution order (SI units).

This is the in-memory form of a measurement file (CSV v1, CONTRACTS.md).  Reading and
writing the file, with its mm/deg units and its one-line errors, happens in
``quickhealth.station.formats``; everything here is SI and already validated.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .transforms import rpy_to_R

F = NDArray[np.float64]


def approach_from_order(q: F) -> F:
    """Approach direction (+1 / −1) of every joint, from the previous row (CSV v1 rule).

    The first row, and joints that did not move, take the direction of the last move of that
    joint (the first row counts as approached from below, +1).  Shape ``(n, nj)``.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    s = np.sign(np.diff(q, axis=0, prepend=q[:1]))
    # carry the last non-zero direction forward: index of the last move up to each row
    idx = np.where(s != 0, np.arange(q.shape[0])[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)
    out = np.take_along_axis(s, np.maximum(last, 0), axis=0)
    return np.where(last >= 0, out, 1.0)


@dataclass(frozen=True, eq=False)
class Measurements:
    """Measured poses of the target, one row per pose, in the order the robot visited them.

    Attributes
    ----------
    q : ndarray, shape (n, nj), rad
        Joint readings.
    pos : ndarray, shape (n, 3), m
        Target point in the instrument frame.
    rpy : ndarray, shape (n, 3), rad, or None
        (pitch, yaw, roll) with ``R = Rz(roll) · Ry(yaw) · Rx(pitch)``, when the orientation
        came as angles (CSV v1 ``pitch, yaw, roll``).
    rot : ndarray, shape (n, 3, 3), or None
        Measured orientation as rotation matrices ``R_instr_target``: the form every
        computation uses (no Euler singularity).  Given directly (a file's quaternion columns),
        or made from ``rpy``.  Both None = position only.
    time : ndarray, shape (n,), s, or None
    temp : ndarray, shape (n,), °C, or None
        Temperature near the robot.
    joint_temp : ndarray, shape (n, nj), °C, or None
        Each joint's temperature as the controller reports it at the pose (CSV v1
        ``temp_j1`` …).
    joint_torque : ndarray, shape (n, nj), N·m, or None
        Each joint's measured torque at the pose: what its drive exerts (CSV v1 ``tau_j1`` …;
        or its current times the joint's torque constant).
    pan : ndarray, shape (n,), rad, or None
        Smart-target pan angle.
    sigma_pos : ndarray, shape (n, 3), m, or None
        Per-row standard uncertainty of the position.
    sigma_rpy : ndarray, shape (n, 3), rad, or None
        Per-row standard uncertainty of the angles.
    sigma_rot : ndarray, shape (n,), rad, or None
        Per-row standard uncertainty of the orientation as one angle: a small rotation about
        any axis (CSV v1 ``srot``); isotropic on the rotation vector, free of singularities.
    pose_id : tuple of str, or None
    meta : dict of str to str
        ``# key: value`` metadata (robot serial, instrument, run id …).
    excluded : ndarray of bool, shape (n,), or None
        Rows kept for the execution order (the next row's approach direction) that carry no
        information: the noise model gives them an uninformative covariance (cross-validation
        leaves poses out this way).  Never read from or written to a file.
    """

    q: F
    pos: F
    rpy: F | None = None
    time: F | None = None
    temp: F | None = None
    pan: F | None = None
    joint_temp: F | None = None
    joint_torque: F | None = None
    sigma_pos: F | None = None
    sigma_rpy: F | None = None
    sigma_rot: F | None = None
    rot: F | None = None
    pose_id: tuple[str, ...] | None = None
    meta: dict[str, str] = field(default_factory=dict)
    excluded: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        n = self.q.shape[0]
        if self.q.ndim != 2 or self.pos.shape != (n, 3):
            raise ValueError(
                f"q must be (n, nj) and pos (n, 3); got {self.q.shape}, {self.pos.shape}"
            )
        for name in ("rpy", "sigma_pos", "sigma_rpy"):
            v = getattr(self, name)
            if v is not None and v.shape != (n, 3):
                raise ValueError(f"{name} must have shape ({n}, 3), got {v.shape}")
        if self.rpy is not None:  # the angles rule when given (``replace`` keeps an old rot)
            object.__setattr__(
                self, "rot", rpy_to_R(self.rpy[:, 0], self.rpy[:, 1], self.rpy[:, 2])
            )
        if self.rot is not None and self.rot.shape != (n, 3, 3):
            raise ValueError(f"rot must have shape ({n}, 3, 3), got {self.rot.shape}")
        if self.sigma_rot is not None and self.rot is None:
            raise ValueError("sigma_rot needs an orientation")
        if self.sigma_rpy is not None and self.rpy is None:
            raise ValueError("sigma_rpy needs the orientation as angles (rpy)")
        for name in ("time", "temp", "pan", "sigma_rot"):
            v = getattr(self, name)
            if v is not None and v.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {v.shape}")
        for name in ("joint_temp", "joint_torque"):
            v = getattr(self, name)
            if v is not None and v.shape != self.q.shape:
                raise ValueError(f"{name} must have shape {self.q.shape}, got {v.shape}")
        if self.excluded is not None and self.excluded.shape != (n,):
            raise ValueError(f"excluded must have shape ({n},), got {self.excluded.shape}")
        if self.pose_id is not None and len(self.pose_id) != n:
            raise ValueError("pose_id needs one entry per row")

    @property
    def n_poses(self) -> int:
        """Number of measured poses."""
        return int(self.q.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return int(self.q.shape[1])

    @property
    def has_orientation(self) -> bool:
        """True for full-pose (7D) data, False for position-only data."""
        return self.rot is not None

    @property
    def R(self) -> F:
        """Measured orientations, shape (n, 3, 3)."""
        if self.rot is None:
            raise ValueError("position-only measurements have no orientation")
        return self.rot

    def position_only(self) -> Measurements:
        """The same poses without their orientation (as a laser tracker's 3-DoF data)."""
        return replace(self, rpy=None, rot=None, sigma_rpy=None, sigma_rot=None)

    def conditions(self) -> dict[str, F | None]:
        """The conditions of every pose, by channel (``time``, ``temp``, ``joint_temp``,
        ``joint_torque``; None where the data have none): the keywords of
        ``FittedModel.predict`` and of the effects' context."""
        return {
            "time": self.time,
            "temp": self.temp,
            "joint_temp": self.joint_temp,
            "joint_torque": self.joint_torque,
        }

    def approach_sign(self) -> F:
        """Approach direction of every joint, from the previous row: see :func:`approach_from_order`."""
        return approach_from_order(self.q)

    def subset(self, idx: NDArray[np.int64] | slice) -> Measurements:
        """Rows ``idx`` (execution order is kept as given)."""

        def take(v):  # type: ignore[no-untyped-def]
            return None if v is None else v[idx]

        pid = None if self.pose_id is None else tuple(np.asarray(self.pose_id, dtype=object)[idx])
        return replace(
            self,
            q=self.q[idx],
            pos=self.pos[idx],
            rpy=take(self.rpy),
            time=take(self.time),
            temp=take(self.temp),
            pan=take(self.pan),
            joint_temp=take(self.joint_temp),
            joint_torque=take(self.joint_torque),
            sigma_pos=take(self.sigma_pos),
            sigma_rpy=take(self.sigma_rpy),
            sigma_rot=take(self.sigma_rot),
            rot=take(self.rot),
            pose_id=pid,
            excluded=take(self.excluded),
        )
