"""The Barrett WAM laser-tracker data set: which sign its offset columns carry.

The files give the tracker's position ``x_t`` and an offset ``dif`` whose sign the data set
does not state; :func:`wam_sign` decides it from the data (``identify import-wam --sign auto``).
"""

from __future__ import annotations

from pathlib import Path

from ...identify.fit import InstrumentNoise, fit_model
from ...identify.robot import RobotModel
from ...identify.select import data_spec
from ..formats.wam import read_wam_csv

#: The arm's repeatability (~1 mm per axis): the instrument noise of the sign test.
WAM_NOISE = InstrumentNoise(sigma_pos=1e-3)


def wam_sign(robot: RobotModel, path: str | Path) -> tuple[float, dict[float, float]]:
    """The sign of the ``dif`` columns: the one whose geometric-model fit has the lower χ²;
    and the χ² of each sign."""
    chi = {}
    for s in (1.0, -1.0):
        m = read_wam_csv(path, s)
        fm = fit_model(robot, m, data_spec(robot, m), noise=WAM_NOISE)
        chi[s] = fm.chi2_data
    return (1.0 if chi[1.0] <= chi[-1.0] else -1.0), chi
