"""Cameras: the OpenCV capture path (fed from image sequences, as a camera would deliver
frames) and the simulated pair (board and target composed, background when empty)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from quickhealth.identify.errors import HardwareError
from quickhealth.identify.transforms import make_T
from quickhealth.station.hardware.cameras import OpenCvStereoCamera
from quickhealth.station.hardware.target import reference_board, reference_target
from quickhealth.station.sim.cameras import SimStereoCamera, scaled_rig
from quickhealth.vision.reference import reference_rig


@pytest.fixture(scope="module")
def rig():
    return scaled_rig(reference_rig(), 0.1)  # 400×300 px


def _sequence(folder, stem, size, n=3):
    w, h = size
    for i in range(n):
        img = np.full((h, w, 3), 40 + 50 * i, np.uint8)
        cv2.imwrite(str(folder / f"{stem}_{i:02d}.png"), img)
    return str(folder / f"{stem}_%02d.png")


def test_opencv_pair_delivers_grey_frames_with_timestamps(rig, tmp_path):
    left = _sequence(tmp_path, "l", rig.left.image_size)
    right = _sequence(tmp_path, "r", rig.right.image_size)
    cam = OpenCvStereoCamera(left, right, rig, max_skew_s=0.5)
    try:
        f1, f2 = cam.capture(), cam.capture()
    finally:
        cam.close()
    assert f1.left.ndim == 2 and f1.left.shape == (300, 400) and f1.right.shape == (300, 400)
    assert f2.time >= f1.time and f1.skew < 0.5
    assert int(f2.left.mean()) == 90  # the second frame, converted to grey


def test_opencv_pair_refuses_a_size_the_calibration_does_not_know(rig, tmp_path):
    left = _sequence(tmp_path, "l", (320, 240))
    right = _sequence(tmp_path, "r", (320, 240))
    cam = OpenCvStereoCamera(left, right, rig, max_skew_s=0.5)
    try:
        with pytest.raises(HardwareError, match="recalibrate"):
            cam.capture()
    finally:
        cam.close()


def test_missing_camera_is_a_clear_error(rig, tmp_path):
    with pytest.raises(HardwareError, match="does not open"):
        OpenCvStereoCamera(str(tmp_path / "none_%02d.png"), 0, rig)


def test_simulated_pair_composes_target_and_static_board(tmp_path):
    from quickhealth.vision.pose7d import PoseMeasurement, measure_stereo

    rig = scaled_rig(reference_rig(), 0.25)
    tgt, board = reference_target(), reference_board()
    T_t = make_T(np.eye(3), [0.25, 0.0, 2.0])
    T_b = make_T(np.eye(3), [-0.45, 0.0, 2.0])
    scene = {"objs": [(T_t, tgt)]}
    cam = SimStereoCamera(rig, lambda: scene["objs"], static=[(T_b, board)], seed=1)
    f = cam.capture()
    m_t = measure_stereo(rig, tgt, f.left, f.right, roi_hint=T_t)
    m_b = measure_stereo(rig, board, f.left, f.right, roi_hint=T_b)
    assert isinstance(m_t, PoseMeasurement) and isinstance(m_b, PoseMeasurement)
    assert np.linalg.norm(m_t.position - T_t[:3, 3]) < 5e-4
    assert np.linalg.norm(m_b.position - T_b[:3, 3]) < 5e-4
    scene["objs"] = []  # the target out of view: the board alone, on a noisy background
    g = cam.capture()
    assert isinstance(measure_stereo(rig, board, g.left, g.right, roi_hint=T_b), PoseMeasurement)
    assert not isinstance(measure_stereo(rig, tgt, g.left, g.right), PoseMeasurement)
    assert g.left.std() > 1.0  # never a blank frame
