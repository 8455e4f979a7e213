"""ISO 9283 pose accuracy and repeatability at plan poses visited more than once (SI).

Position: accuracy AP_P (§7.2.1) and repeatability RP_l (§7.2.3); for pose (7D) data also the
orientation components a, b, c about the robot base's axes.  Pure: arrays in, frozen records
out; the report (:mod:`quickhealth.station.services.report`) shows them.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.errormodel import constant_motions
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.transforms import log_so3, small_error_transform

F = NDArray[np.float64]

_ISO_NAME = re.compile(r"^(ISO_P[1-5])_C\d+$")


def iso_pose_name(point: int, cycle: int) -> str:
    """The plan's name of ISO 9283 point ``point`` (1–5) in cycle ``cycle``: ``ISO_P3_C02``."""
    return f"ISO_P{point}_C{cycle:02d}"


def iso_point(pose_id: str) -> str:
    """The pose a measured row stands for: an ISO cube visit's point (``ISO_P3_C02`` →
    ``ISO_P3``, ``plan --iso9283``), any other pose id as it is."""
    m = _ISO_NAME.match(pose_id)
    return m.group(1) if m else pose_id


@dataclass(frozen=True)
class PoseStats:
    """ISO 9283-style figures of one repeatedly visited pose (m, rad).

    Position: ``accuracy`` AP_P, ``repeatability`` RP_l.  Orientation (pose data only, else
    None), per rotation component a, b, c about the robot base's x, y, z axes:
    ``accuracy_abc`` AP_a, AP_b, AP_c (signed mean deviation from the commanded orientation)
    and ``repeatability_abc`` RP_a, RP_b, RP_c (the ± half-width ``3 S``).
    """

    pose_id: str
    n: int
    accuracy: float  # AP_P: distance of the barycentre of attained positions from the command
    repeatability: (
        float  # RP_l = l̄ + 3 S_l, l = distance of each attained position to the barycentre
    )
    accuracy_abc: F | None = None  # (3,) rad
    repeatability_abc: F | None = None  # (3,) rad


def iso9283_pose_stats(
    pose_id: tuple[str, ...],
    attained: F,
    commanded: F,
    attained_R: F | None = None,
    commanded_R: F | None = None,
    R_meas_base: F | None = None,
) -> list[PoseStats]:
    """Pose accuracy and repeatability (ISO 9283 §7.2.1, §7.2.3) at poses visited ≥ 2 times.

    Parameters
    ----------
    pose_id : tuple of str, length n
    attained : ndarray, shape (n, 3), m
        Measured positions.
    commanded : ndarray, shape (n, 3), m
        Commanded positions in the same frame (the nominal kinematics with the identified
        base and tool).
    attained_R, commanded_R : ndarray, shape (n, 3, 3), optional
        Measured and commanded orientations (same frame): adds the orientation figures.
    R_meas_base : ndarray, shape (3, 3), optional
        The robot base's axes in that frame: the components a, b, c are rotations about them
        (ISO 9283 states orientation in the base coordinate system); default the frame's own.

    Orientation: the attained deviation of visit j is the small rotation
    ``δ_j = log(R_attained,j · R_commandedᵀ)`` expressed in base axes, ``(a_j − a_c, b_j − b_c,
    c_j − c_c)`` to first order; ``AP_abc = mean_j δ_j`` (§7.2.1: ``ā − a_c`` …) and
    ``RP_abc = 3 S`` with ``S = sqrt(Σ (δ_j − δ̄)² / (n − 1))`` per component (§7.2.3).

    Returns
    -------
    list of PoseStats, one per repeated pose, in first-visit order.
    """
    delta = None
    if attained_R is not None and commanded_R is not None:
        w = log_so3(np.asarray(attained_R) @ np.swapaxes(np.asarray(commanded_R), -1, -2))
        R_b = np.eye(3) if R_meas_base is None else np.asarray(R_meas_base, float)
        delta = w @ R_b  # rows: R_bᵀ w, the rotation about the base axes
    out = []
    ids = np.asarray(pose_id)
    seen: list[str] = []
    for p in ids:
        if p not in seen:
            seen.append(str(p))
    for p in seen:
        sel = ids == p
        n = int(sel.sum())
        if n < 2:
            continue
        a = attained[sel]
        bary = a.mean(axis=0)
        l = np.linalg.norm(a - bary, axis=1)
        s_l = math.sqrt(float(np.sum((l - l.mean()) ** 2)) / (n - 1))
        ap = float(np.linalg.norm(bary - commanded[sel].mean(axis=0)))
        ap_abc = rp_abc = None
        if delta is not None:
            d = delta[sel]
            ap_abc = d.mean(axis=0)
            rp_abc = 3.0 * d.std(axis=0, ddof=1)
        out.append(PoseStats(p, n, ap, float(l.mean() + 3 * s_l), ap_abc, rp_abc))
    return out


def run_pose_stats(fitted: FittedModel, meas: Measurements) -> list[PoseStats]:
    """The statistics of a fitted run: attained = measured, commanded = the nominal kinematics
    with the identified base and tool; orientation about the identified robot base's axes."""
    if meas.pose_id is None:
        return []
    T_cmd = fitted.nominal_pose(meas.q)
    rot = meas.has_orientation
    m0 = constant_motions(fitted.spec, fitted.coeffs, 0)
    R_base = (fitted.T_instr_base0 @ small_error_transform(m0[:3], m0[3:]))[:3, :3]
    return iso9283_pose_stats(
        tuple(iso_point(p) for p in meas.pose_id),
        meas.pos,
        T_cmd[:, :3, 3],
        meas.R if rot else None,
        T_cmd[:, :3, :3] if rot else None,
        R_base,
    )
