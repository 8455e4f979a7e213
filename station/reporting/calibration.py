"""Before and after calibration: the TCP error at measured poses with the robot's nominal
kinematics and with the identified model (SI in, SI out).

"Before" is what the robot does when programmed with its nominal kinematics: the measured
target against the nominal robot with the registered base and tool
(:attr:`~quickhealth.identify.fit.FittedModel.registration`, the best rigid fit, so the
set-up is not counted as robot error).  "After" is what is left with the identified model:
measured minus the model's prediction.  On the fitted poses "after" is the fit's residual;
on held-out poses (data the fit never saw) it is the honest figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.fit import FittedModel
from ...identify.measurements import Measurements

F = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class BeforeAfter:
    """The TCP position error (m) at one set of measured poses, nominal and model."""

    label: str  # which poses: "the fitted poses", "held-out poses (FILE)"
    before: F  # (n,) |measured − nominal|
    after: F  # (n,) |measured − model|

    @property
    def n(self) -> int:
        """Number of poses."""
        return int(len(self.before))

    def rms(self, which: str) -> float:
        """RMS of ``"before"`` or ``"after"`` (m)."""
        v = getattr(self, which)
        return float(np.sqrt(np.mean(v**2)))

    def as_dict(self) -> dict[str, object]:
        """report.json's figures (mm)."""
        return {
            "poses": self.label,
            "n": self.n,
            "nominal_rms_mm": self.rms("before") * 1e3,
            "nominal_max_mm": float(self.before.max()) * 1e3,
            "model_rms_mm": self.rms("after") * 1e3,
            "model_max_mm": float(self.after.max()) * 1e3,
        }


def before_after(fitted: FittedModel, meas: Measurements, label: str) -> BeforeAfter:
    """The nominal and model TCP position error at ``meas``'s poses (the model's own effects
    at the rows' time and temperature, approach directions from the row order)."""
    nominal = fitted.nominal_pose(meas.q)[:, :3, 3]
    model = fitted.predict(meas.q, **meas.conditions())[:, :3, 3]
    return BeforeAfter(
        label,
        np.linalg.norm(meas.pos - nominal, axis=1),
        np.linalg.norm(meas.pos - model, axis=1),
    )


def heldout_file(run_dir: Path, source: str | None) -> Path | None:
    """Held-out measurements beside a run: ``RUN/heldout.csv``, else ``<input>.heldout.csv``
    next to the file the model was fitted to (``quickhealth twin --heldout`` writes it)."""
    cands = [run_dir / "heldout.csv"]
    if source:
        p = Path(source)
        cands.append(p.with_name(f"{p.stem}.heldout.csv"))
    return next((p for p in cands if p.is_file()), None)
