"""One pose's images: the quick detection check in the predicted regions, the full 7D
measurement of a pair, and its journal record."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...vision.boards import TargetDescription
from ...vision.markers import Box, detect_markers
from ...vision.pose7d import PoseMeasurement, Rejection, measure_stereo, roi_from_pose
from ..formats.journal import Measured
from ..hardware.cameras import Image, StereoFrame
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
        det = detect_markers(img, target.dictionary, roi=roi, bits=frame.bits)
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
    station: Station,
    target: TargetDescription,
    left: Image,
    right: Image,
    search: tuple[Box, Box],
    bits: int = 8,
) -> PoseMeasurement | Rejection:
    """Full 7D measurement of one stereo pair (the vision library) at the images' depth
    (``bits``), searched first in the boxes ``search`` (px) that the capture record keeps."""
    return measure_stereo(
        station.camera.rig, target, left, right, roi_hint=search, bits=bits if bits > 8 else None
    )


#: The markers' white as a fraction of full scale: the exposure search aims at ``WHITE_AIM``;
#: a pose whose white is outside ``WHITE_OK`` is flagged (``dark`` / ``saturated``), and so is
#: one with more than ``CLIP_FRACTION`` of the target's pixels at full scale.
WHITE_AIM = 0.80
WHITE_OK = (0.45, 0.95)
CLIP_FRACTION = 0.001


def exposure_report(
    station: Station, frame: StereoFrame, T_pred: F, target: TargetDescription
) -> dict[str, Any]:
    """How well exposed the target is in each image of ``frame``: ``white`` (the 99th
    percentile of the target's region as a fraction of full scale, the brighter image),
    ``clipped`` (fraction of its pixels at full scale) and ``verdict`` (``ok``, ``dark``,
    ``saturated``)."""
    rig = station.camera.rig
    whites, clips = [], []
    for cam, img, T in (
        (rig.left, frame.left, T_pred),
        (rig.right, frame.right, rig.T_right_left @ T_pred),
    ):
        x0, y0, x1, y1 = (int(v) for v in roi_from_pose(cam, T, target, margin=0.0))
        h, w = img.shape
        sub = img[max(y0, 0) : min(y1, h), max(x0, 0) : min(x1, w)]
        if sub.size == 0:
            continue
        whites.append(float(np.percentile(sub, 99.0)) / frame.full_scale)
        clips.append(float(np.mean(sub >= frame.full_scale)))
    if not whites:
        return {"white": None, "clipped": None, "verdict": "not in view"}
    white, clipped = max(whites), max(clips)
    verdict = "ok"
    if clipped > CLIP_FRACTION or white > WHITE_OK[1]:
        verdict = "saturated"
    elif white < WHITE_OK[0]:
        verdict = "dark"
    return {"white": round(white, 4), "clipped": round(clipped, 5), "verdict": verdict}


def camera_record(frame: StereoFrame, exposure: dict[str, Any]) -> dict[str, Any]:
    """The capture record's ``camera`` object: depth, trigger, what each camera reported, the
    exposure check."""
    rec: dict[str, Any] = {"bits": frame.bits, "trigger": frame.trigger}
    for side, info in zip(("left", "right"), frame.info, strict=True):
        got = info.to_json()
        if got:
            rec[side] = got
    edge = frame.meta.get("edge")
    if edge:  # the robot's trigger pulse, as the controller's stream confirmed it
        rec["edge"] = dict(edge)
    problems = frame.meta.get("attempt_problems")
    if problems:
        rec["recaptured"] = list(problems)
    rec["exposure"] = exposure
    return rec


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
