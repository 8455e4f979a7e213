"""The smart target's frames: the plan's target frame and the printed plate the camera sees.

- *Target frame* (planning/cell.py, plan.json, the CSV rows): at pan 0 fixed to the flange;
  z is the marker normal pointing out of the plate towards the cameras, y the pan axis.
  The pan motor turns the plate about y by ``pan`` (rad, right-handed).
- *Plate frame* (vision: the marker corners of the target description): x right and y down
  as printed, z *into* the plate (a camera looking at the printed side has the plate's z
  along its own optical axis).

``T_target_plate(pan) = Ry(pan) · Rx(π)``.  The measurement records the target frame at pan
0 (``T_instr_target0 = T_instr_plate · T_target_plate(pan)⁻¹``), so rows measured at different
pan angles describe the same rigid tool and the position (on the pan axis) does not depend on
the pan angle at all.

The printed patterns are the reference designs: :func:`reference_target` (vision's smart
target) and :func:`reference_board` (the fixed board of the instrument self-check).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...identify.transforms import inv_T, make_T, rot_x, rot_y
from ...vision.boards import TargetDescription, grid_markers
from ...vision.boards import reference_target as _reference_target

F = NDArray[np.float64]


def T_target_plate(pan: float) -> F:
    """Plate frame in the target frame at pan angle ``pan`` (rad)."""
    return make_T(rot_y(pan) @ rot_x(np.pi), np.zeros(3))


def target0_from_plate(T_instr_plate: F, pan: float) -> F:
    """Target frame at pan 0 from a measured plate pose and the motor's pan angle."""
    return T_instr_plate @ inv_T(T_target_plate(pan))


def reference_board() -> TargetDescription:
    """The fixed self-check board: 6×6 DICT_5X5_50 markers, 36 mm on a 48 mm pitch.

    A different dictionary from the smart target's, so the two are never confused.
    """
    ids, corners = grid_markers(6, 6, 0.036, 0.048, 0)
    plate = np.array([[-0.15, -0.16], [0.15, 0.16]])
    return TargetDescription(
        "selfcheck-6x6-5x5", "DICT_5X5_50", ids, corners, plate, np.array([0.0, 1.0, 0.0])
    )


def reference_target() -> TargetDescription:
    """The smart target on the pan motor (vision's reference design)."""
    return _reference_target()
