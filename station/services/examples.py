"""The tutorial's example data, made here: what the README's steps read besides what earlier
steps wrote (``quickhealth examples``).

- :func:`calibration_views`: a ChArUco board seen by the simulated cell's stereo camera from
  places chosen to cover both images (``vision calibrate`` then calls the set "ok");
- :func:`tracker_export`: a laser tracker's export of a simulated UR10 in the layout of the
  ``ipa-ur10`` preset (``import tracker``).

Both are drawn from the digital twin and the renderer the simulated cell uses, so
``vision measure RUN --calibration cal.json`` measures a ``run --sim`` folder with a
calibration made from these images.  Pure: arrays and text out; the command writes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.robot import builtin_robot
from ...identify.transforms import make_T, rot_x, rot_y, rot_z
from ...identify.twin import SIGMA_POS, SIGMA_ROT, make_twin, random_joints
from ...vision.boards import BoardSpec, parse_board_spec
from ...vision.camera import StereoRig
from ...vision.render import Imaging, render_stereo
from ..formats.tracker import PRESETS

F = NDArray[np.float64]

#: The tutorial's board: 10 × 7 squares of 60 mm, 45 mm markers (a 600 × 420 mm plate, large
#: enough to fill a camera 2 m from the robot).
BOARD = "charuco:10x7:60:45:DICT_4X4_50"
#: Image cells (10 × 6) the views must cover in each camera, as ``vision calibrate`` counts them.
COVER = 0.6


@dataclass(frozen=True)
class StereoViews:
    """Rendered board views: left and right images (uint8) and the coverage of each camera."""

    left: tuple[NDArray[np.uint8], ...]
    right: tuple[NDArray[np.uint8], ...]
    coverage: tuple[float, float]  # fraction of the 10 × 6 image cells holding a corner


def calibration_views(
    rig: StereoRig, n_views: int = 8, board: str = BOARD, seed: int = 0
) -> StereoViews:
    """``n_views`` stereo pairs of ``board`` inside both cameras' view, 1.3 to 2.4 m away,
    tilted up to 40°: chosen greedily among random poses for the image cells they add, so
    the corners reach the images' edges (a calibration's coverage check)."""
    spec = parse_board_spec(board)
    poses, cover = _board_poses(rig, spec, n_views, np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    im = Imaging(blur_px=0.8, noise_dn=1.0, supersample=1)  # blurred: sub-pixel corners
    pairs = [render_stereo(rig, T, spec, imaging=im, rng=rng) for T in poses]
    return StereoViews(tuple(p[0] for p in pairs), tuple(p[1] for p in pairs), cover)


def _board_poses(
    rig: StereoRig, board: BoardSpec, n: int, rng: np.random.Generator, tries: int = 1500
) -> tuple[list[F], tuple[float, float]]:
    lo, hi = board.plate()
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    obj = board.object_points()
    aim = _axes_crossing(rig)  # the middle of the region both cameras see
    cands: list[tuple[F, set[tuple[int, int, int]]]] = []
    for _ in range(tries):
        z = rng.uniform(0.65, 1.25) * aim[2]
        x = aim[0] * z / aim[2] + rng.uniform(-0.25, 0.25) * z
        y = rng.uniform(-0.22, 0.22) * z
        R = (
            rot_z(rng.uniform(-0.5, 0.5))
            @ rot_y(rng.uniform(-0.7, 0.7))
            @ rot_x(rng.uniform(-0.7, 0.7))
        )
        T = make_T(R, np.array([x, y, z]) - R @ centre)
        cells = _cells(rig, T, obj)
        if cells:
            cands.append((T, cells))
    chosen: list[F] = []
    got: set[tuple[int, int, int]] = set()
    for _ in range(min(n, len(cands))):
        best = max(range(len(cands)), key=lambda i: len(cands[i][1] - got))
        T, cells = cands.pop(best)
        chosen.append(T)
        got |= cells
    cover = tuple(sum(c[0] == k for c in got) / 60.0 for k in (0, 1))
    return chosen, (cover[0], cover[1])


def _axes_crossing(rig: StereoRig) -> F:
    """The point (left camera frame) nearest both optical axes."""
    T = rig.T_left_right
    p1, d1 = np.zeros(3), np.array([0.0, 0.0, 1.0])
    p2, d2 = T[:3, 3], T[:3, 2]
    A = np.array([[d1 @ d1, -d1 @ d2], [d1 @ d2, -d2 @ d2]])
    b = np.array([(p2 - p1) @ d1, (p2 - p1) @ d2])
    s, t = np.linalg.solve(A, b)
    return (p1 + s * d1 + p2 + t * d2) / 2


def _cells(rig: StereoRig, T: F, obj: F) -> set[tuple[int, int, int]]:
    """The 10 × 6 image cells the board's corners fall in, in both cameras (empty when the
    board leaves either image or turns away from a camera)."""
    out: set[tuple[int, int, int]] = set()
    for k, (cam, TT) in enumerate(((rig.left, T), (rig.right, rig.T_right_left @ T))):
        p = obj @ TT[:3, :3].T + TT[:3, 3]
        centre = p.mean(axis=0)
        if p[:, 2].min() < 0.3 or abs(TT[:3, 2] @ centre / np.linalg.norm(centre)) < 0.5:
            return set()
        px = cam.project(p)
        w, h = cam.image_size
        if np.any(px < [0.03 * w, 0.03 * h]) or np.any(px > [0.97 * w, 0.97 * h]):
            return set()
        out |= {(k, int(u * 10 // w), int(v * 6 // h)) for u, v in px}
    return out


def tracker_export(n_poses: int = 60, seed: int = 7) -> str:
    """A laser tracker export of a simulated UR10 (2 m from the tracker, 6-DoF probe) in the
    ``ipa-ur10`` preset's layout: ``;``-separated, decimal commas, joints in rad, positions
    in mm, XYZ Euler angles in degrees, per-row standard uncertainties, temperature."""
    from scipy.spatial.transform import Rotation  # the Euler angles the preset reads

    robot = builtin_robot("ur10")
    twin = make_twin(robot, seed=seed)
    q = random_joints(robot, n_poses, seed=seed + 1, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=seed + 2)
    lay = PRESETS["ipa-ur10"]
    assert lay.orientation is not None and lay.sigma_position and lay.sigma_orientation
    head = ["Timestamp", *lay.joints, str(lay.temp)]
    for a, s in zip(
        (*lay.position, *lay.orientation),
        (*lay.sigma_position, *lay.sigma_orientation),
        strict=True,
    ):
        head += [a, s]
    euler = Rotation.from_matrix(meas.R).as_euler("XYZ", degrees=True)
    sig_pos, sig_rot = SIGMA_POS * 1e3, np.degrees(SIGMA_ROT)
    rows = [";".join(head)]
    for i in range(meas.n_poses):
        vals = [f"{20251101080000 + 7 * i}", *(f"{v:.6f}" for v in meas.q[i]), "21.80"]
        for v in meas.pos[i] * 1e3:
            vals += [f"{v:.5f}", f"{sig_pos:.4f}"]
        for v in euler[i]:
            vals += [f"{v:.6f}", f"{sig_rot:.5f}"]
        rows.append(";".join(x.replace(".", ",") for x in vals))
    return "\n".join(rows) + "\n"
