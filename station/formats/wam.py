"""The Barrett WAM laser-tracker data set (``quickhealth import-wam``)."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from ...identify.errors import InputError
from ...identify.measurements import Measurements
from .common import MAX_FIT_ROWS, read_text_limited


def read_wam_csv(path: str | os.PathLike[str], sign: float) -> Measurements:
    """The Barrett WAM laser-tracker files (step_order, x_t…, x_dif…, joint_1…7) as Measurements.

    Position = desired + ``sign`` · difference (mm → m); joints deg → rad.
    """
    p = Path(path)
    rows = list(csv.reader(read_text_limited(p, "measurements").splitlines()))
    if not rows or not any(rows[0]):
        raise InputError(f"{p}:1:1: empty file: expected the WAM header (x_t, y_t, z_t, ...)")
    if len(rows) > MAX_FIT_ROWS + 1:
        raise InputError(f"{p}: {len(rows) - 1} rows is over the {MAX_FIT_ROWS} row limit of a fit")
    head = [c.strip() for c in rows[0]]
    need = ["x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 8)]
    for c in need:
        if c not in head:
            raise InputError(f"{p}:1:{len(head) + 1}: missing WAM column {c!r}")
    ix = {c: head.index(c) for c in need}
    data = []
    for lineno, r in enumerate(rows[1:], start=2):
        if not r:
            continue
        try:
            vals = [float(r[ix[c]]) for c in need]
        except (ValueError, IndexError):
            raise InputError(f"{p}:{lineno}:1: row is not numeric") from None
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"{p}:{lineno}:1: NaN or infinity in the row")
        data.append(vals)
    if not data:
        raise InputError(f"{p}: no data rows after the header")
    a = np.array(data)
    pos = (a[:, 0:3] + sign * a[:, 3:6]) * 1e-3
    q = np.radians(a[:, 6:13])
    return Measurements(
        q=q, pos=pos, meta={"source": p.name, "instrument": "GTS3800 laser tracker"}
    )
