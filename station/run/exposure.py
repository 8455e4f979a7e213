"""The exposure for the target: a short search at the first pose, fixed for the run.

Industrial cameras run at a fixed exposure (no auto exposure: it would change the images'
geometry from pose to pose through the blur of a moving target and the noise).  When the
cell asks for it (``exposure_us = "auto"`` in its ``[cameras]`` section), the first pose's
pair is taken at the cameras' exposure, the target's white is read in its predicted region
(:func:`~.capture.exposure_report`), and the exposure is scaled towards
:data:`~.capture.WHITE_AIM` of full scale, backing off when any target pixel clips, at most
:data:`STEPS` times.  The exposure found is the run's (recorded in the first capture's
``camera.exposure_search``); every pose's white is checked against it (``camera.exposure``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..station import Station
from .capture import CLIP_FRACTION, WHITE_AIM, exposure_report

F = NDArray[np.float64]
STEPS = 6
TOLERANCE = 0.06  # |white - aim| accepted
EXPOSURE_US = (20.0, 1_000_000.0)  # the range searched, µs


def wants_search(station: Station) -> bool:
    """The cameras can set their exposure and the cell left it to the search."""
    return bool(getattr(station.camera, "auto_exposure", False))


def recorded_exposure(station: Station, captured: dict[int, Any]) -> dict[str, Any] | None:
    """A resumed run keeps the exposure its first pose found: set on the cameras again and
    returned (None: the run recorded no search)."""
    for rec in captured.values():
        found = (rec.camera or {}).get("exposure_search")
        if found:
            station.camera.set_exposure(float(found["exposure_us"]))
            return dict(found)
    return None


def search_exposure(station: Station, T_pred: F) -> dict[str, Any]:
    """Search the exposure at this pose (``T_pred``: the target's predicted plate pose) and
    set it; returns the record (``{}`` when the cell fixes the exposure)."""
    if not wants_search(station):
        return {}
    cam = station.camera
    exposure = float(getattr(cam, "exposure_us", None) or 10_000.0)
    cam.set_exposure(exposure)
    steps: list[dict[str, float]] = []
    for _ in range(STEPS):
        frame = cam.capture()
        rep = exposure_report(station, frame, T_pred, station.target)
        white, clipped = rep["white"], rep["clipped"]
        steps.append({"exposure_us": round(exposure, 1), "white": white, "clipped": clipped})
        if white is None:
            break
        if clipped <= CLIP_FRACTION and abs(white - WHITE_AIM) <= TOLERANCE:
            break
        factor = 0.5 if clipped > CLIP_FRACTION else WHITE_AIM / max(white, 0.02)
        exposure = round(float(np.clip(exposure * factor, *EXPOSURE_US)), 1)
        cam.set_exposure(exposure)
    else:  # no step was good enough: keep the best one seen
        good = [st for st in steps if st["white"] is not None and st["clipped"] <= CLIP_FRACTION]
        best = min(good or steps, key=lambda st: abs((st["white"] or 0.0) - WHITE_AIM))
        cam.set_exposure(best["exposure_us"])
        steps.append(dict(best))
    final = steps[-1]
    return {"exposure_us": final["exposure_us"], "white": final["white"], "steps": steps}
