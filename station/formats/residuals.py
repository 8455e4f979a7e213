"""residuals.csv: measured minus model per pose, as ``identify fit`` writes it beside model.json.

Columns: ``row``, ``pose_id``, ``q1`` … ``qN`` (deg), ``rx_mm``, ``ry_mm``, ``rz_mm``, ``r_mm``
and, for pose data, ``rrx_deg``, ``rry_deg``, ``rrz_deg``.  Cells are quoted by the csv module,
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
    """The residuals.csv text of model ``fm`` fitted to ``meas`` (mm, deg)."""
    cols = ["row", "pose_id"] + [f"q{i + 1}" for i in range(meas.n_joints)]
    cols += ["rx_mm", "ry_mm", "rz_mm", "r_mm"]
    if fm.residual_rot is not None:
        cols += ["rrx_deg", "rry_deg", "rrz_deg"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    qd = np.degrees(meas.q)
    for i in range(fm.n_poses):
        rp = fm.residual_pos[i] * 1e3
        v = [str(i + 1), "" if meas.pose_id is None else csv_cell(str(meas.pose_id[i]))]
        v += [f"{x:.6f}" for x in qd[i]]
        v += [f"{x:.6f}" for x in rp] + [f"{np.linalg.norm(rp):.6f}"]
        if fm.residual_rot is not None:
            v += [f"{x:.7f}" for x in np.degrees(fm.residual_rot[i])]
        w.writerow(v)
    return buf.getvalue()
