import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from quickhealth.identify.transforms import inv_T, make_T, rot_x, rot_y
from quickhealth.station.cli import main
from quickhealth.station.formats.vision import rig_to_json
from quickhealth.vision.boards import parse_board_spec, reference_target
from quickhealth.vision.camera import CameraModel, StereoRig
from quickhealth.vision.reference import T_left_rig, reference_rig
from quickhealth.vision.render import Imaging, render_board, render_stereo

CAM = CameraModel(
    np.array([[420.0, 0, 160], [0, 420, 120], [0, 0, 1]]), [-0.05, 0.02, 0, 0, 0], (320, 240)
)
BOARD = "chessboard:6x4:20"


def _board_poses(n: int, rng, *, spread: float = 0.55, z=(0.3, 0.42)):
    """Board poses whose centres spread over ``spread`` of the half-image (board 6×4 inner
    corners, 20 mm squares; origin at its first inner corner)."""
    out = []
    for _ in range(n):
        zz = rng.uniform(*z)
        u = rng.uniform(-spread, spread) * 160 / 420 * zz
        v = rng.uniform(-spread, spread) * 120 / 420 * zz
        R = rot_y(rng.uniform(-0.5, 0.5)) @ rot_x(rng.uniform(-0.5, 0.5))
        out.append(make_T(R, [u, v, zz]) @ make_T(np.eye(3), [-0.05, -0.03, 0.0]))
    return out


def _board_images(
    folder: Path, n: int, seed: int = 0, cam: CameraModel = CAM, poses=None, **kw
) -> list[Path]:
    rng = np.random.default_rng(seed)
    b = parse_board_spec(BOARD)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for k, T in enumerate(poses if poses is not None else _board_poses(n, rng, **kw)):
        p = folder / f"img_{k:02d}.png"
        cv2.imwrite(str(p), render_board(cam, T, b, imaging=Imaging(noise_dn=1.0), rng=rng))
        out.append(p)
    return out


def _one_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("quickhealth")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.slow
def test_calibrate_mono_writes_cal_json_and_plots(tmp_path, capsys):
    _board_images(tmp_path / "img", 24)
    out = tmp_path / "cal.json"
    rc = main(
        [
            "vision",
            "calibrate",
            "--board",
            BOARD,
            "--left",
            str(tmp_path / "img" / "*.png"),
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    d = json.loads(out.read_text())
    assert {"rms_px", "cameras", "views_used", "views_rejected", "verdict", "reasons"} <= set(d)
    K = np.array(d["cameras"][0]["K"])
    assert abs(K[0, 0] - 420) < 3 * d["cameras"][0]["std"]["fx"] and d["cameras"][0][
        "image_size"
    ] == [320, 240]
    assert d["verdict"] == "ok", d["reasons"]
    for name in ("residuals", "coverage", "uncertainty"):
        assert (tmp_path / f"cal_{name}.png").stat().st_size > 1000
    assert "verdict" in capsys.readouterr().out


def test_corrupt_image_is_refused_and_nothing_written(tmp_path, capsys):
    files = _board_images(tmp_path / "img", 4)
    files[2].write_bytes(b"\x89PNG\r\n\x1a\nthis is not an image")
    out = tmp_path / "cal.json"
    rc = main(
        [
            "vision",
            "calibrate",
            "--board",
            BOARD,
            "--left",
            str(tmp_path / "img" / "*.png"),
            "--out",
            str(out),
        ]
    )
    assert rc == 2
    line = _one_line(capsys.readouterr().err)
    assert "img_02.png" in line and "not a readable image" in line
    assert not out.exists() and not list(tmp_path.glob("cal*"))


def test_images_of_different_sizes_are_refused(tmp_path, capsys):
    files = _board_images(tmp_path / "img", 4)
    cv2.imwrite(str(files[1]), np.zeros((100, 120), np.uint8))
    out = tmp_path / "cal.json"
    rc = main(
        [
            "vision",
            "calibrate",
            "--board",
            BOARD,
            "--left",
            str(tmp_path / "img" / "*.png"),
            "--out",
            str(out),
        ]
    )
    assert rc == 2
    line = _one_line(capsys.readouterr().err)
    assert "img_01.png" in line and "120×100" in line and "one image size" in line
    assert not out.exists()


def test_mismatched_left_right_counts_are_refused(tmp_path, capsys):
    _board_images(tmp_path / "L", 4)
    _board_images(tmp_path / "R", 3)
    out = tmp_path / "cal.json"
    rc = main(["vision", "calibrate", "--board", BOARD, "--left", str(tmp_path / "L" / "*.png"),
               "--right", str(tmp_path / "R" / "*.png"), "--out", str(out)])  # fmt: skip
    assert rc == 2
    assert "matches 4 images but --right matches 3" in _one_line(capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--board", "chessboard:9x6"], "expected chessboard:COLSxROWS:SQUARE_MM"),
        (["--board", "charuco:7x5:30:21:DICT_9X9_1"], "unknown ArUco dictionary"),
        (["--board", BOARD, "--left", "/nonexistent/*.png"], "no image file matches"),
    ],
)
def test_bad_board_spec_and_empty_glob(tmp_path, capsys, args, needle):
    base = {"--board": BOARD, "--left": str(tmp_path / "*.png")}
    for k in range(0, len(args), 2):
        base[args[k]] = args[k + 1]
    argv = [
        "vision",
        "calibrate",
        *sum(([k, v] for k, v in base.items()), []),
        "--out",
        str(tmp_path / "c.json"),
    ]
    assert main(argv) == 2
    assert needle in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "c.json").exists()


def _small_rig() -> StereoRig:
    r = reference_rig()
    return StereoRig(r.left.scaled(0.3), r.right.scaled(0.3), r.T_left_right)


def test_measure_run_dir_writes_csv_with_sigmas_and_pan(tmp_path, capsys):
    rig = _small_rig()
    tgt = reference_target()
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    (run / "calibration.json").write_text(json.dumps(rig_to_json(rig)))
    rng = np.random.default_rng(5)
    rows = ["pose_id,q1,q2,q3,q4,q5,q6,pan,time"]
    truth = {}
    for k, z in enumerate((1.5, 1.8, 2.0)):
        T = T_left_rig() @ make_T(rot_y(0.2 * k), [0.05 * k, 0.0, z])
        left, right = render_stereo(rig, T, tgt, rng=rng)
        cv2.imwrite(str(run / "images" / f"p{k}_left.png"), left)
        cv2.imwrite(str(run / "images" / f"p{k}_right.png"), right)
        rows.append(f"p{k},{10 * k},-90,90,0,45,0,{15 * k},{2.0 * k}")
        truth[f"p{k}"] = T
    # a pair where the right camera saw nothing: rejected with its reason
    cv2.imwrite(str(run / "images" / "p3_left.png"), left)
    cv2.imwrite(str(run / "images" / "p3_right.png"), np.full_like(right, 90))
    rows.append("p3,0,-90,90,0,45,0,0,6.0")
    (run / "images" / "index.csv").write_text("\n".join(rows) + "\n")
    rc = main(["vision", "measure", str(run), "--jobs", "2"])
    assert rc == 0, capsys.readouterr().err
    from quickhealth.station.formats import read_measurements

    meas = read_measurements(run / "measurements.csv", n_joints=6)
    assert meas.n_poses == 3 and meas.pose_id == ("p0", "p1", "p2")
    assert np.allclose(meas.pan, np.radians([0, 15, 30]))
    for k, pid in enumerate(meas.pose_id):
        assert np.linalg.norm(meas.pos[k] - truth[pid][:3, 3]) < 0.2e-3
    assert np.all(meas.sigma_pos > 0)
    assert "p3: one-camera" in (run / "measurements.csv").read_text()


def test_measure_refuses_missing_image_and_writes_nothing(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    (run / "images" / "index.csv").write_text("pose_id,q1,q2\np0,1,2\n")
    assert main(["vision", "measure", str(run)]) == 2
    assert "p0_left.png: missing image" in _one_line(capsys.readouterr().err)
    assert not (run / "measurements.csv").exists()


def test_weak_rendered_set_is_unreliable_and_can_fail_the_command(tmp_path, capsys):
    """Acceptance 3 on rendered images: a small board far away, few views."""
    _board_images(tmp_path / "img", 5, seed=3, spread=0.1, z=(0.9, 1.0))
    out = tmp_path / "cal.json"
    argv = [
        "vision",
        "calibrate",
        "--board",
        BOARD,
        "--left",
        str(tmp_path / "img" / "*.png"),
        "--out",
        str(out),
    ]
    assert main([*argv, "--fail-on-unreliable"]) == 1
    d = json.loads(out.read_text())
    assert d["verdict"] == "unreliable" and d["rms_px"] < 0.3
    text = " ".join(d["reasons"])
    assert "covers too little" in text and "usable views" in text and "focal length" in text


@pytest.mark.slow
def test_calibrate_stereo_pair_writes_R_T_baseline(tmp_path, capsys):
    camR = CameraModel(
        np.array([[425.0, 0, 158], [0, 425, 122], [0, 0, 1]]), [-0.04, 0.01, 0, 0, 0], (320, 240)
    )
    # right camera 60 mm to the right, turned in to look at the middle of the working range
    T_right_left = inv_T(make_T(rot_y(-0.165), [0.06, 0.0, 0.0]))
    rng = np.random.default_rng(8)
    poses = _board_poses(16, rng, spread=0.45)
    _board_images(tmp_path / "L", 0, seed=1, poses=poses)
    _board_images(tmp_path / "R", 0, seed=2, cam=camR, poses=[T_right_left @ T for T in poses])
    out = tmp_path / "stereo.json"
    rc = main(["vision", "calibrate", "--board", BOARD, "--left", str(tmp_path / "L" / "*.png"),
               "--right", str(tmp_path / "R" / "*.png"), "--out", str(out)])  # fmt: skip
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["verdict"] == "ok", d["reasons"]
    assert len(d["cameras"]) == 2 and abs(d["baseline_mm"] - 60.0) < 1.0
    assert np.allclose(np.array(d["T"]), 1000 * T_right_left[:3, 3], atol=1.5)
    # rotation about y trades against both principal points (σ(cx) ≈ 0.7 px at fx 425 on
    # these 320×240 images, ≈ 0.002 rad each): allow 3σ
    assert np.allclose(np.array(d["R"]), T_right_left[:3, :3], atol=0.006)
    assert d["stereo_rms_px"] < 2 * d["mono_rms_px"]


@pytest.mark.parametrize(
    ("bad", "needle"),
    [
        (b"garbage", "not a readable image"),
        ("small", "image is 120×90, the calibration's camera 1200×900"),
    ],
)
def test_measure_refuses_a_bad_image_in_a_worker_and_writes_nothing(tmp_path, capsys, bad, needle):
    rig = _small_rig()
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    (run / "calibration.json").write_text(json.dumps(rig_to_json(rig)))
    T = T_left_rig() @ make_T(np.eye(3), [0.0, 0.0, 2.0])
    left, right = render_stereo(rig, T, reference_target(), imaging=Imaging(supersample=1))
    for k in range(3):
        cv2.imwrite(str(run / "images" / f"p{k}_left.png"), left)
        cv2.imwrite(str(run / "images" / f"p{k}_right.png"), right)
    if bad == "small":
        cv2.imwrite(str(run / "images" / "p1_right.png"), np.zeros((90, 120), np.uint8))
    else:
        (run / "images" / "p1_right.png").write_bytes(bad)
    (run / "images" / "index.csv").write_text("pose_id,q1,q2\np0,1,2\np1,1,2\np2,1,2\n")
    assert main(["vision", "measure", str(run), "--jobs", "2"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "p1_right.png" in line and needle in line
    assert not (run / "measurements.csv").exists()


def test_wrong_board_spec_finds_no_views(tmp_path, capsys):
    _board_images(tmp_path / "img", 4)
    out = tmp_path / "cal.json"
    rc = main(
        [
            "vision",
            "calibrate",
            "--board",
            "chessboard:8x5:20",
            "--left",
            str(tmp_path / "img" / "*.png"),
            "--out",
            str(out),
        ]
    )
    assert rc == 2
    line = _one_line(capsys.readouterr().err)
    assert "only 0 images show the board" in line and "board spec" in line
    assert not out.exists()


def test_measure_a_quickhealth_run_folder_from_its_journal(tmp_path, capsys):
    """A folder as `quickhealth run` leaves it (journal.jsonl + images/): rows give the target
    frame at pan 0, so the same tool pose measured at two pan angles gives the same row."""
    from quickhealth.station.formats import read_measurements
    from quickhealth.station.hardware.target import T_target_plate
    from quickhealth.station.run.journal import SCHEMA, Journal

    rig = _small_rig()
    tgt = reference_target()
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    (run / "calibration.json").write_text(json.dumps(rig_to_json(rig)))
    # target frame at pan 0: z out of the plate towards the cameras
    T_target0 = T_left_rig() @ make_T(rot_y(np.pi), [0.02, -0.01, 1.9])
    rng = np.random.default_rng(12)
    with Journal(run).open() as j:
        j.append({"type": "start", "schema": SCHEMA, "run_id": "t"})
        for k, pan_deg in enumerate((-20.0, 25.0), start=1):
            T_plate = T_target0 @ T_target_plate(np.radians(pan_deg))
            left, right = render_stereo(rig, T_plate, tgt, rng=rng)
            names = [f"images/{k:04d}_p{k}_{s}.png" for s in "LR"]
            cv2.imwrite(str(run / names[0]), left)
            cv2.imwrite(str(run / names[1]), right)
            j.append({"type": "captured", "index": k, "name": f"p{k}", "q_deg": [k, -90, 90, 0, 45, 0],
                      "pan_deg": pan_deg, "time_s": 3.0 * k, "images": names})  # fmt: skip
    assert main(["vision", "measure", str(run)]) == 0, capsys.readouterr().err
    meas = read_measurements(run / "measurements.csv", n_joints=6)
    assert meas.pose_id == ("p1", "p2") and np.allclose(np.degrees(meas.pan), [-20, 25])
    for k in range(2):
        assert np.linalg.norm(meas.pos[k] - T_target0[:3, 3]) < 0.1e-3
        assert np.allclose(meas.R[k], T_target0[:3, :3], atol=1e-3)  # fx 1500 px here
