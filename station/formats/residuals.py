"""residuals.csv: measured minus model per pose, as ``identify fit`` writes it beside model.json.

Columns: ``row``, ``pose_id``, ``q1`` … ``qN`` (deg), ``rx_base_mm``, ``ry_base_mm``,
``rz_base_mm`` (the components along the robot base's axes), ``r_mm`` (the length) and, for pose
data, ``rrx_base_deg``, ``rry_base_deg``, ``rrz_base_deg``; then the same components along the
instrument's axes (``rx_instr_mm`` …, ``rrx_instr_deg`` …).  Cells are quoted by the csv module,
so a pose_id holding a comma or a quote stays one cell, and one a spreadsheet would run as a
formula is neutralised (:func:`~.common.csv_cell`).
"""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING

import numpy as np

from .common import csv_cell

if TYPE_CHECKING:  # the type only (the fit loads scipy)
    from ...identify.fit import FittedModel
    from ...identify.measurements import Measurements


def residual_table(fm: FittedModel, meas: Measurements) -> str:
    """The residuals.csv text of model ``fm`` fitted to ``meas`` (mm, deg): the components in
    the robot base frame first (``*_base_*``), then in the instrument's (``*_instr_*``)."""
    from ...identify.report import residuals_in_base  # the fit's library (loaded by now)

    cols = ["row", "pose_id"] + [f"q{i + 1}" for i in range(meas.n_joints)]
    cols += ["rx_base_mm", "ry_base_mm", "rz_base_mm", "r_mm"]
    rot = fm.residual_rot is not None
    if rot:
        cols += ["rrx_base_deg", "rry_base_deg", "rrz_base_deg"]
    cols += ["rx_instr_mm", "ry_instr_mm", "rz_instr_mm"]
    if rot:
        cols += ["rrx_instr_deg", "rry_instr_deg", "rrz_instr_deg"]
    base_pos, base_rot = residuals_in_base(fm)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    qd = np.degrees(meas.q)
    for i in range(fm.n_poses):
        rp = fm.residual_pos[i] * 1e3
        v = [str(i + 1), "" if meas.pose_id is None else csv_cell(str(meas.pose_id[i]))]
        v += [f"{x:.6f}" for x in qd[i]]
        v += [f"{x:.6f}" for x in base_pos[i] * 1e3] + [f"{np.linalg.norm(rp):.6f}"]
        if base_rot is not None:
            v += [f"{x:.7f}" for x in np.degrees(base_rot[i])]
        v += [f"{x:.6f}" for x in rp]
        if fm.residual_rot is not None:
            v += [f"{x:.7f}" for x in np.degrees(fm.residual_rot[i])]
        w.writerow(v)
    return buf.getvalue()
