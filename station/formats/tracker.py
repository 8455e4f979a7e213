"""Laser-tracker exports of any column layout to :class:`Measurements` (``quickhealth import tracker``).

A tracker export is a delimited text file with one header row (or none) and one row per
measured pose: the robot's joint readings beside the tracker's reading of the target, as a
3-DoF position (a reflector) or a 6-DoF pose (a probe such as the Leica T-Mac).  Its layout
is described by a :class:`TrackerLayout`: which file column is q1 … qN, x, y, z, the three
orientation angles, their uncertainties, temperature, time and pose id; the separator, the
decimal mark, the units and the Euler convention.  :data:`PRESETS` holds the layouts of
known files (``ipa-ur10``, ``wam``).

Orientation: the three angles are turned into rotation matrices ``R_instr_target`` with
``scipy.spatial.transform.Rotation.from_euler(seq, angles)``; ``seq`` is named exactly as
scipy names it (``XYZ`` intrinsic, ``xyz`` extrinsic, any of the 12 sequences), and the
file's angles are given in that sequence's order.  The written file carries the quaternion
form of CSV v1 (``qw, qx, qy, qz``), which has no singularity.

Orientation uncertainty: per-angle standard uncertainties ``σ = (σ1, σ2, σ3)`` are mapped
to the rotation vector through the forward Euler-rate map ``ω = E(θ) · dθ``:
``Σω = E diag(σ²) Eᵀ`` (:func:`euler_rate_matrix`), never through its inverse, which is
singular at gimbal lock.  CSV v1 has one angle, ``srot``: we take ``srot = sqrt(trace(Σω)/3)``,
the isotropic uncertainty with the same total variance.  Every column of ``E`` is a unit
vector, so this equals the RMS of the three per-angle uncertainties at every orientation
(angles assumed independent); it is finite at gimbal lock, where a per-angle spread that the
instrument computed near its own singularity comes out large, which errs on the safe side.

Every bad input raises :class:`InputError` with one line ``file:line:column: what`` (line and
column 1-based, column = the file's column) when it is in the file, or naming the option
(``--length-unit``) when it is in the layout.  Nothing here writes a file.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.measurements import Measurements
from .common import MAX_CELL_CHARS, MAX_ROWS, one_line, read_text_limited
from .measurements import check_joint_values

F = NDArray[np.float64]

#: metres per file length unit
LENGTH_UNITS = {"mm": 1e-3, "m": 1.0, "in": 0.0254}
#: radians per file angle unit
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
SEPARATORS = {"auto": None, ",": ",", ";": ";", "tab": "\t", "\t": "\t"}
DECIMALS = ("point", "comma")
#: the farthest a laser tracker measures (m); a farther target means a wrong length unit
MAX_RANGE_M = 200.0
#: a temperature outside this range (°C) is another unit (K, °F) or a broken cell
TEMP_RANGE_C = (-50.0, 100.0)

# unit words a header may carry, as "x [mm]" or "rx (deg)": quantity and canonical name
_UNIT_WORDS = {
    "mm": ("length", "mm"),
    "m": ("length", "m"),
    "in": ("length", "in"),
    "inch": ("length", "in"),
    '"': ("length", "in"),
    "deg": ("angle", "deg"),
    "degree": ("angle", "deg"),
    "degrees": ("angle", "deg"),
    "°": ("angle", "deg"),
    "rad": ("angle", "rad"),
    "radian": ("angle", "rad"),
    "radians": ("angle", "rad"),
    "°c": ("temperature", "C"),
    "degc": ("temperature", "C"),
    "c": ("temperature", "C"),
    "℃": ("temperature", "C"),
    "s": ("time", "s"),
    "sec": ("time", "s"),
}
# unit words recognised as units but not supported: refused rather than misread
_UNSUPPORTED_UNITS = {
    "cm": "length",
    "µm": "length",
    "um": "length",
    "km": "length",
    "ft": "length",
    "mrad": "angle",
    "µrad": "angle",
    "urad": "angle",
    "grad": "angle",
    "gon": "angle",
    "arcsec": "angle",
    "arcmin": "angle",
    "k": "temperature",
    "°f": "temperature",
    "f": "temperature",
    "ms": "time",
    "min": "time",
    "h": "time",
}
_UNIT_SUFFIX = re.compile(r"^(.*?)\s*[\[(]\s*([^\[\]()]{1,8}?)\s*[\])]\s*$")
_DECIMAL_COMMA_NUMBER = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")


@dataclass(frozen=True)
class TrackerLayout:
    """How a tracker export's columns map to a measurement (a preset or the user's options).

    A column is named by its header text (with or without a unit suffix such as ``[mm]``)
    or by its 1-based number (``"3"``; the only way with ``header=False``).

    Attributes
    ----------
    joints : tuple of str
        Columns of q1 … qN (N = the robot's joints), in the robot's joint order.
    position : tuple of 3 str
        Columns of x, y, z (the target point, instrument frame).
    deviation : tuple of 3 str, or None
        Columns added to ``position`` times ``deviation_sign`` (files that give a nominal
        position and its deviation, such as the WAM set's ``x_t`` and ``x_dif``).
    deviation_sign : float
        +1 or −1.
    orientation : tuple of 3 str, or None
        The three Euler angles, in the order of ``euler``'s axes.  None = position only.
    euler : str or None
        The Euler convention exactly as ``scipy.spatial.transform.Rotation.from_euler``
        names it: three axes, upper-case intrinsic (``XYZ``), lower-case extrinsic (``xyz``).
    sigma_position, sigma_orientation : tuple of 3 str, or None
        Per-row standard uncertainties of x, y, z (length unit) and of the three angles
        (angle unit; they become CSV v1 ``srot``, see the module docstring).
    temp, time, pose_id : str or None
        Temperature (°C), time (s), pose identifier columns.
    joint_temps, joint_torques : tuple of str, or None
        Each joint's temperature (°C) and measured torque (N·m) as the robot's controller
        reported them, in the robot's joint order (CSV v1 ``temp_j1`` …, ``tau_j1`` …).  A
        file whose header has columns named ``temp_j1`` … ``temp_jN`` or ``tau_j1`` …
        ``tau_jN`` gets them mapped without being told.
    separator : str
        ``auto`` (tab, ``;`` or ``,``, whichever the header has most of), ``,``, ``;``, ``tab``.
    decimal : str
        ``point`` (``0.5``) or ``comma`` (``0,5``).
    length_unit, joint_unit, angle_unit : str or None
        ``mm``, ``m``, ``in``; ``deg``, ``rad`` (joints and orientation apart).  None = the
        unit the header names (``x [m]``), else mm and deg.
    header : bool
        The first (non-comment) row names the columns.
    instrument : str or None
        Written as ``# instrument:`` metadata.
    position_note : str or None
        ``# position:`` metadata for a deviation file, formatted with ``sign`` (default:
        the columns' formula).
    """

    joints: tuple[str, ...] = ()
    position: tuple[str, ...] = ()
    deviation: tuple[str, ...] | None = None
    deviation_sign: float = 1.0
    orientation: tuple[str, ...] | None = None
    euler: str | None = None
    sigma_position: tuple[str, ...] | None = None
    sigma_orientation: tuple[str, ...] | None = None
    temp: str | None = None
    time: str | None = None
    pose_id: str | None = None
    joint_temps: tuple[str, ...] | None = None
    joint_torques: tuple[str, ...] | None = None
    separator: str = "auto"
    decimal: str = "point"
    length_unit: str | None = None
    joint_unit: str | None = None
    angle_unit: str | None = None
    header: bool = True
    instrument: str | None = None
    position_note: str | None = None


#: Layouts of known files.  ``ipa-ur10``: the Fraunhofer IPA UR10 T-Mac series
#: (fixtures/ipa-ur10/SOURCE.md); ``wam``: the Barrett WAM set (fixtures/wam/SOURCE.md),
#: position = x_t + sign · x_dif, sign +1 as decided on the data (docs/identify.md).
PRESETS: dict[str, TrackerLayout] = {
    "ipa-ur10": TrackerLayout(
        joints=(
            "shoulder_pan_joint",
            "shoulder_lift_joint",
            "elbow_joint",
            "wrist_1_joint",
            "wrist_2_joint",
            "wrist_3_joint",
        ),
        position=("measurement_x", "measurement_y", "measurement_z"),
        orientation=("measurement_rx", "measurement_ry", "measurement_rz"),
        euler="XYZ",
        sigma_position=("measurement_std_x", "measurement_std_y", "measurement_std_z"),
        sigma_orientation=("measurement_std_rx", "measurement_std_ry", "measurement_std_rz"),
        temp="measurement_temperature",
        separator=";",
        decimal="comma",
        length_unit="mm",
        joint_unit="rad",
        angle_unit="deg",
        instrument="Leica laser tracker with a T-Mac 6-DoF probe",
    ),
    "wam": TrackerLayout(
        joints=tuple(f"joint_{i}" for i in range(1, 8)),
        position=("x_t", "y_t", "z_t"),
        deviation=("x_dif", "y_dif", "z_dif"),
        deviation_sign=1.0,
        separator=",",
        decimal="point",
        length_unit="mm",
        joint_unit="deg",
        instrument="GTS3800 laser tracker",
        position_note="x_t + ({sign:+.0f}) * dif",
    ),
}

# the option of the command line that sets each layout field (messages name it)
OPTION = {
    "joints": "--joints",
    "position": "--position",
    "deviation": "--deviation",
    "deviation_sign": "--deviation-sign",
    "orientation": "--orientation",
    "euler": "--euler",
    "sigma_position": "--sigma-position",
    "sigma_orientation": "--sigma-orientation",
    "temp": "--temp",
    "time": "--time",
    "pose_id": "--pose-id",
    "joint_temps": "--joint-temps",
    "joint_torques": "--joint-torques",
    "separator": "--sep",
    "decimal": "--decimal",
    "length_unit": "--length-unit",
    "joint_unit": "--joint-unit",
    "angle_unit": "--angle-unit",
    "header": "--no-header",
}


def layout_with(base: TrackerLayout, **changes: object) -> TrackerLayout:
    """``base`` with the fields in ``changes`` that are not None replaced (a preset plus options)."""
    names = {f.name for f in fields(TrackerLayout)}
    unknown = set(changes) - names
    if unknown:
        raise TypeError(f"not layout fields: {sorted(unknown)}")
    return replace(base, **{k: v for k, v in changes.items() if v is not None})  # type: ignore[arg-type]


def check_euler(seq: str) -> str:
    """``seq`` when it names an Euler convention as scipy does, else a one-line InputError."""
    s = str(seq)
    ok = (
        len(s) == 3
        and (set(s) <= set("XYZ") or set(s) <= set("xyz"))
        and s[0] != s[1]
        and s[1] != s[2]
    )
    if not ok:
        raise InputError(
            f"{OPTION['euler']} {s!r}: not an Euler convention as scipy names it (three axes "
            "from x, y, z with no axis twice in a row; upper-case intrinsic such as XYZ or ZYX, "
            "lower-case extrinsic such as xyz)"
        )
    return s


def check_layout(layout: TrackerLayout) -> None:
    """Refuse a layout that cannot describe a file (one line naming the option).

    Raises
    ------
    InputError
        An unknown unit, separator, decimal mark or Euler convention; a mapping of the wrong
        length; angle uncertainties without angles; a decimal comma in a comma-separated file.
    """

    def bad(field_: str, value: object, what: str) -> InputError:
        return InputError(f"{OPTION[field_]} {value!r}: {what}")

    if not layout.joints:
        raise InputError(f"{OPTION['joints']}: no joint columns given (q1 … qN of the robot)")
    for name, n in (
        ("position", 3),
        ("deviation", 3),
        ("orientation", 3),
        ("sigma_position", 3),
        ("sigma_orientation", 3),
    ):
        cols = getattr(layout, name)
        if name == "position" and not cols:
            raise InputError(f"{OPTION['position']}: no position columns given (x, y, z)")
        if cols is not None and len(cols) != n:
            raise bad(name, ",".join(cols), f"needs {n} columns, got {len(cols)}")
    for name in ("joint_temps", "joint_torques"):
        cols = getattr(layout, name)
        if cols is not None and len(cols) != len(layout.joints):
            raise bad(
                name,
                ",".join(cols),
                f"needs one column per joint ({len(layout.joints)}), got {len(cols)}",
            )
    for name, known in (
        ("length_unit", LENGTH_UNITS),
        ("joint_unit", ANGLE_UNITS),
        ("angle_unit", ANGLE_UNITS),
    ):
        v = getattr(layout, name)
        if v is not None and v not in known:
            raise bad(name, v, f"unknown unit; use {', '.join(known)}")
    if layout.separator not in SEPARATORS:
        raise bad("separator", layout.separator, "unknown separator; use auto, ',', ';' or tab")
    if layout.decimal not in DECIMALS:
        raise bad("decimal", layout.decimal, "unknown decimal mark; use point or comma")
    if layout.decimal == "comma" and SEPARATORS[layout.separator] == ",":
        raise InputError(
            f"{OPTION['decimal']} comma with {OPTION['separator']} ',': a decimal comma in a "
            "comma-separated file is ambiguous; the file must use ';' or tabs"
        )
    if layout.instrument is not None:
        one_line(layout.instrument, "--instrument")  # it becomes a '# instrument:' line
    if layout.deviation_sign not in (1.0, -1.0):
        raise bad("deviation_sign", layout.deviation_sign, "must be +1 or -1")
    if layout.orientation is not None:
        if layout.euler is None:
            raise InputError(
                f"{OPTION['orientation']} needs {OPTION['euler']} (the convention of the angles, "
                "as scipy names it: XYZ, xyz, ZYX, ...)"
            )
        check_euler(layout.euler)
    elif layout.sigma_orientation is not None:
        raise InputError(
            f"{OPTION['sigma_orientation']} without {OPTION['orientation']}: angle "
            "uncertainties need the angles"
        )
    elif layout.euler is not None:
        check_euler(layout.euler)
        raise InputError(f"{OPTION['euler']} without {OPTION['orientation']}: no angles to convert")


# --------------------------------------------------------------------------- reading


def read_tracker(path: str | os.PathLike[str], layout: TrackerLayout) -> Measurements:
    """Read a tracker export into SI :class:`Measurements` (orientation as ``rot``).

    Raises
    ------
    InputError
        One line ``file:line:column: what`` for a missing file or column, a cell that is not
        a finite number, a decimal mark or unit that contradicts the layout, values that
        look like another unit; or naming the option for a bad layout.
    """
    p = Path(path)
    check_layout(layout)  # before reading: a bad option is named even if the file is bad
    return parse_tracker(read_text_limited(p, "measurements"), str(p), layout)


@dataclass(frozen=True)
class _Column:
    """A mapped column: its index in the file and what it means."""

    index: int
    role: str  # "q3", "x", "angle 2", "sx" …: used in messages
    quantity: str | None  # "length", "joint", "angle", "temperature", "time" or None
    header: str  # the header text ("" without a header)


def _split(line: str, sep: str) -> list[str]:
    if '"' not in line:
        return [c.strip() for c in line.split(sep)]
    return [c.strip() for c in next(csv.reader([line], delimiter=sep))]


def _detect_separator(line: str, decimal: str) -> str:
    cands = ["\t", ";"] + ([","] if decimal == "point" else [])
    counts = [line.count(c) for c in cands]
    best = int(np.argmax(counts))
    return cands[best] if counts[best] > 0 else ","


def parse_tracker(text: str, name: str, layout: TrackerLayout) -> Measurements:
    """:func:`read_tracker` on the file's text (``name`` is used in messages and metadata)."""
    check_layout(layout)
    # ---- lines: skip blank lines and '#' comments
    lines = [
        (i, line)
        for i, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise InputError(
            f"{name}:1:1: empty file: expected "
            + ("a header row naming the columns" if layout.header else "rows of numbers")
        )
    sep = SEPARATORS[layout.separator]
    if sep is None:
        sep = _detect_separator(lines[0][1], layout.decimal)
        if layout.decimal == "comma" and sep == "," and layout.header:
            raise InputError(
                f"{name}:{lines[0][0]}:1: no ';' or tab in the header: a file with decimal "
                f"commas ({OPTION['decimal']} comma) needs one of them as the separator"
            )
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in lines:
        if len(line) > MAX_CELL_CHARS * 256:
            raise InputError(f"{name}:{lineno}:1: line of {len(line)} characters is too long")
        try:
            cells = _split(line, sep)
        except csv.Error as exc:
            raise InputError(f"{name}:{lineno}:1: not a delimited row: {exc}") from None
        for j, c in enumerate(cells):
            if len(c) > MAX_CELL_CHARS:
                raise InputError(
                    f"{name}:{lineno}:{j + 1}: cell of {len(c)} characters is over the limit "
                    f"of {MAX_CELL_CHARS}"
                )
        rows.append((lineno, cells))
    header: list[str] = []
    header_line = 0
    if layout.header:
        header_line, header = rows[0]
        rows = rows[1:]
    if not rows:
        raise InputError(f"{name}:{header_line + 1}:1: no data rows after the header")
    if len(rows) > MAX_ROWS:
        raise InputError(f"{name}: {len(rows)} data rows is over the limit of {MAX_ROWS}")
    width = len(header) if layout.header else max(len(c) for _, c in rows)

    layout = _named_joint_columns(layout, header)
    cols = _resolve_columns(layout, header, header_line, width, name)
    units = _units(layout, cols, header_line, name)

    # ---- rows: as wide as the header (trailing empty cells are a trailing separator)
    need = max(c.index for c in cols.values()) + 1
    for lineno, cells in rows:
        if len(cells) < (width if layout.header else need) or any(cells[width:]):
            hint = (
                " (decimal commas in a comma-separated file?)"
                if sep == "," and len(cells) > width
                else ""
            )
            raise InputError(
                f"{name}:{lineno}:{min(len(cells), width) + 1}: row has {len(cells)} cells, "
                f"the {'header' if layout.header else 'layout'} has {width}{hint}"
            )

    def numbers(key: str) -> F:
        c = cols[key]
        return _numbers(rows, c, layout.decimal, name)

    n_j = len(layout.joints)
    q_file = np.stack([numbers(f"q{i + 1}") for i in range(n_j)], axis=1)
    _check_angle_unit(q_file, units["joint"], [cols[f"q{i + 1}"] for i in range(n_j)], rows, name)
    q = np.radians(q_file) if units["joint"] == "deg" else q_file * ANGLE_UNITS[units["joint"]]

    pos_file = np.stack([numbers(k) for k in ("x", "y", "z")], axis=1)
    if layout.deviation is not None:
        dev = np.stack([numbers(k) for k in ("dx", "dy", "dz")], axis=1)
        pos_file = pos_file + layout.deviation_sign * dev
    pos = pos_file * LENGTH_UNITS[units["length"]]
    far = np.linalg.norm(pos, axis=1)
    if np.any(far > MAX_RANGE_M):
        i = int(np.argmax(far))
        raise InputError(
            f"{name}:{rows[i][0]}:{cols['x'].index + 1}: the target is {far[i]:.4g} m from the "
            f"instrument, beyond any laser tracker's range: the positions are not in "
            f"{units['length']} ({OPTION['length_unit']})"
        )

    rot = sigma_rot = None
    if layout.orientation is not None:
        assert layout.euler is not None
        akeys = [f"angle {k + 1}" for k in range(3)]
        ang_file = np.stack([numbers(k) for k in akeys], axis=1)
        _check_angle_unit(ang_file, units["angle"], [cols[k] for k in akeys], rows, name)
        ang = ang_file * ANGLE_UNITS[units["angle"]]
        from scipy.spatial.transform import Rotation  # scipy (0.1 s): tracker files only

        rot = Rotation.from_euler(layout.euler, ang).as_matrix()
        if layout.sigma_orientation is not None:
            skeys = [f"s(angle {k + 1})" for k in range(3)]
            s_ang = np.stack([_positive(numbers(k), cols[k], rows, name) for k in skeys], axis=1)
            sigma_rot = srot_from_euler_sigmas(
                layout.euler, ang, s_ang * ANGLE_UNITS[units["angle"]]
            )
    sigma_pos = None
    if layout.sigma_position is not None:
        s = np.stack(
            [_positive(numbers(k), cols[k], rows, name) for k in ("sx", "sy", "sz")], axis=1
        )
        sigma_pos = s * LENGTH_UNITS[units["length"]]
    temp = time = None
    if layout.temp is not None:
        temp = numbers("temp")
        lo, hi = TEMP_RANGE_C
        out = np.flatnonzero((temp < lo) | (temp > hi))
        if out.size:
            i = int(out[0])
            raise InputError(
                f"{name}:{rows[i][0]}:{cols['temp'].index + 1}: temperature {temp[i]:.6g} is "
                f"outside [{lo:g}, {hi:g}] °C: the column must be in degrees Celsius"
            )
    if layout.time is not None:
        time = numbers("time")
    per_joint: dict[str, F | None] = {}
    for field_, prefix in (("joint_temps", "temp_j"), ("joint_torques", "tau_j")):
        per_joint[field_] = None
        if getattr(layout, field_) is None:
            continue
        keys = [f"{prefix}{i + 1}" for i in range(n_j)]
        vals = np.stack([numbers(k) for k in keys], axis=1)
        per_joint[field_] = check_joint_values(
            vals,
            prefix,
            lambda i, j, keys=keys: (
                f"{name}:{rows[i][0]}:{cols[keys[j]].index + 1}: {cols[keys[j]].role}"
            ),
        )
    pose_id = None
    if layout.pose_id is not None:
        j = cols["pose_id"].index
        for lineno, cells in rows:
            v = cells[j]
            if v == "" or any(ch < " " or ch == "\x7f" for ch in v):
                raise InputError(
                    f"{name}:{lineno}:{j + 1}: pose id {v[:40]!r} is empty or has a control "
                    "character"
                )
        pose_id = tuple(cells[j] for _, cells in rows)

    meta = {"source": Path(name).name}
    if layout.instrument:
        meta["instrument"] = layout.instrument
    if layout.deviation is not None:
        meta["position"] = (
            layout.position_note.format(sign=layout.deviation_sign)  # a preset's wording
            if layout.position_note
            else f"({', '.join(layout.position)}) + ({layout.deviation_sign:+.0f}) * "
            f"({', '.join(layout.deviation)})"
        )
    if layout.orientation is not None:
        meta["orientation"] = (
            f"({', '.join(layout.orientation)}) as scipy from_euler('{layout.euler}') in "
            f"{units['angle']}, written as a quaternion"
        )
        if sigma_rot is not None:
            meta["srot"] = "sqrt(trace(E diag(s^2) E^T) / 3) of the per-angle uncertainties"
    return Measurements(
        q=q,
        pos=pos,
        rot=rot,
        sigma_rot=sigma_rot,
        sigma_pos=sigma_pos,
        temp=temp,
        time=time,
        joint_temp=per_joint["joint_temps"],
        joint_torque=per_joint["joint_torques"],
        pose_id=pose_id,
        meta=meta,
    )


def _named_joint_columns(layout: TrackerLayout, header: list[str]) -> TrackerLayout:
    """The layout with the CSV v1 per-joint columns (``temp_j1`` … ``temp_jN``, ``tau_j1`` …)
    mapped when the header names all of them and the layout maps none of that kind."""
    bare = {_UNIT_SUFFIX.sub(r"\1", h).strip() if _UNIT_SUFFIX.match(h) else h for h in header}
    changes: dict[str, tuple[str, ...]] = {}
    for field_, prefix in (("joint_temps", "temp_j"), ("joint_torques", "tau_j")):
        names = tuple(f"{prefix}{i + 1}" for i in range(len(layout.joints)))
        if getattr(layout, field_) is None and names and set(names) <= bare:
            changes[field_] = names
    return replace(layout, **changes) if changes else layout  # type: ignore[arg-type]


def _resolve_columns(
    layout: TrackerLayout, header: list[str], header_line: int, width: int, name: str
) -> dict[str, _Column]:
    """Every mapped column's index; one line for a missing, ambiguous or doubly used column."""
    bare = [_UNIT_SUFFIX.sub(r"\1", h).strip() if _UNIT_SUFFIX.match(h) else h for h in header]
    wanted: list[tuple[str, str, str | None, str, str]] = []  # key, role, quantity, ref, field
    for i, ref in enumerate(layout.joints):
        wanted.append((f"q{i + 1}", f"q{i + 1}", "joint", ref, "joints"))
    for k, ref in zip("xyz", layout.position, strict=True):
        wanted.append((k, k, "length", ref, "position"))
    for k, ref in zip(("dx", "dy", "dz"), layout.deviation or (), strict=False):
        wanted.append((k, f"deviation {k[1]}", "length", ref, "deviation"))
    for k, ref in enumerate(layout.orientation or ()):
        wanted.append((f"angle {k + 1}", f"angle {k + 1}", "angle", ref, "orientation"))
    for k, ref in zip(("sx", "sy", "sz"), layout.sigma_position or (), strict=False):
        wanted.append((k, k, "length", ref, "sigma_position"))
    for k, ref in enumerate(layout.sigma_orientation or ()):
        wanted.append((f"s(angle {k + 1})", f"s(angle {k + 1})", "angle", ref, "sigma_orientation"))
    for k in ("temp", "time", "pose_id"):
        ref = getattr(layout, k)
        if ref is not None:
            q = {"temp": "temperature", "time": "time", "pose_id": None}[k]
            wanted.append((k, k, q, ref, k))
    for field_, prefix, q, what in (
        ("joint_temps", "temp_j", "temperature", "temperature"),
        ("joint_torques", "tau_j", None, "torque"),
    ):
        for i, ref in enumerate(getattr(layout, field_) or ()):
            wanted.append((f"{prefix}{i + 1}", f"joint {i + 1} {what}", q, ref, field_))

    hl = header_line or 1
    out: dict[str, _Column] = {}
    used: dict[int, str] = {}
    for key, role, quantity, ref, field_ in wanted:
        ref = ref.strip()
        idx = [j for j, h in enumerate(header) if h == ref]
        if not idx:
            idx = [j for j, h in enumerate(bare) if h == ref]
        if len(idx) > 1:
            raise InputError(
                f"{name}:{hl}:{idx[1] + 1}: column {ref!r} ({OPTION[field_]}, {role}) appears "
                f"{len(idx)} times in the header (columns {', '.join(str(j + 1) for j in idx)}); "
                "name it by number"
            )
        if not idx and ref.isdigit() and 1 <= int(ref) <= width:
            idx = [int(ref) - 1]
        if not idx:
            if not layout.header:
                raise InputError(
                    f"{OPTION[field_]} {ref!r}: without a header, columns are named by number "
                    f"(1 … {width})"
                )
            shown = ", ".join(header[:12]) + (", …" if len(header) > 12 else "")
            raise InputError(
                f"{name}:{hl}:{len(header) + 1}: missing column {ref!r} ({OPTION[field_]}, "
                f"{role}); the header has: {shown}"
            )
        j = idx[0]
        if j in used:
            raise InputError(
                f"{name}:{hl}:{j + 1}: column {ref!r} is mapped twice ({used[j]} and {role})"
            )
        used[j] = role
        out[key] = _Column(j, role, quantity, header[j] if header else "")
    return out


def _units(
    layout: TrackerLayout, cols: dict[str, _Column], header_line: int, name: str
) -> dict[str, str]:
    """The length, joint and angle units: the layout's, else the header's, else mm and deg.

    A header unit (``x [m]``) that contradicts the layout or another column of the same
    quantity, or a unit that is not supported (``[cm]``, ``[K]``), is refused at its cell.
    """
    given = {"length": layout.length_unit, "joint": layout.joint_unit, "angle": layout.angle_unit}
    option = {"length": "length_unit", "joint": "joint_unit", "angle": "angle_unit"}
    found: dict[str, tuple[str, _Column]] = {}
    for c in cols.values():
        m = _UNIT_SUFFIX.match(c.header) if c.header else None
        if not m or c.quantity is None:
            continue
        word = m.group(2).strip().lower()
        q_kind = "angle" if c.quantity == "joint" else c.quantity
        where = f"{name}:{header_line}:{c.index + 1}: column {c.header!r} ({c.role})"
        if word in _UNSUPPORTED_UNITS:
            what = {"length": "mm, m or in", "angle": "deg or rad", "temperature": "°C"}.get(
                _UNSUPPORTED_UNITS[word], "s"
            )
            raise InputError(f"{where}: unit {m.group(2)!r} is not supported; convert to {what}")
        if word not in _UNIT_WORDS:
            continue  # "(A)", "[TMac]": a name, not a unit
        kind, unit = _UNIT_WORDS[word]
        if kind != q_kind:
            article = "an" if q_kind[0] in "aeiou" else "a"
            raise InputError(f"{where}: unit {m.group(2)!r} is not {article} {q_kind} unit")
        if c.quantity in given:
            if given[c.quantity] is not None and unit != given[c.quantity]:
                raise InputError(
                    f"{where}: the header says {unit}, but the {c.quantity} unit is "
                    f"{given[c.quantity]} ({OPTION[option[c.quantity]]})"
                )
            prev = found.get(c.quantity)
            if prev is not None and prev[0] != unit:
                raise InputError(
                    f"{where}: the header says {unit}, but column {prev[1].header!r} says "
                    f"{prev[0]}: one {c.quantity} unit per file"
                )
            found[c.quantity] = (unit, c)
    default = {"length": "mm", "joint": "deg", "angle": "deg"}
    return {
        k: given[k] or (found[k][0] if k in found else default[k])
        for k in ("length", "joint", "angle")
    }


def _numbers(rows: list[tuple[int, list[str]]], c: _Column, decimal: str, name: str) -> F:
    """Column ``c`` as finite floats; the first bad cell is named ``file:line:column``."""
    j = c.index
    cells = [r[j] for _, r in rows]
    fast = None
    if decimal == "point" or not any("." in s for s in cells):  # a dot in comma mode: blamed
        if decimal == "comma":
            cells = [s.replace(",", ".") for s in cells]
        try:  # vectorised fast path; the loop below finds the cell to blame
            fast = np.array(cells, dtype=np.float64)
        except ValueError:
            fast = None
    if fast is not None and np.all(np.isfinite(fast)):
        return fast
    where_col = f"column {c.header!r} ({c.role})" if c.header else f"column {j + 1} ({c.role})"
    out = np.empty(len(rows))
    for i, (lineno, r) in enumerate(rows):
        raw = r[j]
        at = f"{name}:{lineno}:{j + 1}: {where_col}"
        if raw == "":
            raise InputError(f"{at}: empty cell")
        if decimal == "comma" and "." in raw:
            raise InputError(
                f"{at}: {raw!r} has a decimal point, but the file is read with decimal commas "
                f"({OPTION['decimal']} comma)"
            )
        text = raw.replace(",", ".") if decimal == "comma" else raw
        try:
            v = float(text)
        except ValueError:
            hint = ""
            if decimal == "point" and _DECIMAL_COMMA_NUMBER.match(raw):
                hint = f": a decimal comma? give {OPTION['decimal']} comma"
            raise InputError(f"{at}: {raw!r} is not a number{hint}") from None
        if not math.isfinite(v):
            raise InputError(f"{at}: {raw!r} is not a finite number")
        out[i] = v
    return out


def _positive(v: F, c: _Column, rows: list[tuple[int, list[str]]], name: str) -> F:
    bad = np.flatnonzero(v <= 0)
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"{name}:{rows[i][0]}:{c.index + 1}: column {c.header or c.index + 1!r} ({c.role}): "
            f"uncertainty {rows[i][1][c.index]} must be > 0"
        )
    return v


def _check_angle_unit(
    vals: F, unit: str, cs: Sequence[_Column], rows: list[tuple[int, list[str]]], name: str
) -> None:
    """Refuse angles that look like the other unit (the CSV v1 reader's rule, both ways).

    Degrees that are all within ±2π while some column moves by more than 0.2 (joints) or 1
    (orientation) are radians; radians beyond ±4π (joints: two turns) or ±2π (Euler angles)
    are degrees.
    """
    joints = cs[0].quantity == "joint"
    what = "joint angles" if joints else "orientation angles"
    opt = OPTION["joint_unit" if joints else "angle_unit"]
    a = np.abs(vals)
    i, k = np.unravel_index(np.argmax(a), a.shape)
    amax = float(a[i, k])
    at = f"{name}:{rows[i][0]}:{cs[k].index + 1}"
    if unit == "deg":
        spread = 0.2 if joints else 1.0
        if len(rows) >= 3 and amax <= 2 * math.pi + 1e-6 and np.ptp(vals, axis=0).max() > spread:
            raise InputError(
                f"{at}: {what} look like radians (every |value| <= {amax:.3g}), but the unit is "
                f"deg: give {opt} rad"
            )
    else:
        limit = 4 * math.pi if joints else 2 * math.pi + 1e-6
        if amax > limit:
            raise InputError(
                f"{at}: {what} look like degrees ({vals[i, k]:.6g} is beyond "
                f"±{limit:.3g} rad), but the unit is rad: give {opt} deg"
            )


# --------------------------------------------------------------------------- orientation


def euler_rate_matrix(seq: str, angles: F) -> F:
    """The Euler-rate map ``E`` of scipy's convention ``seq``: ``ω = E(θ) · dθ``.

    Parameters
    ----------
    seq : str
        As ``Rotation.from_euler`` names it (``XYZ`` intrinsic, ``xyz`` extrinsic, …).
    angles : ndarray, shape (n, 3), rad
        In the order of ``seq``'s axes.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        Column k is the unit axis (instrument frame) about which a change of angle k turns the
        target; ``ω`` is the angular velocity in the instrument frame (``Ṙ Rᵀ = [ω]×``).
        Defined everywhere, also at gimbal lock (where two columns become parallel).
    """
    from scipy.spatial.transform import Rotation  # scipy (0.1 s): tracker files only

    angles = np.atleast_2d(np.asarray(angles, dtype=float))
    seq = check_euler(seq)
    # the elementary rotations in matrix order (left to right) and the angle each one takes:
    # intrinsic "ABC" is R_A(θ1) R_B(θ2) R_C(θ3); extrinsic "abc" is R_c(θ3) R_b(θ2) R_a(θ1)
    order = [0, 1, 2] if seq.isupper() else [2, 1, 0]
    n = angles.shape[0]
    E = np.empty((n, 3, 3))
    prefix = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for k in order:
        axis = "xyz".index(seq[k].lower())
        E[:, :, k] = prefix[:, :, axis]  # prefix · e_axis
        prefix = prefix @ Rotation.from_euler(seq[k].lower(), angles[:, k : k + 1]).as_matrix()
    return E


def srot_from_euler_sigmas(seq: str, angles: F, sigmas: F) -> F:
    """CSV v1 ``srot`` (rad) from per-angle standard uncertainties (rad), shape (n,).

    ``Σω = E diag(σ²) Eᵀ`` (forward map, :func:`euler_rate_matrix`), then
    ``srot = sqrt(trace(Σω) / 3)``: the isotropic rotation uncertainty with the same total
    variance.  Finite at every orientation.
    """
    E = euler_rate_matrix(seq, angles)
    sig2 = np.asarray(sigmas, dtype=float) ** 2
    cov = np.einsum("nik,nk,njk->nij", E, sig2, E)
    return np.sqrt(np.trace(cov, axis1=1, axis2=2) / 3.0)
