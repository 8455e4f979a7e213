import cv2
import numpy as np
import pytest

from quickhealth.identify.transforms import make_T, rot_x, rot_y
from quickhealth.vision.boards import Layer, parse_board_spec
from quickhealth.vision.camera import CameraModel
from quickhealth.vision.render import Imaging, render_board, render_layers


@pytest.mark.parametrize("ss", [1, 3])
def test_edges_land_where_the_model_projects_them_to_0_01_px(ss):
    # a black rectangle, frontal, pinhole: each row's darkness integral is the rectangle's
    # width in pixels and its first moment the rectangle's centre, exactly, if the
    # anti-aliasing is right
    cam = CameraModel(
        np.array([[800.0, 0, 200.3], [0, 800.0, 150.7], [0, 0, 1]]), np.zeros(5), (400, 300)
    )
    sq = Layer(
        np.array([-0.0123, -0.011]),
        np.array([0.02371, 0.0]),
        np.array([0.0, 0.0217]),
        np.zeros((1, 1)),
    )
    T = make_T(np.eye(3), [0.0, 0.0, 1.0])
    sharp = Imaging(
        blur_px=0.0, noise_dn=0.0, white_dn=255.0, dark_dn=0.0, background=1.0, supersample=ss
    )
    img = render_layers(cam, T, [sq], np.array([[-0.05, -0.04], [0.05, 0.04]]), sharp, None).astype(
        float
    )
    dark = 1.0 - img / 255.0
    x = np.arange(400.0)
    rows = slice(150 - 5, 150 + 5)
    width = dark[rows].sum(1)
    centre = (dark[rows] * x).sum(1) / width
    x0, x1 = cam.project(np.array([[-0.0123, 0, 1.0], [-0.0123 + 0.02371, 0, 1.0]]))[:, 0]
    assert np.all(
        np.abs(width - (x1 - x0)) < 0.01 * 2 + 2 / 255 * 2
    )  # 8-bit quantisation of two edge pixels
    assert np.all(np.abs(centre - (x0 + x1) / 2) < 0.01)


def test_rendered_chessboard_corners_match_projection_with_distortion():
    cam = CameraModel(
        np.array([[700.0, 0, 322], [0, 702, 238], [0, 0, 1]]),
        [-0.2, 0.08, 0.001, -0.0005, 0.0],
        (640, 480),
    )
    board = parse_board_spec("chessboard:7x5:25")
    T = make_T(rot_y(0.35) @ rot_x(-0.25), [-0.07, -0.05, 0.45])
    img = render_board(cam, T, board, imaging=Imaging(blur_px=1.0, noise_dn=0.0))
    truth = cam.project(board.object_points() @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    start = (truth + 0.4).reshape(-1, 1, 2)
    r = cv2.cornerSubPix(
        img, start, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    )
    err = np.linalg.norm(r.reshape(-1, 2) - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.05
    assert abs(np.mean(r.reshape(-1, 2) - truth)) < 0.01


def test_noise_lighting_and_reproducibility():
    cam = CameraModel(
        np.array([[500.0, 0, 160], [0, 500, 120], [0, 0, 1]]), np.zeros(5), (320, 240)
    )
    board = parse_board_spec("chessboard:5x4:20")
    T = make_T(np.eye(3), [-0.04, -0.03, 0.6])
    a = render_board(cam, T, board, rng=np.random.default_rng(3))
    b = render_board(cam, T, board, rng=np.random.default_rng(3))
    assert np.array_equal(a, b) and a.dtype == np.uint8
    dim = render_board(cam, T, board, imaging=Imaging(gain=0.5, noise_dn=0.0))
    grad = render_board(cam, T, board, imaging=Imaging(gradient=(0.6, 0.0), noise_dn=0.0))
    assert dim.mean() < 0.7 * a.mean()
    assert grad[:, -20:].mean() > grad[:, :20].mean()
