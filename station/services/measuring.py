"""Measure a run's stored stereo pairs again: the 7D camera on images already on disk.

:func:`measure_pairs` measures every pair (in worker processes when asked), every pair before
anything is written: an unreadable image stops the work.  :func:`to_run_measurements` turns
the results into the run's measurements: for a run of ``quickhealth run`` the target frame
at pan 0, as the run records it (:mod:`quickhealth.station.hardware.target`).
``vision measure RUN_DIR`` is these two with its files.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.measurements import Measurements
from ...vision.boards import TargetDescription
from ...vision.camera import StereoRig
from ...vision.markers import Box
from ...vision.pose7d import PoseMeasurement, Rejection, measure_stereo, to_measurements
from ..formats.vision import read_gray
from ..hardware.target import target0_from_plate
from ..workers import Pool

F = NDArray[np.float64]
Result = PoseMeasurement | Rejection


@dataclass(frozen=True)
class StoredPair:
    """One pose's stored images, its pan angle (rad) and time (s), when known."""

    pose_id: str
    left: Path
    right: Path
    pan: float | None = None
    time: float | None = None
    search: tuple[Box, Box] | None = None  # px boxes the run searched first (its journal)
    bits: int | None = None  # significant bits of 16-bit images (its journal); None: 8 or 16


# the rig and target of a worker process (set once by its initializer)
_RIG: list[tuple[StereoRig, TargetDescription]] = []


def _init_worker(rig: StereoRig, target: TargetDescription) -> None:
    _RIG[:] = [(rig, target)]


def _measure_one(pair: StoredPair) -> tuple[str, Result]:
    rig, target = _RIG[0]
    imgs = []
    for p, cam in ((pair.left, rig.left), (pair.right, rig.right)):
        img = read_gray(p, depth=True)  # measured at the depth the cameras took it
        w, h = cam.image_size
        if img.shape != (h, w):
            raise InputError(
                f"{p}: image is {img.shape[1]}×{img.shape[0]}, the calibration's camera {w}×{h}"
            )
        imgs.append(img)
    return pair.pose_id, measure_stereo(
        rig, target, imgs[0], imgs[1], bits=pair.bits, roi_hint=pair.search, pan=pair.pan,
        time=pair.time,
    )  # fmt: skip


def measure_pairs(
    rig: StereoRig,
    target: TargetDescription,
    pairs: Sequence[StoredPair],
    *,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Result]:
    """Every pair's 7D measurement (or why it was rejected), by pose id.

    ``workers`` > 1 measures in that many processes; ``progress(done, total)`` after each.

    Raises
    ------
    InputError
        A missing image, or one of another size than the calibration's cameras.
    """
    for pair in pairs:
        for p in (pair.left, pair.right):
            if not p.is_file():
                raise InputError(f"{p}: missing image for pose {pair.pose_id!r}")
    results: dict[str, Result] = {}
    pool = None
    if workers == 1:
        _init_worker(rig, target)
        it: Iterator[tuple[str, Result]] = map(_measure_one, pairs)
    else:
        pool = Pool(workers, initializer=_init_worker, initargs=(rig, target))  # ends with us
        it = pool.map(_measure_one, pairs, chunksize=4)
    try:
        for k, (pid, res) in enumerate(it, start=1):
            results[pid] = res
            if progress is not None:
                progress(k, len(pairs))
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return results


def to_run_measurements(
    pose_ids: Sequence[str],
    q: F,
    results: dict[str, Result],
    *,
    temp: F | None = None,
    at_pan0: bool = False,
    meta: dict[str, str] | None = None,
) -> tuple[Measurements, list[str]]:
    """The measured poses (execution order) and one line per rejected pair.

    ``at_pan0``: record the target frame at pan 0 (a run of ``quickhealth run``); a rotation
    about the origin leaves the measurement's (δt, ω) and their covariance unchanged.

    Raises
    ------
    InputError
        No pair was measured.
    """
    if at_pan0:
        results = {
            pid: replace(r, T_left_target=target0_from_plate(r.T_left_target, r.pan))
            if isinstance(r, PoseMeasurement) and r.pan is not None
            else r
            for pid, r in results.items()
        }
    keep = [k for k, pid in enumerate(pose_ids) if isinstance(results[pid], PoseMeasurement)]
    rejected = []
    for pid in pose_ids:
        r = results[pid]
        if isinstance(r, Rejection):
            rejected.append(f"{pid}: {r.reason.value} ({r.detail})")
    if not keep:
        first = rejected[0] if rejected else "-"
        raise InputError(f"no pose measured in {len(pose_ids)} pairs (first: {first})")
    meta = dict(meta or {})
    if rejected:
        meta["rejected"] = "; ".join(rejected)
    meas = to_measurements(
        q[keep],
        [results[pose_ids[k]] for k in keep],  # type: ignore[misc]
        temp=None if temp is None else temp[keep],
        pose_id=[pose_ids[k] for k in keep],
        meta=meta,
    )
    return meas, rejected
