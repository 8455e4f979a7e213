"""Measurement CSV v1 (CONTRACTS.md): read, check for a fit, write.

Every unit conversion between the file (mm, degrees) and the library (m, rad) happens here,
once.  Every bad input raises :class:`InputError` with one line ``file:line:column: what``
(line and column 1-based; column = the CSV column).
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.measurements import Measurements
from ...identify.robot import RobotModel
from ...identify.transforms import R_to_quat, quat_to_R
from .common import (
    MAX_CELL_CHARS,
    MAX_FIT_ROWS,
    MAX_LINE_CHARS,
    MAX_ROWS,
    MIN_DISTINCT_POSES,
    MIN_JOINT_SPAN_DEG,
    csv_cell,
    csv_text,
    excerpt,
    meta_line,
    one_line,
    read_meta_line,
    read_text_limited,
    write_text_atomic,
)

F = NDArray[np.float64]

OPTIONAL_COLUMNS = (
    "pitch",
    "yaw",
    "roll",
    "time",
    "temp",
    "pan",
    "sx",
    "sy",
    "sz",
    "spitch",
    "syaw",
    "sroll",
    "pose_id",
    "qw",
    "qx",
    "qy",
    "qz",
    "srot",
)

#: Per-row uncertainties an instrument can state: 1 nm … 1 m, 1e-6 … 90 deg (outside them
#: the number is a typing error, and 1e-300 weighted one row above all others).
SIGMA_POS_MM_RANGE = (1e-6, 1e3)
SIGMA_ROT_DEG_RANGE = (1e-6, 90.0)

#: Per-joint columns (CSV v1): each joint's temperature (°C) and measured torque (N·m), as
#: ``temp_j1`` … ``temp_jN`` and ``tau_j1`` … ``tau_jN``, all of a group or none, and the range
#: a controller can report (outside it the number is a typing error or another unit).
JOINT_COLUMNS = {
    "temp_j": ("joint_temp", "°C", (-50.0, 200.0)),
    "tau_j": ("joint_torque", "N·m", (-5000.0, 5000.0)),
}


def check_joint_values(vals: F, prefix: str, where: Callable[[int, int], str]) -> F:
    """``vals`` (n, nj) of the per-joint group ``prefix`` (:data:`JOINT_COLUMNS`), refused in one
    line at ``where(row, joint)`` when a value is outside what a controller reports."""
    _, unit, (lo, hi) = JOINT_COLUMNS[prefix]
    bad = np.argwhere((vals < lo) | (vals > hi))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        raise InputError(
            f"{where(i, j)}: {vals[i, j]:.6g} {unit} is outside what a controller reports "
            f"({lo:g} to {hi:g} {unit}): another unit?"
        )
    return vals


#: How far from 1 a quaternion's norm may be (rounding of written cells) before it is refused.
QUAT_NORM_TOL = 1e-3


def check_joint_limits(
    q: F, robot: RobotModel, name: str, lines: Sequence[int] | None = None, what: str = "row"
) -> None:
    """Refuse joint values (rad) outside the robot's limits, one line naming the first."""
    q = np.atleast_2d(q)
    lo = np.asarray(robot.q_min)[None, :] - 1e-9
    hi = np.asarray(robot.q_max)[None, :] + 1e-9
    bad = ~((q >= lo) & (q <= hi))
    if not bad.any():
        return
    i, j = (int(v) for v in np.argwhere(bad)[0])
    where = f"{name}:{lines[i]}:" if lines is not None else f"{name}: {what} {i + 1}: "
    if lines is not None:
        where += " "
    n = int(bad.any(axis=1).sum())
    raise InputError(
        f"{where}joint {j + 1} at {math.degrees(q[i, j]):.6g} deg is outside the robot's limits "
        f"[{math.degrees(robot.q_min[j]):.6g}, {math.degrees(robot.q_max[j]):.6g}] deg"
        + (f" ({n} {what}s in all)" if n > 1 else "")
    )


def check_fit_rows(meas: Measurements, name: str) -> None:
    """The one row limit of every command that fits (``identify fit``, ``diagnose``,
    ``compare``, ``reprocess``, the TUI and ``run --archive``: :func:`check_poses_for_fit` and
    :func:`quickhealth.station.services.fitting.assess`).

    Raises
    ------
    InputError
        More than :data:`~.common.MAX_FIT_ROWS` rows (one line).
    """
    if meas.n_poses > MAX_FIT_ROWS:
        raise InputError(
            f"{name}: {meas.n_poses} rows is over the fit's limit of {MAX_FIT_ROWS} (the order "
            "search costs rows x fits; the NIST loop has 150 poses): fit a subset"
        )


def check_poses_for_fit(meas: Measurements, robot: RobotModel, name: str) -> None:
    """Meaning of a measurement set before a fit: rows, joint limits, distinct poses, spans.

    Raises
    ------
    InputError
        More than ``MAX_FIT_ROWS`` rows, a joint outside the robot's limits, fewer than
        ``MIN_DISTINCT_POSES`` different joint configurations, or a joint that does not move
        (its error motions cannot be identified: named).
    """
    check_fit_rows(meas, name)
    check_joint_limits(meas.q, robot, name)
    distinct = np.unique(np.round(meas.q, 6), axis=0).shape[0]
    if distinct < MIN_DISTINCT_POSES and distinct < meas.n_poses:  # (few rows: the fit says)
        raise InputError(
            f"{name}: only {distinct} distinct joint configuration(s) in {meas.n_poses} rows; "
            f"a fit needs at least {MIN_DISTINCT_POSES}"
        )
    _check_position_scale(meas, robot, name)
    span = np.degrees(np.ptp(meas.q, axis=0))
    still = [j + 1 for j in range(meas.n_joints) if span[j] < MIN_JOINT_SPAN_DEG]
    if still:
        raise InputError(
            f"{name}: joint(s) {', '.join(map(str, still))} move less than "
            f"{MIN_JOINT_SPAN_DEG} deg over the data: their error motions cannot be identified; "
            "measure with every joint moving"
        )


#: Measured positions may span this many times more or less than the robot's flange does over
#: the same joints (a tool lever or a short robot explain a factor of a few, units 1000).
POSITION_SCALE_LIMIT = 20.0
#: A row this far (m) from the median measured position is not the same set-up.
MAX_POSITION_OFFSET_M = 50.0


def _check_position_scale(meas: Measurements, robot: RobotModel, name: str) -> None:
    """Refuse positions in the wrong unit or from another set-up (one line).

    The spread of the measured points (RMS distance from their centroid) against that of the
    nominal flange over the same joints: a ratio near 1/1000 is metres in a millimetre
    column; a row tens of metres from the others is not the same instrument set-up.
    """
    pos = meas.pos
    if np.all(np.isnan(pos)):
        return
    far = np.linalg.norm(pos - np.median(pos, axis=0), axis=1)
    if far.max() > MAX_POSITION_OFFSET_M:
        i = int(np.argmax(far))
        raise InputError(
            f"{name}: row {i + 1}: its position is {far[i]:.4g} m from the median of the "
            "others: not the same instrument set-up (a typing error, or another file's row?)"
        )
    T = robot.fk(meas.q).reshape(-1, 4, 4)
    flange = np.sqrt(np.mean(np.sum((T[:, :3, 3] - T[:, :3, 3].mean(0)) ** 2, axis=1)))
    measured = np.sqrt(np.mean(np.sum((pos - pos.mean(0)) ** 2, axis=1)))
    if flange > 0 and not 1 / POSITION_SCALE_LIMIT < measured / flange < POSITION_SCALE_LIMIT:
        raise InputError(
            f"{name}: the measured positions spread {measured * 1e3:.4g} mm while the robot's "
            f"flange moves {flange * 1e3:.4g} mm over these joints: positions in another unit "
            "(CSV v1 needs mm), or the wrong robot description?"
        )


def read_measurements(
    path: str | os.PathLike[str],
    n_joints: int | None = None,
    *,
    joints_only: bool = False,
) -> Measurements:
    """Read a measurement file (CSV v1, CONTRACTS.md) into SI :class:`Measurements`.

    Parameters
    ----------
    n_joints : int, optional
        Joint count of the robot; ``q1 … qN`` are then required.  Without it the joint columns
        present (consecutive from ``q1``) are used.
    joints_only : bool
        Accept a file of joint commands without ``x, y, z`` (``pos`` is then NaN).

    Raises
    ------
    InputError
        ``file:line:column: what`` for a missing file, missing or duplicate column, a cell
        that is not a finite number, angles that look like radians, a ragged row.
    """
    p = Path(path)
    text = read_text_limited(p, "measurements")
    return parse_measurements(text, str(p), n_joints, joints_only=joints_only)


def parse_measurements(
    text: str, name: str = "<text>", n_joints: int | None = None, *, joints_only: bool = False
) -> Measurements:
    """:func:`read_measurements` on the file's text (``name`` is used in messages)."""
    meta: dict[str, str] = {}
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if len(line) > MAX_LINE_CHARS:  # comments too: a comment becomes the file's metadata
            raise InputError(
                f"{name}:{lineno}:1: line of {len(line)} characters is too long "
                f"(at most {MAX_LINE_CHARS})"
            )
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            kv = read_meta_line(s)
            if kv is not None:
                meta[kv[0]] = kv[1]
            continue
        if '"' not in line:  # the common case, 20x faster than the csv module per line
            cells = [c.strip() for c in line.split(",")]
        else:
            try:
                cells = [c.strip() for c in next(csv.reader([line]))]
            except csv.Error as exc:
                raise InputError(f"{name}:{lineno}:1: not a CSV row: {exc}") from None
        for j, c in enumerate(cells):
            if len(c) > MAX_CELL_CHARS:
                raise InputError(
                    f"{name}:{lineno}:{j + 1}: cell of {len(c)} characters is over the limit "
                    f"of {MAX_CELL_CHARS}"
                )
        if header is None:
            header, header_line = cells, lineno
        else:
            rows.append((lineno, cells))
    if header is None:
        raise InputError(f"{name}:1:1: no header row (expected columns q1…qN, x, y, z)")
    col: dict[str, int] = {}
    for j, h in enumerate(header):
        if not h:
            raise InputError(f"{name}:{header_line}:{j + 1}: empty column name in the header")
        if h in col:
            raise InputError(
                f"{name}:{header_line}:{j + 1}: duplicate column {h!r} (also column {col[h] + 1})"
            )
        col[h] = j
    if n_joints is None:
        n_joints = 0
        while f"q{n_joints + 1}" in col:
            n_joints += 1
        if n_joints == 0:
            raise InputError(f"{name}:{header_line}:1: missing column 'q1' (joint readings, deg)")
    required = [f"q{i + 1}" for i in range(n_joints)]
    if not joints_only:
        required += ["x", "y", "z"]
    for c in required:
        if c not in col:
            raise InputError(
                f"{name}:{header_line}:{len(header) + 1}: missing column {c!r} "
                f"(required: {', '.join(required)})"
            )
    extra_q = f"q{n_joints + 1}"
    if extra_q in col:
        raise InputError(
            f"{name}:{header_line}:{col[extra_q] + 1}: column {extra_q!r}, but the robot has "
            f"{n_joints} joints"
        )
    for group in (
        ("pitch", "yaw", "roll"),
        ("sx", "sy", "sz"),
        ("spitch", "syaw", "sroll"),
        ("qw", "qx", "qy", "qz"),
    ):
        present = [g for g in group if g in col]
        if present and len(present) != len(group):
            missing = [g for g in group if g not in col]
            raise InputError(
                f"{name}:{header_line}:{col[present[0]] + 1}: column {present[0]!r} needs "
                f"{', '.join(repr(m) for m in missing)} too"
            )
    for a, b, what in (
        ("pitch", "qw", "orientation"),
        ("spitch", "srot", "orientation uncertainty"),
    ):
        if a in col and b in col:
            raise InputError(
                f"{name}:{header_line}:{col[b] + 1}: {what} given twice ({a!r} and {b!r} "
                "columns): keep one"
            )
    for prefix in JOINT_COLUMNS:
        group = [f"{prefix}{i + 1}" for i in range(n_joints)]
        present = [g for g in group if g in col]
        if present and len(present) != len(group):
            missing = [g for g in group if g not in col]
            raise InputError(
                f"{name}:{header_line}:{col[present[0]] + 1}: column {present[0]!r} needs "
                f"{', '.join(repr(m) for m in missing)} too (one per joint)"
            )
        beyond = f"{prefix}{n_joints + 1}"
        if beyond in col:
            raise InputError(
                f"{name}:{header_line}:{col[beyond] + 1}: column {beyond!r}, but the robot has "
                f"{n_joints} joints"
            )
    if "srot" in col and "pitch" not in col and "qw" not in col:
        raise InputError(
            f"{name}:{header_line}:{col['srot'] + 1}: orientation uncertainty 'srot' without an "
            "orientation (pitch, yaw, roll or qw, qx, qy, qz)"
        )
    if not rows:
        raise InputError(f"{name}:{header_line + 1}:1: no data rows")
    if len(rows) > MAX_ROWS:
        raise InputError(f"{name}: {len(rows)} data rows is over the limit of {MAX_ROWS}")
    for lineno, cells in rows:
        if len(cells) != len(header):
            raise InputError(
                f"{name}:{lineno}:{min(len(cells), len(header)) + 1}: row has {len(cells)} "
                f"cells, the header has {len(header)}"
            )

    parsed: dict[str, F] = {}

    def numbers(c: str, positive: bool = False) -> F:
        if c in parsed and not positive:
            return parsed[c]
        j = col[c]
        try:  # vectorised fast path; the loop below finds the cell to blame
            fast = np.array([cells[j] for _, cells in rows], dtype=np.float64)
        except ValueError:
            fast = None
        if fast is not None and np.all(np.isfinite(fast)) and not (positive and np.any(fast <= 0)):
            parsed[c] = fast
            return fast
        out = np.empty(len(rows))
        for i, (lineno, cells) in enumerate(rows):
            cell = cells[j]
            try:
                v = float(cell)
            except ValueError:
                what = "empty cell" if cell == "" else f"{cell!r} is not a number"
                raise InputError(f"{name}:{lineno}:{j + 1}: column {c!r}: {what}") from None
            if not math.isfinite(v):
                raise InputError(f"{name}:{lineno}:{j + 1}: column {c!r}: {cell} is not finite")
            if positive and v <= 0:
                raise InputError(
                    f"{name}:{lineno}:{j + 1}: column {c!r}: uncertainty {cell} must be > 0"
                )
            out[i] = v
        return out

    def looks_like_radians(cols: Sequence[str], what: str, spread: float) -> None:
        vals = np.stack([numbers(c) for c in cols], axis=1)
        amax = np.abs(vals).max()
        if len(rows) >= 3 and amax <= 2 * math.pi + 1e-6 and np.ptp(vals, axis=0).max() > spread:
            i, j = np.unravel_index(np.argmax(np.abs(vals)), vals.shape)
            raise InputError(
                f"{name}:{rows[i][0]}:{col[cols[j]] + 1}: {what} look like radians (every "
                f"|value| <= {amax:.2f}); the file needs degrees"
            )

    qcols = [f"q{i + 1}" for i in range(n_joints)]
    looks_like_radians(qcols, "joint angles", 0.2)
    q = np.radians(np.stack([numbers(c) for c in qcols], axis=1))
    if joints_only and "x" not in col:
        pos = np.full((len(rows), 3), np.nan)
    else:
        pos = np.stack([numbers(c) for c in ("x", "y", "z")], axis=1) * 1e-3
    rpy = rot = None
    if "pitch" in col:
        looks_like_radians(("pitch", "yaw", "roll"), "orientation angles", 1.0)
        rpy = np.radians(np.stack([numbers(c) for c in ("pitch", "yaw", "roll")], axis=1))
    if "qw" in col:
        quat = np.stack([numbers(c) for c in ("qw", "qx", "qy", "qz")], axis=1)
        norm = np.linalg.norm(quat, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > QUAT_NORM_TOL)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{name}:{rows[i][0]}:{col['qw'] + 1}: quaternion (qw, qx, qy, qz) has norm "
                f"{norm[i]:.6g}, not 1: not a rotation"
                + (f" ({bad.size} rows in all)" if bad.size > 1 else "")
            )
        rot = quat_to_R(quat)

    def uncertainty(cols: Sequence[str], unit: str, lo: float, hi: float) -> F:
        """Positive uncertainties within what an instrument can state (``lo`` … ``hi``)."""
        vals = np.stack([numbers(c, True) for c in cols], axis=1)
        bad = np.argwhere((vals < lo) | (vals > hi))
        if bad.size:
            i, j = (int(v) for v in bad[0])
            raise InputError(
                f"{name}:{rows[i][0]}:{col[cols[j]] + 1}: column {cols[j]!r}: uncertainty "
                f"{vals[i, j]:.6g} {unit} is outside what an instrument states "
                f"({lo:g} to {hi:g} {unit})"
            )
        return vals

    sig_pos = (
        uncertainty(("sx", "sy", "sz"), "mm", *SIGMA_POS_MM_RANGE) * 1e-3 if "sx" in col else None
    )
    sig_rpy = (
        np.radians(uncertainty(("spitch", "syaw", "sroll"), "deg", *SIGMA_ROT_DEG_RANGE))
        if "spitch" in col
        else None
    )
    if sig_rpy is not None and rpy is None:
        raise InputError(
            f"{name}:{header_line}:{col['spitch'] + 1}: angle uncertainties without angle columns"
        )
    sig_rot = (
        np.radians(uncertainty(("srot",), "deg", *SIGMA_ROT_DEG_RANGE)[:, 0])
        if "srot" in col
        else None
    )
    pose_id = (  # as written: a cell that looked like a formula carries an apostrophe
        tuple(csv_text(cells[col["pose_id"]]) for _, cells in rows) if "pose_id" in col else None
    )

    def per_joint(prefix: str) -> F | None:
        """The group ``prefix1`` … ``prefixN`` (n, nj) within what a controller reports."""
        cols = [f"{prefix}{i + 1}" for i in range(n_joints)]
        if cols[0] not in col:
            return None
        vals = np.stack([numbers(c) for c in cols], axis=1)
        return check_joint_values(
            vals, prefix, lambda i, j: f"{name}:{rows[i][0]}:{col[cols[j]] + 1}: column {cols[j]!r}"
        )

    return Measurements(
        q=q,
        pos=pos,
        rpy=rpy,
        rot=rot,
        sigma_rot=sig_rot,
        time=numbers("time") if "time" in col else None,
        temp=numbers("temp") if "temp" in col else None,
        pan=np.radians(numbers("pan")) if "pan" in col else None,
        joint_temp=per_joint("temp_j"),
        joint_torque=per_joint("tau_j"),
        sigma_pos=sig_pos,
        sigma_rpy=sig_rpy,
        pose_id=pose_id,
        meta=meta,
    )


def format_measurements(meas: Measurements) -> str:
    """CSV v1 text of ``meas`` (mm, deg; full precision).

    Raises
    ------
    InputError
        Data the contract (and :func:`parse_measurements`) would refuse: non-finite joints,
        a pose id or a metadata value with a line break or control character (it would
        split the row or forge a ``# key: value`` line: :func:`~.common.one_line`).  A pose
        id a spreadsheet would run as a formula is written neutralised (:func:`~.common.csv_cell`;
        read back as it was).
    """
    if not np.all(np.isfinite(meas.q)):
        i = int(np.argwhere(~np.isfinite(meas.q))[0][0])
        raise InputError(f"measurement row {i + 1}: joint angles are not finite; not written")
    if meas.pose_id is not None:
        for i, pid in enumerate(meas.pose_id):
            one_line(pid, f"measurement row {i + 1}: pose_id")
            if len(str(pid)) > MAX_CELL_CHARS - 1:  # room for csv_cell's apostrophe
                raise InputError(
                    f"measurement row {i + 1}: pose_id {excerpt(pid)} is longer than "
                    f"{MAX_CELL_CHARS - 1} characters; not written"
                )
            if str(pid) != str(pid).strip():
                raise InputError(
                    f"measurement row {i + 1}: pose_id {str(pid)[:40]!r} begins or ends with a "
                    "space, which the reader strips; not written"
                )
    buf = io.StringIO()
    for k, v in meas.meta.items():
        buf.write(meta_line(k, v))
    cols: list[tuple[str, F | tuple[str, ...]]] = []
    if meas.pose_id is not None:
        cols.append(("pose_id", tuple(csv_cell(str(p)) for p in meas.pose_id)))
    for i in range(meas.n_joints):
        cols.append((f"q{i + 1}", np.degrees(meas.q[:, i])))
    if not np.all(np.isnan(meas.pos)):
        for i, c in enumerate("xyz"):
            cols.append((c, meas.pos[:, i] * 1e3))
    if meas.rpy is not None:
        for i, c in enumerate(("pitch", "yaw", "roll")):
            cols.append((c, np.degrees(meas.rpy[:, i])))
    elif meas.rot is not None:  # orientation as rotations: the quaternion form (no singularity)
        quat = R_to_quat(meas.rot)
        for i, c in enumerate(("qw", "qx", "qy", "qz")):
            cols.append((c, quat[:, i]))
    for c in ("time", "temp"):
        v = getattr(meas, c)
        if v is not None:
            cols.append((c, v))
    for prefix, (attr, _, _) in JOINT_COLUMNS.items():
        v = getattr(meas, attr)
        if v is not None:
            cols += [(f"{prefix}{i + 1}", v[:, i]) for i in range(meas.n_joints)]
    if meas.pan is not None:
        cols.append(("pan", np.degrees(meas.pan)))
    if meas.sigma_pos is not None:
        for i, c in enumerate(("sx", "sy", "sz")):
            cols.append((c, meas.sigma_pos[:, i] * 1e3))
    if meas.sigma_rpy is not None:
        for i, c in enumerate(("spitch", "syaw", "sroll")):
            cols.append((c, np.degrees(meas.sigma_rpy[:, i])))
    if meas.sigma_rot is not None:
        cols.append(("srot", np.degrees(meas.sigma_rot)))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([c for c, _ in cols])
    for r in range(meas.n_poses):
        row = [v[r] if isinstance(v, tuple) else repr(float(v[r])) for _, v in cols]
        if row and str(row[0]).lstrip().startswith("#"):
            # a pose_id opening the line with '#' would read as a comment: quote it
            buf.write('"' + str(row[0]).replace('"', '""') + '"')
            if len(row) > 1:
                buf.write(",")
                w.writerow(row[1:])
            else:
                buf.write("\n")
        else:
            w.writerow(row)
    return buf.getvalue()


def write_measurements(path: str | os.PathLike[str], meas: Measurements) -> None:
    """Write ``meas`` as CSV v1 (atomically: a half-written file never appears)."""
    write_text_atomic(path, format_measurements(meas))
