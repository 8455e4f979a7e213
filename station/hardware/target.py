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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.transforms import inv_T, make_T, rot_x, rot_y

F = NDArray[np.float64]


def T_target_plate(pan: float) -> F:
    """Plate frame in the target frame at pan angle ``pan`` (rad)."""
    return make_T(rot_y(pan) @ rot_x(np.pi), np.zeros(3))


def target0_from_plate(T_instr_plate: F, pan: float) -> F:
    """Target frame at pan 0 from a measured plate pose and the motor's pan angle."""
    return T_instr_plate @ inv_T(T_target_plate(pan))
