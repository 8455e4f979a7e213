import numpy as np

from quickhealth.identify.transforms import make_T, rot_x, rot_y
from quickhealth.vision.boards import reference_target
from quickhealth.vision.markers import detect_markers, refine_marker_corners
from quickhealth.vision.reference import T_left_rig, reference_rig
from quickhealth.vision.render import Imaging, render_target


def test_far_markers_are_found_and_corner_bias_removed():
    """At the far end of the range (2.5 m, turned 35°) every marker is found, and the edge-line
    refinement removes OpenCV's ≈ 0.2 px inward bias of outer marker corners."""
    cam = reference_rig().left
    tgt = reference_target()
    T = T_left_rig() @ make_T(rot_y(0.6) @ rot_x(0.2), [0.1, 0.05, 2.5])
    img = render_target(
        cam, T, tgt, imaging=Imaging(blur_px=0.9, noise_dn=2.0), rng=np.random.default_rng(0)
    )
    det = detect_markers(img, tgt.dictionary)
    assert sorted(det.ids.tolist()) == list(range(48))
    truth = cam.project(tgt.corners[det.ids] @ T[:3, :3].T + T[:3, 3])

    def inward(c):
        ctr = truth.mean(1, keepdims=True)
        d = (truth - ctr) / np.linalg.norm(truth - ctr, axis=-1, keepdims=True)
        return -np.mean(np.sum((c - truth) * d, -1))

    f = cam.fx
    ref = refine_marker_corners(
        img, det.corners,
        to_ideal=lambda p: cam.pixel_to_ray(p) * f,
        from_ideal=lambda x: cam.project(np.concatenate([x / f, np.ones((*x.shape[:-1], 1))], -1)),
    )  # fmt: skip
    assert inward(det.corners) > 0.1  # OpenCV's sub-pixel refinement
    assert abs(inward(ref)) < 0.03
    assert np.sqrt(np.mean(np.sum((ref - truth) ** 2, -1))) < 0.1


def test_roi_search_returns_full_image_coordinates():
    cam = reference_rig().left
    tgt = reference_target()
    T = T_left_rig() @ make_T(np.eye(3), [0.0, 0.0, 2.0])
    img = render_target(cam, T, tgt, imaging=Imaging(supersample=1))
    truth = cam.project(tgt.corners @ T[:3, :3].T + T[:3, 3])
    lo, hi = truth.reshape(-1, 2).min(0), truth.reshape(-1, 2).max(0)
    det = detect_markers(
        img,
        tgt.dictionary,
        roi=(int(lo[0]) - 40, int(lo[1]) - 40, int(hi[0]) + 40, int(hi[1]) + 40),
    )
    assert det.ids.size == 48 and det.roi is not None
    assert np.abs(det.corners - truth[det.ids]).max() < 0.5
    none = detect_markers(img, tgt.dictionary, roi=(0, 0, 200, 200))
    assert none.ids.size == 0


def test_tiny_markers_are_found_by_upsampling():
    """Markers of ≈ 12 px a side (bit cells ≈ 2 px, the simulated cell's quarter-size images
    at 2.4 m): OpenCV's contour stage misses most of them at 1×; the automatic 2× retry
    finds them, and the corners land where the model projects them."""
    from quickhealth.identify.transforms import rot_z

    cam = reference_rig().right.scaled(0.25)
    tgt = reference_target()
    T = make_T(rot_z(0.6) @ rot_y(0.45), [0.05, 0.0, 2.4])
    img = render_target(cam, T, tgt, rng=np.random.default_rng(2))
    one = detect_markers(img, tgt.dictionary, upscale=1.0)
    auto = detect_markers(img, tgt.dictionary)
    assert auto.ids.size >= 24 and auto.ids.size >= one.ids.size + 8
    truth = cam.project(tgt.corners[auto.ids] @ T[:3, :3].T + T[:3, 3])
    assert np.sqrt(np.mean(np.sum((auto.corners - truth) ** 2, -1))) < 0.4
