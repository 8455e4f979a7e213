"""The reference 7D camera design (docs/vision.md): what the simulated cell and the tests use.

Two 12 MP cameras (4000×3000 px, 3.2 µm pixels, 12.8 × 9.6 mm sensor) with 16 mm lenses
(fx = fy = 5000 px), mild barrel distortion, 800 mm apart and each turned in by
atan(0.4 / 2) = 11.3° so the optical axes cross 2 m in front of the rig; the smart target of
:func:`~quickhealth.vision.boards.reference_target` (48 markers, 192 corners).

At 2.5 m the per-corner depth noise is Z²·σ_d/(f·B) ≈ 0.44 mm for σ = 0.2 px per image
(σ_d = √2 · 0.2 px); averaged over ≈ 190 corners in each camera this is ≈ 0.03 mm, inside
the 0.05 mm requirement (the Cramér–Rao bound of :func:`~quickhealth.vision.pose7d.pose_crb`
gives the exact figure for any pose).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.transforms import inv_T, make_T, rot_y

from .camera import CameraModel, StereoRig

F = NDArray[np.float64]

#: Half the baseline and the distance at which the optical axes cross, m.
HALF_BASELINE = 0.4
CONVERGENCE = 2.0


def T_rig_cameras() -> tuple[F, F]:
    """Poses of the left and right cameras in the rig frame (midpoint, z forward, y down)."""
    a = np.arctan2(HALF_BASELINE, CONVERGENCE)
    T_rig_left = make_T(rot_y(a), [-HALF_BASELINE, 0.0, 0.0])
    T_rig_right = make_T(rot_y(-a), [HALF_BASELINE, 0.0, 0.0])
    return T_rig_left, T_rig_right


def reference_rig() -> StereoRig:
    """The reference stereo pair as calibrated (the simulated cell's cameras)."""
    size = (4000, 3000)
    K_l = np.array([[5000.0, 0.0, 2003.5], [0.0, 5000.0, 1496.2], [0.0, 0.0, 1.0]])
    K_r = np.array([[4996.0, 0.0, 1995.8], [0.0, 4996.0, 1502.9], [0.0, 0.0, 1.0]])
    d_l = np.array([-0.08, 0.12, 0.0002, -0.0001, 0.0])
    d_r = np.array([-0.075, 0.11, -0.0001, 0.0002, 0.0])
    T_rig_left, T_rig_right = T_rig_cameras()
    return StereoRig(
        CameraModel(K_l, d_l, size), CameraModel(K_r, d_r, size), inv_T(T_rig_left) @ T_rig_right
    )


def T_left_rig() -> F:
    """Maps points from the rig frame into the left camera (instrument) frame."""
    return inv_T(T_rig_cameras()[0])
