"""Files of the 7D camera: images, calibration JSON (CAL.json), target description files.

Lengths in files are mm; inside, m.  Every bad input raises :class:`InputError` with one line
naming the file.  Formats: docs/vision.md.
"""

from __future__ import annotations

import csv
import glob as _glob
import io
import json
import os
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ... import vision as vision_package
from ...identify.errors import InputError
from ...vision.boards import TargetDescription, reference_target
from ...vision.calibrate import CalibrationResult
from ...vision.camera import CameraModel, StereoRig
from ..fsio import write_atomic
from .common import MAX_LINE_CHARS, read_text_limited

U8 = NDArray[np.uint8]
F = NDArray[np.float64]


def expand_glob(pattern: str, what: str) -> list[Path]:
    """Sorted files matching ``pattern``; InputError when none do."""
    files = sorted(Path(p) for p in _glob.glob(os.path.expanduser(pattern)) if Path(p).is_file())
    if not files:
        hint = (
            " (did the shell expand it? quote the glob)" if any(c in pattern for c in "*?[") else ""
        )
        raise InputError(f"{what} {pattern!r}: no image file matches{hint}")
    return files


MAX_IMAGE_PIXELS = 50_000_000  # 50 Mpx: twice the largest machine-vision sensor we expect
MAX_IMAGE_BYTES = 200 << 20


def _header_pixels(path: Path) -> int | None:
    """Width x height from the file's header without decoding it (None: format unknown)."""
    try:
        from PIL import Image  # Pillow reads a header without decoding; optional

        Image.MAX_IMAGE_PIXELS = None  # we judge the size ourselves, below
        with Image.open(path) as im:
            w, h = im.size
        return int(w) * int(h)
    except Exception:  # noqa: BLE001 - an unknown or broken header: OpenCV decides below
        return None


def read_gray(path: Path, *, depth: bool = False) -> U8:
    """One image as 8-bit grey (``depth``: at its depth, uint16 for a 16-bit PNG or TIFF, as
    a run stores a 10- to 16-bit camera's images); InputError for unreadable, corrupt or
    oversized files.

    Limits (docs/vision.md): a regular file of at most 200 MiB whose header claims at most
    ``MAX_IMAGE_PIXELS`` pixels; the header is read before anything is decoded.
    """
    try:
        st = path.stat()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a device or a pipe); refusing to read it")
    if st.st_size > MAX_IMAGE_BYTES:
        raise InputError(f"{path}: {st.st_size >> 20} MiB is over the 200 MiB limit of an image")
    n_px = _header_pixels(path)
    if n_px is not None and n_px > MAX_IMAGE_PIXELS:
        raise InputError(
            f"{path}: the image header claims {n_px / 1e6:.0f} Mpx, over the limit of "
            f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpx"
        )
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        flags = cv2.IMREAD_GRAYSCALE | (cv2.IMREAD_ANYDEPTH if depth else 0)
        img = cv2.imdecode(data, flags) if data.size else None
    except cv2.error as exc:
        msg = " ".join(str(exc).split())[-160:]
        raise InputError(f"{path}: OpenCV cannot decode this image: {msg}") from None
    if img is None:
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)")
    if img.size > MAX_IMAGE_PIXELS:
        raise InputError(f"{path}: {img.size / 1e6:.0f} Mpx is over the limit")
    return img


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file."""
    img = read_gray(path)
    return (int(img.shape[1]), int(img.shape[0]))


def read_image_set(paths: Sequence[Path]) -> list[U8]:
    """All images of one camera; InputError if any is unreadable or their sizes differ."""
    imgs = [read_gray(p) for p in paths]
    s0 = imgs[0].shape
    for p, im in zip(paths, imgs, strict=True):
        if im.shape != s0:
            raise InputError(
                f"{p}: image is {im.shape[1]}×{im.shape[0]} but {paths[0].name} is {s0[1]}×{s0[0]}: "
                "one calibration set needs one image size"
            )
    return imgs


def write_png(path: Path, img: U8) -> None:
    """Write an 8-bit image (PNG) atomically."""
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise InputError(f"{path}: could not encode the image")
    _write_bytes(path, buf.tobytes())


def _write_bytes(path: Path, data: bytes) -> None:
    write_atomic(path, data)


def write_json(path: Path, doc: dict[str, Any]) -> None:
    """Write a JSON document atomically."""
    _write_bytes(path, (json.dumps(doc, indent=1) + "\n").encode())


def _load_json(path: Path) -> dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}:{exc.colno}: not valid JSON ({exc.msg})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object")
    return doc


def calibration_to_json(result: CalibrationResult) -> dict[str, Any]:
    """CAL.json content of a calibration (CONTRACTS.md)."""
    return result.to_dict()


def rig_to_json(rig: StereoRig, note: str = "") -> dict[str, Any]:
    """A stereo rig as a CAL.json document (for the reference design and the simulator)."""
    T_right_left = rig.T_right_left
    return {
        "format": "quickhealth-calibration",
        "version": 1,
        "note": note,
        "rms_px": 0.0,
        "cameras": [
            {"K": c.K.tolist(), "dist": c.dist.tolist(), "image_size": list(c.image_size)}
            for c in rig.cameras
        ],
        "R": T_right_left[:3, :3].tolist(),
        "T": (1000 * T_right_left[:3, 3]).tolist(),
        "baseline_mm": 1000 * rig.baseline,
        "views_used": [],
        "views_rejected": [],
        "verdict": "ok",
        "reasons": [],
    }


def read_rig(path: Path) -> StereoRig:
    """The stereo rig of a stereo CAL.json (R, T: left → right, T in mm)."""
    doc = _load_json(path)
    try:
        cams = [
            CameraModel(
                np.asarray(c["K"], float), np.asarray(c["dist"], float), tuple(c["image_size"])
            )
            for c in doc["cameras"]
        ]
        if len(cams) != 2 or "R" not in doc or "T" not in doc:
            raise InputError(f"{path}: not a stereo calibration (needs two cameras, 'R' and 'T')")
        T = np.eye(4)
        T[:3, :3] = np.asarray(doc["R"], float)
        T[:3, 3] = np.asarray(doc["T"], float).ravel() / 1000.0
    except InputError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: bad calibration file ({type(exc).__name__}: {exc})") from None
    if doc.get("verdict") == "unreliable":
        raise InputError(
            f"{path}: calibration verdict is 'unreliable' ({'; '.join(doc.get('reasons', []))}): recalibrate"
        )
    _check_rig(path, cams, T)
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return StereoRig(cams[0], cams[1], Ti)


def _check_rig(path: Path, cams: list[CameraModel], T_right_left: np.ndarray) -> None:
    """Refuse (one line, exit 2) a calibration whose numbers mean no camera: a camera matrix
    that is not ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with positive focal lengths (a
    singular K), a principal point far outside the image, distortion that is not finite or
    absurd, an image size outside 1 px … 50 Mpx, R not a rotation, a baseline of 0 or > 100 m."""
    for name, c in zip(("left", "right"), cams, strict=True):
        K, where = c.K, f"{path}: {name} camera"
        w, h = c.image_size
        if not (0 < w and 0 < h and w * h <= 50_000_000):
            raise InputError(f"{where}: image size {w}×{h} px is not a camera's")
        if not np.all(np.isfinite(K)) or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise InputError(f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], finite")
        if not (0 < K[0, 0] < 1e6 and 0 < K[1, 1] < 1e6):
            raise InputError(
                f"{where}: focal lengths fx = {K[0, 0]:g}, fy = {K[1, 1]:g} px must be positive "
                "(K is singular or mirrored)"
            )
        if not (-w <= K[0, 2] <= 2 * w and -h <= K[1, 2] <= 2 * h):
            raise InputError(
                f"{where}: principal point ({K[0, 2]:g}, {K[1, 2]:g}) px lies far outside the "
                f"{w}×{h} image"
            )
        if not np.all(np.isfinite(c.dist)) or np.abs(c.dist).max() > 1e3:
            raise InputError(f"{where}: distortion {c.dist.tolist()} is not finite or absurd")
    R, t = T_right_left[:3, :3], T_right_left[:3, 3]
    if not (np.all(np.isfinite(R)) and np.allclose(R @ R.T, np.eye(3), atol=1e-6)):
        raise InputError(f"{path}: R is not a rotation matrix")
    if np.linalg.det(R) < 0:
        raise InputError(f"{path}: R is a reflection (determinant -1), not a rotation")
    b = float(np.linalg.norm(t)) if np.all(np.isfinite(t)) else float("nan")
    if not 1e-3 <= b <= 100.0:
        raise InputError(f"{path}: T gives a baseline of {b * 1e3:g} mm; expected 1 mm … 100 m")


def read_target(path: Path | None) -> TargetDescription:
    """A target description file, or the reference target when ``path`` is None."""
    if path is None:
        return reference_target()
    return TargetDescription.from_dict(_load_json(path), where=str(path))


def data_path(name: str) -> Path:
    """A file shipped in quickhealth/vision/data."""
    return Path(vision_package.__file__).parent / "data" / name


def read_image_index(path: Path) -> tuple[list[str], F, F, F, F]:
    """A run folder's image index (``images/index.csv``: ``pose_id``, ``q1`` … ``qN`` in deg,
    optional ``pan`` deg, ``time`` s, ``temp`` °C): pose ids, joints (rad), pan (rad), time,
    temperature (NaN where a column is missing), in file order."""
    if not path.is_file():
        raise InputError(
            f"{path}: missing (the run folder's image index: pose_id, q1..qN in deg, pan, time)"
        )
    text = read_text_limited(path, "measurements")  # regular file, size, UTF-8
    for ln, line in enumerate(text.splitlines(), start=1):
        if len(line) > MAX_LINE_CHARS:
            raise InputError(
                f"{path}:{ln}:1: line of {len(line)} characters is too long (at most "
                f"{MAX_LINE_CHARS})"
            )
    try:
        rows = [r for r in csv.reader(io.StringIO(text, newline="")) if r and r[0][:1] != "#"]
    except csv.Error as exc:
        raise InputError(f"{path}: not a CSV file: {exc}") from None
    if len(rows) < 2:
        raise InputError(f"{path}: no rows")
    head = [h.strip() for h in rows[0]]
    qcols = [c for c in head if c.startswith("q") and c[1:].isdigit()]
    if "pose_id" not in head or not qcols:
        raise InputError(f"{path}:1: header needs pose_id and q1..qN")
    qcols.sort(key=lambda c: int(c[1:]))
    ids, q, pan, time, temp = [], [], [], [], []
    for ln, r in enumerate(rows[1:], start=2):
        if len(r) != len(head):
            raise InputError(f"{path}:{ln}: {len(r)} cells, header has {len(head)}")
        d = dict(zip(head, (c.strip() for c in r), strict=True))
        try:
            q.append([float(d[c]) for c in qcols])
            pan.append(float(d["pan"]) if "pan" in d else np.nan)
            time.append(float(d["time"]) if "time" in d else np.nan)
            temp.append(float(d["temp"]) if "temp" in d else np.nan)
        except ValueError:
            bad = next(c for c in head if c != "pose_id" and not _isnum(d[c]))
            raise InputError(
                f"{path}:{ln}:{head.index(bad) + 1}: {bad} is not a number ({d[bad]!r})"
            ) from None
        bad_q = [c for c, v in zip(qcols, q[-1], strict=True) if not np.isfinite(v)]
        if bad_q:
            raise InputError(
                f"{path}:{ln}:{head.index(bad_q[0]) + 1}: {bad_q[0]} is {d[bad_q[0]]!r}, not a "
                "finite joint angle"
            )
        ids.append(check_pose_id(d["pose_id"], f"{path}:{ln}:{head.index('pose_id') + 1}"))
    return ids, np.radians(np.array(q)), np.radians(np.array(pan)), np.array(time), np.array(temp)


def check_pose_id(pid: str, where: str) -> str:
    """A pose id usable in CSV v1 and as an image file name: no control characters, no path."""
    if (
        not pid
        or len(pid) > 128
        or any(c < " " or c in "/\\\x7f" for c in pid)
        or pid in (".", "..")
    ):
        raise InputError(
            f"{where}: pose_id {pid[:40]!r} must be 1-128 characters without control "
            "characters or path separators"
        )
    return pid


def _isnum(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False
