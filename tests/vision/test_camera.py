import cv2
import numpy as np

from quickhealth.vision.camera import CameraModel
from quickhealth.vision.reference import reference_rig


def test_projection_matches_opencv_and_undistort_inverts_distort():
    cam = CameraModel(
        np.array([[900.0, 0, 650], [0, 905, 360], [0, 0, 1]]),
        [0.05, -0.1, 0.001, -0.002, 0.02],
        (1280, 720),
    )
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(1, 2, 50)])
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    assert np.allclose(cam.project(p), ref.reshape(-1, 2), atol=1e-9)
    px = cam.project(p)
    xn = cam.pixel_to_ray(px)
    assert np.allclose(xn, p[:, :2] / p[:, 2:], atol=1e-12)


def test_reference_rig_geometry():
    rig = reference_rig()
    assert abs(rig.baseline - 0.8) < 1e-12
    assert rig.left.image_size == (4000, 3000) and rig.left.fx == 5000.0
    # the optical axes cross about 2 m ahead: the rig midpoint at 2 m projects near both centres
    from quickhealth.vision.reference import T_left_rig

    p = T_left_rig() @ np.array([0, 0, 2.0, 1])
    for cam, T in ((rig.left, np.eye(4)), (rig.right, rig.T_right_left)):
        q = cam.project((T @ p)[:3])
        assert np.linalg.norm(q - [cam.cx, cam.cy]) < 5
