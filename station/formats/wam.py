"""The Barrett WAM laser-tracker data set (``quickhealth identify import-wam``).

The WAM files are one layout of the tracker importer (:mod:`.tracker`, preset ``wam``):
this module keeps the old entry point, with the sign of the ``dif`` columns as an argument.
"""

from __future__ import annotations

import os

from ...identify.measurements import Measurements
from .tracker import PRESETS, layout_with, read_tracker


def read_wam_csv(path: str | os.PathLike[str], sign: float) -> Measurements:
    """The Barrett WAM laser-tracker files (step_order, x_t…, x_dif…, joint_1…7) as Measurements.

    Position = desired + ``sign`` · difference (mm → m); joints deg → rad.  The importer's
    preset ``wam`` with ``deviation_sign=sign``.
    """
    return read_tracker(path, layout_with(PRESETS["wam"], deviation_sign=float(sign)))
