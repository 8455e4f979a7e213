"""Calibration boards and smart-target descriptions (pure: specs and dicts in, geometry out).

Frames: a board or target frame has x to the right, y down and z into the plate, so a camera
facing the printed side sees it with ``T_cam_target ≈ [I | (0, 0, d)]``.  Lengths in metres.

The printed appearance of boards and targets is described by :class:`Layer` objects (grids of
black/white cells on the plate) so the renderer can draw them exactly and anti-aliased.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.errors import InputError

F = NDArray[np.float64]
I64 = NDArray[np.int64]


class BoardKind(Enum):
    """Kind of calibration board."""

    CHESSBOARD = "chessboard"
    CHARUCO = "charuco"


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary by name (e.g. ``DICT_4X4_50``); InputError if unknown."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        raise InputError(
            f"unknown ArUco dictionary {name!r} (expected an OpenCV name such as DICT_4X4_50)"
        )
    return cv2.aruco.getPredefinedDictionary(code)


@dataclass(frozen=True, eq=False)
class Layer:
    """A grid of cells printed on the plate: cell (row j, col i) covers the parallelogram
    ``origin + (i..i+1)·axis_u + (j..j+1)·axis_v``; ``cells`` holds reflectance 0 (black) … 1.

    Outside its grid a layer is transparent (white, reflectance 1).
    """

    origin: F  # (2,) m, in the plate (target x, y)
    axis_u: F  # (2,) m per cell
    axis_v: F  # (2,) m per cell
    cells: F  # (nv, nu)


@dataclass(frozen=True, eq=False)
class BoardSpec:
    """A calibration board as given by ``--board SPEC`` (CONTRACTS.md).

    ``cols``, ``rows``: inner corners for a chessboard, squares for a ChArUco board.
    """

    kind: BoardKind
    cols: int
    rows: int
    square: float  # m
    marker: float = 0.0  # m, ChArUco only
    dictionary: str = ""

    @property
    def n_corners(self) -> int:
        """Number of corners the board offers."""
        if self.kind is BoardKind.CHESSBOARD:
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    @property
    def corner_grid(self) -> tuple[int, int]:
        """(columns, rows) of the inner-corner grid."""
        if self.kind is BoardKind.CHESSBOARD:
            return (self.cols, self.rows)
        return (self.cols - 1, self.rows - 1)

    def object_points(self) -> F:
        """Corner positions in the board frame, shape (n_corners, 3), indexed by corner id.

        Chessboard: id = row·cols + col, corner (0, 0) at the origin.  ChArUco: OpenCV's ids
        (row·(squares_x−1)+col), positions as OpenCV's board gives them.
        """
        if self.kind is BoardKind.CHARUCO:
            return np.asarray(self.cv_board().getChessboardCorners(), dtype=float).reshape(-1, 3)
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([c.ravel() * self.square, r.ravel() * self.square, np.zeros(c.size)], -1)

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board (OpenCV ≥ 4.6 layout)."""
        if self.kind is not BoardKind.CHARUCO:
            raise ValueError("only ChArUco boards have an OpenCV board object")
        return cv2.aruco.CharucoBoard(
            (self.cols, self.rows), self.square, self.marker, aruco_dictionary(self.dictionary)
        )

    def plate(self) -> tuple[F, F]:
        """(top-left, bottom-right) corners of the white plate, m, with a one-square margin."""
        if self.kind is BoardKind.CHESSBOARD:
            lo = np.array([-2.0, -2.0]) * self.square
            hi = np.array([self.cols + 1.0, self.rows + 1.0]) * self.square
        else:
            lo = np.array([-1.0, -1.0]) * self.square
            hi = np.array([self.cols + 1.0, self.rows + 1.0]) * self.square
        return lo, hi

    def layers(self) -> list[Layer]:
        """The printed pattern as layers for the renderer."""
        s = self.square
        if self.kind is BoardKind.CHESSBOARD:
            j, i = np.mgrid[0 : self.rows + 1, 0 : self.cols + 1]
            cells = ((i + j) % 2).astype(float)  # square (0, 0), top-left of corner 0, is black
            return [Layer(np.array([-s, -s]), np.array([s, 0.0]), np.array([0.0, s]), cells)]
        board = self.cv_board()
        obj = np.asarray(board.getObjPoints(), dtype=float)[:, :, :2]
        ids = np.asarray(board.getIds()).ravel()
        centres = obj.mean(axis=1)
        cells = np.zeros((self.rows, self.cols))
        ci = np.floor(centres / s).astype(int)
        cells[ci[:, 1], ci[:, 0]] = 1.0  # marker squares are white
        out = [Layer(np.zeros(2), np.array([s, 0.0]), np.array([0.0, s]), cells)]
        out += _marker_layers(aruco_dictionary(self.dictionary), ids, obj)
        return out


def _marker_layers(dictionary: cv2.aruco.Dictionary, ids: I64, corners: F) -> list[Layer]:
    """One layer per marker; ``corners`` (n, 4, 2) in OpenCV order (TL, TR, BR, BL)."""
    nb = int(dictionary.markerSize) + 2
    out = []
    for mid, c in zip(ids, corners, strict=True):
        img = dictionary.generateImageMarker(int(mid), nb, borderBits=1)
        out.append(
            Layer(c[0].copy(), (c[1] - c[0]) / nb, (c[3] - c[0]) / nb, img.astype(float) / 255.0)
        )
    return out


_CHESS = re.compile(r"^chessboard:(\d+)x(\d+):([0-9.]+)$", re.I)
_CHARUCO = re.compile(r"^charuco:(\d+)x(\d+):([0-9.]+):([0-9.]+):(DICT_\w+)$", re.I)


def parse_board_spec(spec: str) -> BoardSpec:
    """Parse ``chessboard:COLSxROWS:SQUARE_MM`` or ``charuco:SXxSY:SQUARE_MM:MARKER_MM:DICT``."""
    m = _CHESS.match(spec.strip())
    if m:
        cols, rows, sq = int(m[1]), int(m[2]), float(m[3])
        if cols < 2 or rows < 2 or sq <= 0:
            raise InputError(
                f"--board {spec!r}: need at least 2×2 inner corners and a positive square size"
            )
        return BoardSpec(BoardKind.CHESSBOARD, cols, rows, sq / 1000.0)
    m = _CHARUCO.match(spec.strip())
    if m:
        sx, sy, sq, mk, name = int(m[1]), int(m[2]), float(m[3]), float(m[4]), m[5].upper()
        if sx < 3 or sy < 3 or not 0 < mk < sq:
            raise InputError(f"--board {spec!r}: need ≥3×3 squares and 0 < MARKER_MM < SQUARE_MM")
        aruco_dictionary(name)
        return BoardSpec(BoardKind.CHARUCO, sx, sy, sq / 1000.0, mk / 1000.0, name)
    raise InputError(
        f"--board {spec!r}: expected chessboard:COLSxROWS:SQUARE_MM (inner corners) or "
        "charuco:SQUARESXxSQUARESY:SQUARE_MM:MARKER_MM:DICT, e.g. charuco:7x5:30:21:DICT_4X4_50"
    )


@dataclass(frozen=True, eq=False)
class TargetDescription:
    """A smart target: ArUco markers on a plate that turns on a pan motor.

    Attributes
    ----------
    name : str
    dictionary : str
        OpenCV dictionary name.
    ids : ndarray, shape (n,), int
        Marker ids.
    corners : ndarray, shape (n, 4, 3), m
        Each marker's corners in the target frame, OpenCV order (top-left, top-right,
        bottom-right, bottom-left as printed).  The renderer needs z = 0 (planar plate).
    plate : ndarray, shape (2, 2), m
        Plate outline (top-left, bottom-right) in target x, y.
    pan_axis : ndarray, shape (3,)
        Unit pan-motor axis in the target frame (through the target origin).
    """

    name: str
    dictionary: str
    ids: I64
    corners: F
    plate: F
    pan_axis: F

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=np.int64).ravel()
        corners = np.asarray(self.corners, dtype=float)
        if corners.shape != (ids.size, 4, 3):
            raise InputError(f"target {self.name!r}: need 4 corners (x, y, z) per marker id")
        if np.unique(ids).size != ids.size:
            raise InputError(f"target {self.name!r}: duplicate marker ids")
        d = aruco_dictionary(self.dictionary)
        if ids.size and (ids.min() < 0 or ids.max() >= d.bytesList.shape[0]):
            raise InputError(f"target {self.name!r}: marker ids outside {self.dictionary}")
        ax = np.asarray(self.pan_axis, dtype=float)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "corners", corners)
        object.__setattr__(self, "plate", np.asarray(self.plate, dtype=float).reshape(2, 2))
        object.__setattr__(self, "pan_axis", ax / np.linalg.norm(ax))

    @property
    def n_corners(self) -> int:
        """Number of marker corners the target offers."""
        return int(self.ids.size * 4)

    @property
    def marker_side(self) -> float:
        """Smallest marker side length, m."""
        return float(np.linalg.norm(self.corners[:, 1] - self.corners[:, 0], axis=-1).min())

    def layers(self) -> list[Layer]:
        """The printed markers as layers for the renderer (planar targets only)."""
        if np.any(np.abs(self.corners[..., 2]) > 1e-9):
            raise ValueError("the renderer draws planar targets (all corners at z = 0) only")
        return _marker_layers(aruco_dictionary(self.dictionary), self.ids, self.corners[..., :2])

    def to_dict(self) -> dict[str, Any]:
        """The target description file's content (mm), see docs/vision.md."""
        return {
            "format": "quickhealth-target",
            "version": 1,
            "name": self.name,
            "units": "mm",
            "dictionary": self.dictionary,
            "plate_mm": (self.plate * 1000).round(6).tolist(),
            "pan_axis": self.pan_axis.round(12).tolist(),
            "markers": [
                {"id": int(i), "corners_mm": (c * 1000).round(6).tolist()}
                for i, c in zip(self.ids, self.corners, strict=True)
            ],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "target") -> TargetDescription:
        """Build from a target description file's content (``markers`` list and/or ``grid``)."""
        try:
            if d.get("format") != "quickhealth-target" or int(d.get("version", 0)) != 1:
                raise InputError(f"{where}: not a quickhealth-target version 1 file (key 'format')")
            if d.get("units", "mm") != "mm":
                raise InputError(f"{where}: units must be 'mm'")
            ids: list[int] = []
            corners: list[Any] = []
            for k, m in enumerate(d.get("markers", [])):
                c = np.asarray(m["corners_mm"], dtype=float)
                if c.shape != (4, 3) or not np.all(np.isfinite(c)):
                    raise InputError(f"{where}: markers[{k}].corners_mm must be 4 finite [x, y, z]")
                ids.append(int(m["id"]))
                corners.append(c / 1000.0)
            if "grid" in d:
                g = d["grid"]
                gi, gc = grid_markers(
                    int(g["cols"]), int(g["rows"]), float(g["marker_mm"]) / 1000,
                    float(g["pitch_mm"]) / 1000, int(g.get("first_id", 0)),
                )  # fmt: skip
                ids += gi.tolist()
                corners += list(gc)
            if not ids:
                raise InputError(f"{where}: no markers (give 'markers' or 'grid')")
            cor = np.asarray(corners)
            if "plate_mm" in d:
                plate = np.asarray(d["plate_mm"], dtype=float) / 1000.0
            else:
                margin = 0.5 * float(np.linalg.norm(cor[0, 1] - cor[0, 0]))
                plate = np.array([cor[..., :2].reshape(-1, 2).min(0) - margin,
                                  cor[..., :2].reshape(-1, 2).max(0) + margin])  # fmt: skip
            return cls(
                name=str(d.get("name", "target")),
                dictionary=str(d["dictionary"]),
                ids=np.asarray(ids),
                corners=cor,
                plate=plate,
                pan_axis=np.asarray(d.get("pan_axis", [0.0, 1.0, 0.0]), dtype=float),
            )
        except InputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                f"{where}: bad target description ({type(exc).__name__}: {exc})"
            ) from None


def grid_markers(cols: int, rows: int, side: float, pitch: float, first_id: int) -> tuple[I64, F]:
    """Markers on a regular grid centred on the target origin, ids row by row."""
    j, i = np.mgrid[0:rows, 0:cols]
    cx = (i.ravel() - (cols - 1) / 2.0) * pitch
    cy = (j.ravel() - (rows - 1) / 2.0) * pitch
    h = side / 2.0
    off = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    c2 = np.stack([cx, cy], -1)[:, None, :] + off[None]
    c3 = np.concatenate([c2, np.zeros((*c2.shape[:2], 1))], -1)
    return np.arange(cols * rows, dtype=np.int64) + first_id, c3


def reference_target() -> TargetDescription:
    """The reference smart target: 8×6 DICT_4X4_50 markers, 24 mm on a 32 mm pitch (192 corners).

    At 2.5 m through the reference camera (fx ≈ 5000 px) a marker spans ≈ 48 px and one
    marker cell ≈ 8 px: well above the detector's limits as tuned in :mod:`markers`.
    """
    ids, corners = grid_markers(8, 6, 0.024, 0.032, 0)
    plate = np.array([[-0.136, -0.104], [0.136, 0.104]])
    return TargetDescription(
        "reference-8x6-4x4", "DICT_4X4_50", ids, corners, plate, np.array([0.0, 1.0, 0.0])
    )


def pan_transform(target: TargetDescription, pan: float) -> F:
    """``T_mount_target`` for a pan angle (rad): rotation about the target's pan axis."""
    from quickhealth.identify.transforms import exp_so3, make_T

    return make_T(exp_so3(target.pan_axis * pan), np.zeros(3))
