"""The run journal's records (schema ``quickhealth.journal/1``): typed in SI, stored in mm and deg.

Each line of ``RUN_DIR/journal.jsonl`` is one record (``type``: a :class:`RecordKind`).  The
run writes typed records and every reader gets them back typed, through the one encoder
(:func:`encode`) and the one decoder (:func:`decode`) here; the durable storage (checksums,
``fsync``, the torn last line) is :mod:`quickhealth.station.run.journal`.

- ``start``, ``resume``, ``stop``, ``end``: plain objects (ids, times, reasons; no units);
- ``selfcheck`` (:class:`SelfCheck`): the instrument self-check on the reference board;
- ``captured`` (:class:`Captured`): a pose reached and imaged;
- ``measured`` (:class:`Measured`): the 7D measurement of a captured pose;
- ``failed`` (:class:`Failed`): a pose that could not be captured.

In the file: joints ``q_deg``, ``q_cmd_deg``, pan ``pan_deg``, the measured target frame at
pan 0 ``x_mm``, ``rpy_deg`` with ``sigma_mm``, ``sigma_deg``, the board ``T_instr_board_mm``
(a 4×4 with its translation in mm) — as the journals of earlier versions hold them; and
``search_px``, the two pixel boxes the capture was first searched in (absent in older
journals), so that its images measured again give the same detection.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

F = NDArray[np.float64]
Box = tuple[int, int, int, int]  # x0, y0, x1, y1 (px), as vision.markers.Box


class RecordKind(StrEnum):
    """What a journal line records (its ``type``)."""

    START = "start"
    SELFCHECK = "selfcheck"
    CAPTURED = "captured"
    MEASURED = "measured"
    FAILED = "failed"
    STOP = "stop"
    RESUME = "resume"
    END = "end"


@dataclass(frozen=True, eq=False)
class SelfCheck:
    """The reference board measured at a phase of the run (``start``, ``resume``, ``end``).

    ``T_instr_board`` (4, 4), m, and ``sigma_pos`` (3,), m, when ``ok``; ``reason`` when not.
    ``time_s``: s since the run's epoch (None when not measured).
    """

    phase: str
    ok: bool
    reason: str = ""
    T_instr_board: F | None = None
    sigma_pos: F | None = None
    rms_px: float | None = None
    time_s: float | None = None


@dataclass(frozen=True, eq=False)
class Captured:
    """A pose reached and imaged: the settled joint reading ``q`` and the command ``q_cmd``
    (rad), the pan angle (rad), the capture time (s since the run's epoch), the two image files
    (relative to the run folder), the captures it took and the markers seen (left, right).

    ``timing`` (s, absent in older journals): where the robot's time at the pose went,
    ``move`` (the leg, wall clock), ``settle`` (until the joint stream showed rest), ``pan``
    (the motor's remaining turn), ``capture`` (every capture and its detection check), and
    ``start`` (when the move began, s since the run's epoch).

    ``camera`` (absent in older journals): what the cameras reported about the pair: ``bits``
    (8 to 16: the stored images' depth), ``trigger``, ``left`` / ``right`` (``frame_id``,
    ``timestamp_ns``, ``exposure_us``, ``gain_db``, ``temperature_c`` where the camera says),
    ``exposure`` (the markers' white level as a fraction of full scale and ``ok``,
    ``saturated`` or ``dark``).

    ``joint_temp`` (°C) and ``joint_torque`` (N·m), one per joint (absent in older journals
    and where the controller reports none): what the controller said about each joint at the
    pose, its temperature and the torque its drive exerted (CSV v1 ``temp_jK``, ``tau_jK``)."""

    index: int
    name: str
    q: F
    pan: float
    time_s: float
    images: tuple[str, ...]
    q_cmd: F | None = None
    attempts: int = 1
    markers: tuple[int, ...] = ()
    search: tuple[Box, Box] | None = None
    timing: dict[str, float] | None = None
    camera: dict[str, Any] | None = None
    joint_temp: F | None = None
    joint_torque: F | None = None


@dataclass(frozen=True, eq=False)
class Measured:
    """The 7D measurement of a captured pose: the target frame at pan 0 (``position`` m,
    ``rpy`` rad) with its standard uncertainties, or why the vision library rejected it.

    ``timing`` (s, absent in older journals): ``start`` and ``end`` of the worker's work on
    the pair (s since the run's epoch: it overlaps the arm's move to the next pose),
    ``images`` (writing them) and ``measure`` (the 7D measurement)."""

    index: int
    name: str
    ok: bool
    reason: str = ""
    position: F | None = None
    rpy: F | None = None
    sigma_pos: F | None = None
    sigma_rpy: F | None = None
    rms_px: float | None = None
    n_corners: tuple[int, ...] = ()
    n_outliers: int = 0
    timing: dict[str, float] | None = None


@dataclass(frozen=True, eq=False)
class Failed:
    """A pose that could not be captured (joints ``q`` and ``pan`` rad, at ``time_s``)."""

    index: int
    name: str
    reason: str
    q: F | None = None
    pan: float | None = None
    time_s: float | None = None


Record = SelfCheck | Captured | Measured | Failed | dict[str, Any]


def _mm(v: F | None) -> list[float] | None:
    return None if v is None else (np.asarray(v, float) * 1e3).tolist()


def _deg(v: F | None) -> list[float] | None:
    return None if v is None else np.degrees(np.asarray(v, float)).tolist()


def _T_mm(T: F) -> list[list[float]]:
    M = np.array(T, dtype=float)
    M[:3, 3] *= 1e3
    return M.tolist()


def encode(rec: Record) -> dict[str, Any]:
    """The JSON object of a record (file units; ``type`` first)."""
    if isinstance(rec, Mapping):
        return dict(rec)
    if isinstance(rec, SelfCheck):
        out: dict[str, Any] = {"type": RecordKind.SELFCHECK.value, "phase": rec.phase, "ok": rec.ok}
        if not rec.ok:
            return {**out, "reason": rec.reason}
        assert rec.T_instr_board is not None
        return {
            **out,
            "T_instr_board_mm": _T_mm(rec.T_instr_board),
            "sigma_mm": _mm(rec.sigma_pos),
            "rms_px": rec.rms_px,
            "time_s": rec.time_s,
        }
    if isinstance(rec, Captured):
        return {
            "type": RecordKind.CAPTURED.value,
            "index": rec.index,
            "name": rec.name,
            "q_deg": _deg(rec.q),
            "q_cmd_deg": _deg(rec.q_cmd),
            "pan_deg": float(np.degrees(rec.pan)),
            "time_s": rec.time_s,
            "images": list(rec.images),
            "attempts": rec.attempts,
            "markers": list(rec.markers),
            **({} if rec.search is None else {"search_px": [list(b) for b in rec.search]}),
            **({} if rec.timing is None else {"timing_s": dict(rec.timing)}),
            **({} if rec.camera is None else {"camera": dict(rec.camera)}),
            **({} if rec.joint_temp is None else {"joint_temp_c": _plain(rec.joint_temp)}),
            **({} if rec.joint_torque is None else {"joint_torque_nm": _plain(rec.joint_torque)}),
        }
    if isinstance(rec, Measured):
        out = {
            "type": RecordKind.MEASURED.value,
            "index": rec.index,
            "name": rec.name,
            "ok": rec.ok,
        }
        if rec.timing is not None:
            out["timing_s"] = dict(rec.timing)
        if not rec.ok:
            return {**out, "reason": rec.reason}
        return {
            **out,
            "x_mm": _mm(rec.position),
            "rpy_deg": _deg(rec.rpy),
            "sigma_mm": _mm(rec.sigma_pos),
            "sigma_deg": _deg(rec.sigma_rpy),
            "rms_px": rec.rms_px,
            "n_corners": list(rec.n_corners),
            "n_outliers": rec.n_outliers,
        }
    assert isinstance(rec, Failed)
    return {
        "type": RecordKind.FAILED.value,
        "index": rec.index,
        "name": rec.name,
        "q_deg": _deg(rec.q),
        "pan_deg": None if rec.pan is None else float(np.degrees(rec.pan)),
        "reason": rec.reason,
        "time_s": rec.time_s,
    }


def _plain(v: F) -> list[float]:
    return np.asarray(v, float).tolist()


def _joint_values(v: object, what: str) -> F | None:
    """A capture's per-joint values (finite numbers), or None when not recorded."""
    if v is None:
        return None
    a = np.asarray(v, dtype=float)
    if a.ndim != 1 or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be one finite number per joint")
    return a


def _m(v: object) -> F | None:
    return None if v is None else np.asarray(v, dtype=float) / 1e3


def _rad(v: object) -> F | None:
    return None if v is None else np.radians(np.asarray(v, dtype=float))


def _boxes(v: object) -> tuple[Box, Box] | None:
    """Two search boxes ``[[x0, y0, x1, y1], [...]]`` (px), or None when not recorded."""
    if v is None:
        return None
    a = np.asarray(v, dtype=np.int64)
    if a.shape != (2, 4):
        raise ValueError(f"search_px must be two boxes of 4 pixel bounds, got shape {a.shape}")
    l, r = (tuple(int(x) for x in b) for b in a)
    return l, r  # type: ignore[return-value]


def _timing(v: object) -> dict[str, float] | None:
    """A capture's ``timing_s`` object (s per part), or None when not recorded."""
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise ValueError("timing_s must be an object of seconds")
    out = {str(k): float(x) for k, x in v.items()}
    if not all(np.isfinite(x) and x >= 0 for x in out.values()):
        raise ValueError("timing_s: every part must be a finite, non-negative number of seconds")
    return out


def _camera(v: object) -> dict[str, Any] | None:
    """A capture's ``camera`` object, or None when not recorded."""
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise ValueError("camera must be an object")
    bits = v.get("bits", 8)
    if not isinstance(bits, int) or not 8 <= bits <= 16:
        raise ValueError(f"camera.bits must be an integer in 8..16, got {bits!r}")
    return dict(v)


def decode(obj: Mapping[str, Any]) -> Record:
    """The typed record of a journal line's JSON object (SI); ``start``, ``resume``, ``stop``
    and ``end`` stay objects.

    Raises
    ------
    KeyError, TypeError, ValueError
        A record without a field its kind needs (the reader names the line).
    """
    kind = RecordKind(obj["type"])
    if kind is RecordKind.SELFCHECK:
        ok = bool(obj["ok"])
        if not ok:
            return SelfCheck(str(obj["phase"]), False, str(obj.get("reason", "")))
        T = np.array(obj["T_instr_board_mm"], dtype=float)
        T[:3, 3] /= 1e3
        return SelfCheck(
            str(obj["phase"]),
            True,
            T_instr_board=T,
            sigma_pos=_m(obj.get("sigma_mm")),
            rms_px=obj.get("rms_px"),
            time_s=obj.get("time_s"),
        )
    if kind is RecordKind.CAPTURED:
        return Captured(
            index=int(obj["index"]),
            name=str(obj["name"]),
            q=_rad(obj["q_deg"]),
            pan=float(np.radians(obj["pan_deg"])),
            time_s=float(obj["time_s"]),
            images=tuple(str(p) for p in obj["images"]),
            q_cmd=_rad(obj.get("q_cmd_deg")),
            attempts=int(obj.get("attempts", 1)),
            markers=tuple(int(m) for m in obj.get("markers", ())),
            search=_boxes(obj.get("search_px")),
            timing=_timing(obj.get("timing_s")),
            camera=_camera(obj.get("camera")),
            joint_temp=_joint_values(obj.get("joint_temp_c"), "joint_temp_c"),
            joint_torque=_joint_values(obj.get("joint_torque_nm"), "joint_torque_nm"),
        )
    if kind is RecordKind.MEASURED:
        if not obj["ok"]:
            return Measured(
                int(obj["index"]),
                str(obj["name"]),
                False,
                str(obj.get("reason", "")),
                timing=_timing(obj.get("timing_s")),
            )
        return Measured(
            index=int(obj["index"]),
            name=str(obj["name"]),
            ok=True,
            position=_m(obj["x_mm"]),
            rpy=_rad(obj["rpy_deg"]),
            sigma_pos=_m(obj["sigma_mm"]),
            sigma_rpy=_rad(obj["sigma_deg"]),
            rms_px=obj.get("rms_px"),
            n_corners=tuple(int(c) for c in obj.get("n_corners", ())),
            n_outliers=int(obj.get("n_outliers", 0)),
            timing=_timing(obj.get("timing_s")),
        )
    if kind is RecordKind.FAILED:
        pan = obj.get("pan_deg")
        return Failed(
            index=int(obj["index"]),
            name=str(obj["name"]),
            reason=str(obj.get("reason", "")),
            q=_rad(obj.get("q_deg")),
            pan=None if pan is None else float(np.radians(pan)),
            time_s=obj.get("time_s"),
        )
    return dict(obj)
