"""One pose's images: the quick detection check in the predicted regions, the full 7D
measurement of a pair, and its journal record."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...vision.boards import TargetDescription
from ...vision.markers import Box, detect_markers
from ...vision.pose7d import PoseMeasurement, Rejection, measure_stereo, roi_from_pose
from ..formats.journal import Measured
from ..hardware.cameras import StereoFrame
from ..hardware.target import target0_from_plate
from ..station import Station

F = NDArray[np.float64]
U8 = NDArray[np.uint8]


def quick_check(
    station: Station, frame: StereoFrame, T_pred: F, target: TargetDescription, min_markers: int
) -> tuple[bool, str, tuple[int, int]]:
    """Markers of ``target`` found in each image's predicted region: (ok, reason, counts)."""
    rig = station.camera.rig
    counts = []
    ids = set(int(i) for i in target.ids)
    for cam, img, T in (
        (rig.left, frame.left, T_pred),
        (rig.right, frame.right, rig.T_right_left @ T_pred),
    ):
        roi = roi_from_pose(cam, T, target, margin=0.5)
        det = detect_markers(img, target.dictionary, roi=roi)
        counts.append(sum(1 for i in det.ids if int(i) in ids))
    c = (counts[0], counts[1])
    if min(c) >= min_markers:
        return True, "", c
    return (
        False,
        f"target not detected ({c[0]} markers in the left image, {c[1]} in the right, "
        f"need {min_markers})",
        c,
    )


def measure_frame(
    station: Station, target: TargetDescription, left: U8, right: U8, search: tuple[Box, Box]
) -> PoseMeasurement | Rejection:
    """Full 7D measurement of one stereo pair (the vision library), searched first in the
    boxes ``search`` (px) that the capture record keeps."""
    return measure_stereo(station.camera.rig, target, left, right, roi_hint=search)


def measured_record(index: int, name: str, meas: PoseMeasurement, pan: float) -> Measured:
    """The journal record of a measured pose: the target frame at pan 0 with uncertainties."""
    T0 = target0_from_plate(meas.T_left_target, pan)
    m0 = PoseMeasurement(T0, meas.cov, meas.rms_px, meas.n_corners, meas.n_outliers)
    return Measured(
        index,
        name,
        True,
        position=m0.position,
        rpy=m0.rpy,
        sigma_pos=m0.sigma_pos,
        sigma_rpy=m0.sigma_rpy,
        rms_px=meas.rms_px,
        n_corners=tuple(meas.n_corners),
        n_outliers=meas.n_outliers,
    )
