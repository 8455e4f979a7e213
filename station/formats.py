"""Files of the identification: measurement CSV v1, model.json, report.json, robot descriptions.

Every unit conversion between the file boundary (mm, degrees) and the library (m, rad)
happens here, once.  Every bad input raises :class:`InputError` with one line
``file:line:column: what`` (line and column 1-based; column = the CSV column).

Robot descriptions (``--robot``)
--------------------------------
- a built-in name: ``ur5``;
- a DH table file ``*.toml`` (format below);
- a URDF file ``*.urdf``, read through pinocchio (revolute joints, any axis).

DH table format (TOML)::

    [robot]
    name = "wam"
    convention = "dh"        # "dh": A_i = Rz(θ_i+o_i) Tz(d_i) Tx(a_i) Rx(α_i)
                             # "mdh" (Craig): A_i = Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i+o_i) Tz(d_i),
                             #   row i holds a_{i-1}, α_{i-1}, d_i
    length_unit = "mm"       # "mm" or "m"
    angle_unit = "deg"       # "deg" or "rad"

    [[joint]]                # one table per joint, base to flange
    name = "j1"
    a = 0.0
    d = 0.0
    alpha = -90.0
    theta_offset = 0.0       # optional
    q_min = -150.0           # optional (default ±360°)
    q_max = 150.0
    mass = 3.7               # optional, kg (all joints or none)
    com = [0.0, -25.6, 1.9]  # optional, length unit, in DH frame i
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quickhealth.identify.errors import InputError
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import RobotModel, from_dh, ur5

from .fsio import write_atomic

F = NDArray[np.float64]

MODEL_SCHEMA = "quickhealth.model/1"
REPORT_SCHEMA = "quickhealth.report/2"  # station/report_json.py; /1 files still read
REPORT_SCHEMAS_READ = ("quickhealth.report/1", REPORT_SCHEMA)
BUILTIN_ROBOTS = {"ur5": ur5}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")

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
)


# --------------------------------------------------------------------------- limits
# Every file the station reads is bounded (docs/identify.md, "Limits"): a file over its size
# limit, a non-regular file (a FIFO, /dev/zero behind a symlink), a cell over MAX_CELL_CHARS,
# more rows than the command handles, or JSON nested deeper than MAX_JSON_DEPTH is refused
# with one line (exit 2) before it can cost memory.

MiB = 1 << 20
MAX_BYTES = {
    "measurements": 256 * MiB,  # ~1 M rows of CSV v1
    "model": 64 * MiB,
    "report": 64 * MiB,
    "program": 16 * MiB,
    "robot": 4 * MiB,
    "json": 64 * MiB,
}
MAX_ROWS = 1_000_000  # predict / compensate: streamed through vectorised code
MAX_FIT_ROWS = 20_000  # fit, diagnose, compare: the order search is O(rows x fits)
MAX_CELL_CHARS = 256  # one CSV cell (a pose_id, a number)
MAX_JSON_DEPTH = 32  # model.json and report.json are at most 5 levels deep
MIN_DISTINCT_POSES = 8  # fewer different joint configurations cannot support any model
MIN_JOINT_SPAN_DEG = 1.0  # a joint that moves less than this cannot be identified


def read_text_limited(path: str | os.PathLike[str], what: str = "json") -> str:
    """A UTF-8 text file, refused (one line) when it is missing, not a regular file, larger
    than ``MAX_BYTES[what]`` or not UTF-8 text."""
    p = Path(path)
    limit = MAX_BYTES.get(what, MAX_BYTES["json"])
    try:
        st = p.stat()
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror}") from None
    import stat as _stat

    if _stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: is a directory, expected a {what} file")
    if not _stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: not a regular file (a device or a pipe); refusing to read it")
    if st.st_size > limit:
        raise InputError(
            f"{p}: {st.st_size / MiB:.1f} MiB is over the {limit // MiB} MiB limit of a {what} file"
        )
    try:
        with open(p, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror}") from None
    if len(data) > limit:
        raise InputError(f"{p}: over the {limit // MiB} MiB limit of a {what} file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{p}: not UTF-8 text (binary content at byte {exc.start}); expected a {what} file"
        ) from None


_read_text_limited = read_text_limited


def _json_depth_ok(text: str, limit: int = MAX_JSON_DEPTH) -> bool:
    """True when no bracket nesting of ``text`` is deeper than ``limit`` (strings skipped)."""
    # strip string literals, then track the depth with cumulative sums (vectorised)
    stripped = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)
    b = np.frombuffer(stripped.encode("utf-8", "replace"), dtype=np.uint8)
    step = np.zeros(b.size, dtype=np.int32)
    step[(b == ord("[")) | (b == ord("{"))] = 1
    step[(b == ord("]")) | (b == ord("}"))] = -1
    return b.size == 0 or int(np.cumsum(step).max(initial=0)) <= limit


def load_json_limited(path: str | os.PathLike[str], what: str = "json") -> Any:
    """A JSON document within the size and depth limits; every failure is one line."""
    p = Path(path)
    text = read_text_limited(p, what)
    if not _json_depth_ok(text):
        raise InputError(f"{p}: JSON nested deeper than {MAX_JSON_DEPTH} levels; not a {what} file")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of 100 000 digits
        raise InputError(f"{p}: not a usable {what} file: {str(exc).splitlines()[0]}") from None


def finite_float(text: str) -> float:
    """argparse type of every float option: a finite number (``nan``, ``inf`` are refused)."""
    import argparse

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


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


def check_poses_for_fit(meas: Measurements, robot: RobotModel, name: str) -> None:
    """Meaning of a measurement set before a fit: rows, joint limits, distinct poses, spans.

    Raises
    ------
    InputError
        More than ``MAX_FIT_ROWS`` rows, a joint outside the robot's limits, fewer than
        ``MIN_DISTINCT_POSES`` different joint configurations, or a joint that does not move
        (its error motions cannot be identified: named).
    """
    if meas.n_poses > MAX_FIT_ROWS:
        raise InputError(
            f"{name}: {meas.n_poses} rows is over the fit's limit of {MAX_FIT_ROWS} (the order "
            "search costs rows x fits; the NIST loop has 150 poses): fit a subset"
        )
    check_joint_limits(meas.q, robot, name)
    distinct = np.unique(np.round(meas.q, 6), axis=0).shape[0]
    if distinct < MIN_DISTINCT_POSES and distinct < meas.n_poses:  # (few rows: the fit says)
        raise InputError(
            f"{name}: only {distinct} distinct joint configuration(s) in {meas.n_poses} rows; "
            f"a fit needs at least {MIN_DISTINCT_POSES}"
        )
    span = np.degrees(np.ptp(meas.q, axis=0))
    still = [j + 1 for j in range(meas.n_joints) if span[j] < MIN_JOINT_SPAN_DEG]
    if still:
        raise InputError(
            f"{name}: joint(s) {', '.join(map(str, still))} move less than "
            f"{MIN_JOINT_SPAN_DEG} deg over the data: their error motions cannot be identified; "
            "measure with every joint moving"
        )


# --------------------------------------------------------------------------- CSV v1


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
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = re.match(r"#\s*([^:]+?)\s*:\s*(.*)$", s)
            if m:
                meta[m.group(1)] = m.group(2).strip()
            continue
        if len(line) > MAX_CELL_CHARS * 64:
            raise InputError(f"{name}:{lineno}:1: line of {len(line)} characters is too long")
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
    for group in (("pitch", "yaw", "roll"), ("sx", "sy", "sz"), ("spitch", "syaw", "sroll")):
        present = [g for g in group if g in col]
        if present and len(present) != 3:
            missing = [g for g in group if g not in col]
            raise InputError(
                f"{name}:{header_line}:{col[present[0]] + 1}: column {present[0]!r} needs "
                f"{', '.join(repr(m) for m in missing)} too"
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
    rpy = None
    if "pitch" in col:
        looks_like_radians(("pitch", "yaw", "roll"), "orientation angles", 1.0)
        rpy = np.radians(np.stack([numbers(c) for c in ("pitch", "yaw", "roll")], axis=1))
    sig_pos = (
        np.stack([numbers(c, True) for c in ("sx", "sy", "sz")], axis=1) * 1e-3
        if "sx" in col
        else None
    )
    sig_rpy = (
        np.radians(np.stack([numbers(c, True) for c in ("spitch", "syaw", "sroll")], axis=1))
        if "spitch" in col
        else None
    )
    if sig_rpy is not None and rpy is None:
        raise InputError(
            f"{name}:{header_line}:{col['spitch'] + 1}: angle uncertainties without angle columns"
        )
    pose_id = tuple(cells[col["pose_id"]] for _, cells in rows) if "pose_id" in col else None
    return Measurements(
        q=q,
        pos=pos,
        rpy=rpy,
        time=numbers("time") if "time" in col else None,
        temp=numbers("temp") if "temp" in col else None,
        pan=np.radians(numbers("pan")) if "pan" in col else None,
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
        a pose id with a control character (a newline would split the row).
    """
    if not np.all(np.isfinite(meas.q)):
        i = int(np.argwhere(~np.isfinite(meas.q))[0][0])
        raise InputError(f"measurement row {i + 1}: joint angles are not finite; not written")
    if meas.pose_id is not None:
        for i, pid in enumerate(meas.pose_id):
            if any(c < " " or c == "\x7f" for c in str(pid)) or len(str(pid)) > MAX_CELL_CHARS:
                raise InputError(
                    f"measurement row {i + 1}: pose_id {str(pid)[:40]!r} has a control character "
                    "or is too long; not written"
                )
    buf = io.StringIO()
    for k, v in meas.meta.items():
        buf.write(f"# {k}: {v}\n")
    cols: list[tuple[str, F | tuple[str, ...]]] = []
    if meas.pose_id is not None:
        cols.append(("pose_id", meas.pose_id))
    for i in range(meas.n_joints):
        cols.append((f"q{i + 1}", np.degrees(meas.q[:, i])))
    if not np.all(np.isnan(meas.pos)):
        for i, c in enumerate("xyz"):
            cols.append((c, meas.pos[:, i] * 1e3))
    if meas.rpy is not None:
        for i, c in enumerate(("pitch", "yaw", "roll")):
            cols.append((c, np.degrees(meas.rpy[:, i])))
    for c in ("time", "temp"):
        v = getattr(meas, c)
        if v is not None:
            cols.append((c, v))
    if meas.pan is not None:
        cols.append(("pan", np.degrees(meas.pan)))
    if meas.sigma_pos is not None:
        for i, c in enumerate(("sx", "sy", "sz")):
            cols.append((c, meas.sigma_pos[:, i] * 1e3))
    if meas.sigma_rpy is not None:
        for i, c in enumerate(("spitch", "syaw", "sroll")):
            cols.append((c, np.degrees(meas.sigma_rpy[:, i])))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([c for c, _ in cols])
    for r in range(meas.n_poses):
        w.writerow([v[r] if isinstance(v, tuple) else repr(float(v[r])) for _, v in cols])
    return buf.getvalue()


def write_measurements(path: str | os.PathLike[str], meas: Measurements) -> None:
    """Write ``meas`` as CSV v1 (atomically: a half-written file never appears)."""
    write_text_atomic(path, format_measurements(meas))


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically, respecting the umask (:func:`..fsio.write_atomic`)."""
    write_atomic(path, text)


# --------------------------------------------------------------------------- robot descriptions


def load_robot(spec: str) -> RobotModel:
    """A robot from a built-in name (``ur5``) or a description file path (``.toml``, ``.urdf``).

    A bare name (no path separator, no file suffix) is only looked up among the built-ins,
    so a name can never reach outside them (``../x`` is a path, never a name).
    """
    s = spec.strip()
    is_path = ("/" in s) or ("\\" in s) or s.lower().endswith((".toml", ".urdf"))
    if not is_path:
        if s.lower() in BUILTIN_ROBOTS and _NAME.fullmatch(s):
            return BUILTIN_ROBOTS[s.lower()]()
        raise InputError(
            f"unknown robot {spec!r}: built-in robots are {', '.join(BUILTIN_ROBOTS)}; "
            "or give a path to a .toml DH table or a .urdf file"
        )
    p = Path(s)
    if not p.is_file():
        raise InputError(f"{p}: robot description file not found")
    if p.suffix.lower() == ".toml":
        return read_dh_toml(p)
    if p.suffix.lower() == ".urdf":
        return read_urdf(p)
    raise InputError(f"{p}: unknown robot description format (use .toml or .urdf)")


def read_dh_toml(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a DH table in TOML (format in the module docstring)."""
    p = Path(path)
    try:
        doc = tomllib.loads(read_text_limited(p, "robot"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML: {exc}") from None
    try:
        robot = _dh_from_doc(p, doc)
    except (TypeError, ValueError, AttributeError, KeyError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{p}: not a DH table: {' '.join(str(exc).split())}") from None
    _check_robot(robot, str(p))
    return robot


def _check_robot(robot: RobotModel, name: str) -> None:
    """Finite link transforms and limits, sane sizes (a robot under 20 m, limits within ±4 turns)."""
    links = np.asarray(robot.links, float)
    if not np.all(np.isfinite(links)) or not np.all(np.isfinite(robot.q_offset)):
        raise InputError(f"{name}: the robot's link transforms are not all finite numbers")
    if np.abs(links[:, :3, 3]).max(initial=0.0) > 20.0:
        raise InputError(f"{name}: a link is longer than 20 m; check length_unit")
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise InputError(f"{name}: joint limits are not all finite numbers")
    if np.any(hi <= lo) or np.abs(np.concatenate([lo, hi])).max() > 8 * math.pi + 1e-9:
        raise InputError(f"{name}: joint limits must satisfy q_min < q_max within ±1440 deg")


def _dh_from_doc(p: Path, doc: dict[str, Any]) -> RobotModel:
    head = doc.get("robot", {})
    if not isinstance(head, dict):
        raise InputError(f"{p}: [robot] must be a table")
    joints = doc.get("joint")
    if not isinstance(joints, list) or not joints:
        raise InputError(f"{p}: no [[joint]] tables")
    if not all(isinstance(j, dict) for j in joints):
        raise InputError(f"{p}: every joint must be a [[joint]] table")
    conv = head.get("convention", "dh")
    if conv not in ("dh", "mdh"):
        raise InputError(f"{p}: [robot] convention must be 'dh' or 'mdh', got {conv!r}")
    lu = {"mm": 1e-3, "m": 1.0}.get(head.get("length_unit", "m"))
    au = {"deg": math.pi / 180, "rad": 1.0}.get(head.get("angle_unit", "deg"))
    if lu is None or au is None:
        raise InputError(f"{p}: length_unit must be 'mm' or 'm', angle_unit 'deg' or 'rad'")

    def get(i: int, key: str, default: float | None = None) -> float:
        v = joints[i].get(key, default)
        if v is None:
            raise InputError(f"{p}: joint {i + 1} has no {key!r}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"{p}: joint {i + 1}: {key} = {v!r} is not a number")
        return float(v)

    n = len(joints)
    a = [get(i, "a") * lu for i in range(n)]
    d = [get(i, "d") * lu for i in range(n)]
    alpha = [get(i, "alpha") * au for i in range(n)]
    off = [get(i, "theta_offset", 0.0) * au for i in range(n)]
    lo = [get(i, "q_min", -2 * math.pi / au) * au for i in range(n)]
    hi = [get(i, "q_max", 2 * math.pi / au) * au for i in range(n)]
    has_mass = ["mass" in j for j in joints]
    masses = coms = None
    if any(has_mass):
        if not all(has_mass) or not all("com" in j for j in joints):
            raise InputError(f"{p}: give mass and com for every joint or for none")
        masses = [get(i, "mass") for i in range(n)]
        coms = []
        for i, j in enumerate(joints):
            c = j["com"]
            if not (
                isinstance(c, list)
                and len(c) == 3
                and all(isinstance(x, int | float) and not isinstance(x, bool) for x in c)
            ):
                raise InputError(f"{p}: joint {i + 1}: com must be a list of 3 numbers")
            coms.append([float(x) * lu for x in c])
    names = tuple(str(j.get("name", f"j{i + 1}")) for i, j in enumerate(joints))
    if any(h <= l for l, h in zip(lo, hi, strict=True)):
        raise InputError(f"{p}: every joint needs q_max > q_min")
    return from_dh(
        str(head.get("name", p.stem)),
        a,
        d,
        alpha,
        theta_offset=off,
        q_min=lo,
        q_max=hi,
        masses=masses,
        coms=coms,
        modified=conv == "mdh",
        joint_names=names,
    )


def read_urdf(path: str | os.PathLike[str]) -> RobotModel:
    """Robot from a URDF file through pinocchio (serial chain of revolute joints).

    Each joint's axis ``a`` is turned onto z: the joint placement is followed by a constant
    rotation ``R_a`` with ``R_a ẑ = a`` so the joint is ``Rz(θ)`` as the error model expects.
    The flange is the last joint's frame.
    """
    import pinocchio as pin

    p = Path(path)
    read_text_limited(p, "robot")  # size, regular file, UTF-8 before pinocchio sees it
    try:
        model = pin.buildModelFromUrdf(str(p))
    except (ValueError, RuntimeError) as exc:
        raise InputError(f"{p}: pinocchio cannot read this URDF: {exc}") from None
    nj = model.njoints - 1
    if nj < 1 or model.nq != nj:
        raise InputError(
            f"{p}: needs a chain of 1-dof revolute joints (nq={model.nq}, joints={nj})"
        )
    links = np.tile(np.eye(4), (nj + 1, 1, 1))
    Ra_prev = np.eye(3)
    masses, coms = [], []
    for i in range(1, nj + 1):
        jm = model.joints[i]
        short = jm.shortname()
        if model.parents[i] != i - 1:
            raise InputError(f"{p}: joint {model.names[i]!r} does not continue a serial chain")
        if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            axis = {
                "JointModelRX": [1, 0, 0],
                "JointModelRY": [0, 1, 0],
                "JointModelRZ": [0, 0, 1],
            }[short]
        elif short == "JointModelRevoluteUnaligned":
            axis = np.asarray(jm.extract().axis, float)
        else:
            raise InputError(
                f"{p}: joint {model.names[i]!r} is {short}; only revolute joints are supported"
            )
        Ra = _rot_z_onto(np.asarray(axis, float))
        M = model.jointPlacements[i].homogeneous
        prev = np.eye(4)
        prev[:3, :3] = Ra_prev.T
        Rah = np.eye(4)
        Rah[:3, :3] = Ra
        links[i - 1] = prev @ M @ Rah if i > 1 else M @ Rah
        Ra_prev = Ra
        inert = model.inertias[i]
        masses.append(float(inert.mass))
        coms.append(np.asarray(inert.lever, float))
    last = np.eye(4)
    last[:3, :3] = Ra_prev.T
    links[nj] = last
    com_arr = np.empty((nj, 3))
    for i in range(nj):
        # com in the frame after Rz(θ_i)·C_i: C_i⁻¹ · (R_aᵀ c)
        Ra_i = _rot_z_onto(_axis_of(model, i + 1))
        c = Ra_i.T @ coms[i]
        Ci = links[i + 1]
        com_arr[i] = Ci[:3, :3].T @ (c - Ci[:3, 3])
    has_inertia = sum(masses) > 0
    lo = np.asarray(model.lowerPositionLimit, float)
    hi = np.asarray(model.upperPositionLimit, float)
    bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo)
    lo = np.where(bad, -2 * np.pi, lo)
    hi = np.where(bad, 2 * np.pi, hi)
    return RobotModel(
        name=p.stem,
        links=links,
        q_offset=np.zeros(nj),
        q_min=lo,
        q_max=hi,
        masses=np.array(masses) if has_inertia else None,
        coms=com_arr if has_inertia else None,
        joint_names=tuple(model.names[1:]),
        convention="urdf",
    )


def _axis_of(model: Any, i: int) -> F:
    short = model.joints[i].shortname()
    table = {"JointModelRX": [1, 0, 0], "JointModelRY": [0, 1, 0], "JointModelRZ": [0, 0, 1]}
    if short in table:
        return np.array(table[short], float)
    return np.asarray(model.joints[i].extract().axis, float)


def _rot_z_onto(a: F) -> F:
    """A rotation R with ``R ẑ = a / |a|`` (identity for a = ẑ)."""
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, a)
    s, c = np.linalg.norm(v), float(z @ a)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K * ((1 - c) / s**2)


def robot_to_json(robot: RobotModel) -> dict[str, Any]:
    """The robot embedded in model.json (so a model file predicts on its own)."""
    return {
        "name": robot.name,
        "convention": robot.convention,
        "links": robot.links.tolist(),
        "q_offset": robot.q_offset.tolist(),
        "q_min": robot.q_min.tolist(),
        "q_max": robot.q_max.tolist(),
        "masses": None if robot.masses is None else robot.masses.tolist(),
        "coms": None if robot.coms is None else robot.coms.tolist(),
        "joint_names": list(robot.joint_names),
        "dh": robot.dh,
    }


def _shaped(d: dict[str, Any], key: str, shape: tuple[int, ...], optional: bool = False) -> Any:
    """``d[key]`` as a float array of ``shape`` (-1: any length), or InputError."""
    v = d.get(key)
    if v is None and optional:
        return None
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"robot.{key} is not an array of numbers") from None
    if a.ndim != len(shape) or any(n not in (-1, m) for n, m in zip(shape, a.shape, strict=True)):
        raise InputError(f"robot.{key} has shape {a.shape}, expected {shape}")
    return a


def robot_from_json(d: dict[str, Any]) -> RobotModel:
    """Inverse of :func:`robot_to_json` (shapes checked: InputError without a file name)."""
    if not isinstance(d, dict):
        raise InputError("robot is not a JSON object")
    q_offset = _shaped(d, "q_offset", (-1,))
    nj = q_offset.shape[0]
    if not 1 <= nj <= 12:
        raise InputError(f"robot has {nj} joints (1..12 expected)")
    links = _shaped(d, "links", (nj + 1, 4, 4))
    q_min = _shaped(d, "q_min", (nj,))
    q_max = _shaped(d, "q_max", (nj,))
    masses = _shaped(d, "masses", (nj,), optional=True)
    coms = _shaped(d, "coms", (nj, 3), optional=True)
    names = d.get("joint_names", ())
    if not isinstance(names, list | tuple) or len(names) not in (0, nj):
        raise InputError(f"robot.joint_names must list {nj} names")
    return RobotModel(
        name=str(d["name"]),
        links=links,
        q_offset=q_offset,
        q_min=q_min,
        q_max=q_max,
        masses=masses,
        coms=coms,
        joint_names=tuple(str(n) for n in names),
        dh=d.get("dh") if isinstance(d.get("dh"), dict) else None,
        convention=str(d.get("convention", "generic")),
    )


# --------------------------------------------------------------------------- model.json


def model_to_json(fitted: Any) -> dict[str, Any]:
    """JSON document of a :class:`~quickhealth.identify.fit.FittedModel` (schema-versioned)."""
    spec = fitted.spec
    return {
        "schema": MODEL_SCHEMA,
        "units": "SI (m, rad); coefficients of the Chebyshev series of each error motion",
        "robot": robot_to_json(fitted.robot),
        "spec": {
            "orders": spec.orders.tolist(),
            "q_lo": spec.q_lo.tolist(),
            "q_hi": spec.q_hi.tolist(),
        },
        "labels": fitted.labels,
        "coeffs": fitted.coeffs.tolist(),
        "effects": [
            {
                "name": e.name,
                "params": np.asarray(p, float).tolist(),
                "param_names": list(e.param_names),
                **(e.info() if hasattr(e, "info") else {}),
            }
            for e, p in zip(fitted.effects, fitted.effect_params, strict=True)
        ],
        "cov": fitted.cov.tolist(),
        "T_instr_base0": np.asarray(fitted.T_instr_base0).tolist(),
        "T_flange_target0": np.asarray(fitted.T_flange_target0).tolist(),
        "residual_pos": fitted.residual_pos.tolist(),
        "residual_rot": None if fitted.residual_rot is None else fitted.residual_rot.tolist(),
        "stats": {
            "chi2": fitted.chi2,
            "chi2_data": fitted.chi2_data,
            "dof": fitted.dof,
            "bic": fitted.bic,
            "rms_pos": fitted.rms_pos,
            "rms_rot": fitted.rms_rot,
            "n_iter": fitted.n_iter,
            "converged": fitted.converged,
            "n_poses": fitted.n_poses,
        },
        "unidentifiable": list(fitted.unidentifiable),
        "held": list(fitted.held),
        "reference_time_s": getattr(fitted, "reference_time", None),
        "noise": {
            "sigma_pos": fitted.noise.sigma_pos,
            "sigma_rot": fitted.noise.sigma_rot,
            "sigma_q": fitted.noise.sigma_q,
        },
        "prior": {
            "joint_pos": fitted.prior.joint_pos,
            "joint_rot": fitted.prior.joint_rot,
            "setup_pos": fitted.prior.setup_pos,
            "setup_rot": fitted.prior.setup_rot,
        },
    }


def model_from_json(doc: dict[str, Any], name: str = "model.json") -> Any:
    """A :class:`~quickhealth.identify.fit.FittedModel` from its JSON document."""
    from quickhealth.identify.effects import parse_effects
    from quickhealth.identify.errormodel import ErrorModelSpec
    from quickhealth.identify.fit import FittedModel, InstrumentNoise, ParameterPrior

    if not isinstance(doc, dict) or doc.get("schema") != MODEL_SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(
            f"{name}: not a quickhealth model (schema {got!r}, expected {MODEL_SCHEMA!r})"
        )
    try:
        try:
            robot = robot_from_json(doc["robot"])
        except InputError as exc:
            raise InputError(f"{name}: model file is incomplete or damaged: {exc}") from None
        sp = doc["spec"]
        spec = ErrorModelSpec(np.asarray(sp["orders"], np.int64), sp["q_lo"], sp["q_hi"])
        effects = parse_effects([e["name"] for e in doc["effects"]], robot)
        st = doc["stats"]
        rr = doc.get("residual_rot")
        return FittedModel(
            robot=robot,
            spec=spec,
            coeffs=np.asarray(doc["coeffs"], float),
            cov=np.asarray(doc["cov"], float),
            effects=tuple(effects),
            effect_params=[np.asarray(e["params"], float) for e in doc["effects"]],
            T_instr_base0=np.asarray(doc["T_instr_base0"], float),
            T_flange_target0=np.asarray(doc["T_flange_target0"], float),
            residual_pos=np.asarray(doc["residual_pos"], float).reshape(-1, 3),
            residual_rot=None if rr is None else np.asarray(rr, float).reshape(-1, 3),
            chi2=float(st["chi2"]),
            chi2_data=float(st["chi2_data"]),
            dof=int(st["dof"]),
            bic=float(st["bic"]),
            rms_pos=float(st["rms_pos"]),
            rms_rot=None if st["rms_rot"] is None else float(st["rms_rot"]),
            n_iter=int(st["n_iter"]),
            converged=bool(st["converged"]),
            unidentifiable=tuple(doc["unidentifiable"]),
            noise=InstrumentNoise(**doc["noise"]),
            prior=ParameterPrior(**doc["prior"]),
            n_poses=int(st["n_poses"]),
            held=tuple(doc.get("held", ())),
            reference_time=(
                None if doc.get("reference_time_s") is None else float(doc["reference_time_s"])
            ),
        )
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        if isinstance(exc, InputError):
            raise
        what = " ".join(repr(exc).split())[:200]
        raise InputError(f"{name}: model file is incomplete or damaged: {what}") from None


# largest believable Chebyshev coefficient of a joint error motion: 20 mm, 0.05 rad (2.9 deg).
# A UR5's identified errors are tens of µm and µrad; anything near these is a broken model.
MAX_COEFF_M = 0.02
MAX_COEFF_RAD = 0.05


def check_model(fm: Any, name: str) -> None:
    """Meaning of a model: coefficient count, finite numbers, sane magnitudes and ranges.

    Raises
    ------
    InputError
        One line naming the first offending entry.
    """
    spec = fm.spec
    robot = fm.robot
    _check_robot(robot, name)
    nj = robot.n_joints
    if spec.orders.shape[0] < nj:
        raise InputError(
            f"{name}: the error model has orders for {spec.orders.shape[0]} joints, the robot has {nj}"
        )
    if np.any(spec.orders < 0) or np.any(spec.orders > 40):
        raise InputError(f"{name}: Chebyshev orders must be in 0..40")
    c = np.asarray(fm.coeffs, float)
    if c.ndim != 1 or c.size != spec.n_params:
        raise InputError(
            f"{name}: {c.size} coefficients, but the orders need {spec.n_params}: damaged model"
        )
    labels = spec.labels()
    bad = np.flatnonzero(~np.isfinite(c))
    if bad.size:
        raise InputError(
            f"{name}: coefficient {labels[bad[0]]} is {c[bad[0]]}, not a finite number"
        )
    is_len = spec.index()[:, 1] < 3
    cap = np.where(is_len, MAX_COEFF_M, MAX_COEFF_RAD)
    big = np.flatnonzero(np.abs(c) > cap)
    if big.size:
        k = int(big[np.argmax(np.abs(c[big]) / cap[big])])
        unit, scale = ("mm", 1e3) if is_len[k] else ("mrad", 1e3)
        raise InputError(
            f"{name}: coefficient {labels[k]} = {c[k] * scale:.6g} {unit} is beyond any real "
            f"robot (limit {cap[k] * scale:.0f} {unit}): refusing the model"
        )
    if not (np.all(np.isfinite(spec.q_lo)) and np.all(np.isfinite(spec.q_hi))):
        raise InputError(f"{name}: the model's joint ranges are not finite numbers")
    if (
        np.any(spec.q_hi <= spec.q_lo)
        or np.any(spec.q_lo < robot.q_min - 1e-6)
        or np.any(spec.q_hi > robot.q_max + 1e-6)
    ):
        raise InputError(
            f"{name}: the model's identified joint ranges are empty or outside the robot's limits"
        )
    cov = np.asarray(fm.cov, float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] < c.size:
        raise InputError(
            f"{name}: the covariance has shape {cov.shape}, expected square >= {c.size}"
        )
    if not np.all(np.isfinite(cov)):
        raise InputError(f"{name}: the covariance holds numbers that are not finite")
    for e, prm in zip(fm.effects, fm.effect_params, strict=True):
        if not np.all(np.isfinite(prm)):
            raise InputError(f"{name}: effect {e.name} has parameters that are not finite")
    for key in ("T_instr_base0", "T_flange_target0"):
        T = np.asarray(getattr(fm, key), float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"{name}: {key} is not a finite 4x4 transform")


def write_model(path: str | os.PathLike[str], fitted: Any) -> None:
    """Write model.json (JSON only; never pickle), with the writer's ``provenance``."""
    from .provenance import provenance

    doc = {**model_to_json(fitted), "provenance": provenance()}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def read_model(path: str | os.PathLike[str]) -> Any:
    """Read model.json back into a FittedModel."""
    p = Path(path)
    # binary files (e.g. a pickle) are refused as not UTF-8: never loaded as code
    doc = load_json_limited(p, "model")
    try:
        fm = model_from_json(doc, str(p))
        check_model(fm, str(p))
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(str(p)) else f"{p}: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - any other failure to interpret it: damaged
        what = " ".join(repr(exc).split())[:200]
        raise InputError(f"{p}: model file is incomplete or damaged: {what}") from None
    return fm


# --------------------------------------------------------------------------- report.json


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def write_report(path: str | os.PathLike[str], report: dict[str, Any]) -> None:
    """Write report.json (``schema`` and this writer's ``provenance`` set; NaN/inf become null)."""
    from .provenance import provenance

    doc = {"schema": REPORT_SCHEMA, **_jsonable(report), "provenance": provenance()}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def read_report(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read report.json."""
    p = Path(path)
    doc = load_json_limited(p, "report")
    if not isinstance(doc, dict) or doc.get("schema") not in REPORT_SCHEMAS_READ:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(f"{p}: not a quickhealth report (schema {got!r})")
    return doc


REPORT_REQUIRED = ("n_poses", "rms_pos_mm", "chi2", "bic")
REPORT_FIGURES = ("mean_mm", "std_mm", "max_mm")


def check_report(doc: Any, name: str) -> None:
    """A report.json fit for the archive and the trend: the fit's figures are all there.

    Raises
    ------
    InputError
        The first missing or non-finite figure (``workspace.mean_mm`` …, ``n_poses`` …).
    """
    if not isinstance(doc, dict):
        raise InputError(f"{name}: not a quickhealth report (a JSON object is expected)")
    ws = doc.get("workspace")
    for key in REPORT_FIGURES:
        v = ws.get(key) if isinstance(ws, dict) else doc.get(f"workspace_{key}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
            raise InputError(
                f"{name}: workspace.{key} is {'missing' if v is None else repr(v)}: "
                "not a complete fit report (run quickhealth identify fit)"
            )
    for key in REPORT_REQUIRED:
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(
                f"{name}: {key} is {'missing' if v is None else repr(v)}: not a complete fit "
                "report (run quickhealth identify fit)"
            )


# --------------------------------------------------------------------------- URScript


def read_urscript(path: str | os.PathLike[str], n_joints: int) -> tuple[str, Any]:
    """A URScript program's text and its joint targets (:mod:`quickhealth.identify.urscript`).

    The one reader of programs for ``predict`` and ``compensate``.  Every move whose target
    cannot be read (a variable, a pose literal ``p[...]``, an expression, a wrong length) is
    refused, one line per target (``file:line:column: what``): nothing is guessed.

    Raises
    ------
    InputError
        Missing or binary file, a program that does not tokenize, unreadable targets, no
        target at all.
    """
    from quickhealth.identify.urscript import joint_targets

    p = Path(path)
    text = _read_text_limited(p, "program")
    if "\x00" in text:
        raise InputError(f"{p}: not a URScript program (binary content)")
    try:
        t = joint_targets(text, n_joints)
    except InputError as exc:
        raise InputError(f"{p}:{exc}") from None
    if t.unreadable:
        raise InputError(
            "\n".join(f"{p}:{line}:{col}: {cmd} {why}" for line, col, cmd, why in t.unreadable)
        )
    if not len(t.q):
        raise InputError(f"{p}:1:1: no movej/movel with a joint target found")
    return text, t


def read_urscript_joints(path: str | os.PathLike[str], n_joints: int) -> tuple[F, list[int]]:
    """Joint targets (rad, shape (n, n_joints)) and their 1-based lines (:func:`read_urscript`)."""
    _, t = read_urscript(path, n_joints)
    return t.q, list(t.lines)


# --------------------------------------------------------------------------- WAM data set


def read_wam_csv(path: str | os.PathLike[str], sign: float) -> Measurements:
    """The Barrett WAM laser-tracker files (step_order, x_t…, x_dif…, joint_1…7) as Measurements.

    Position = desired + ``sign`` · difference (mm → m); joints deg → rad.
    """
    p = Path(path)
    try:
        rows = list(csv.reader(p.read_text(encoding="utf-8").splitlines()))
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    head = rows[0]
    need = ["x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 8)]
    for c in need:
        if c not in head:
            raise InputError(f"{p}:1:{len(head) + 1}: missing WAM column {c!r}")
    ix = {c: head.index(c) for c in need}
    data = []
    for lineno, r in enumerate(rows[1:], start=2):
        if not r:
            continue
        try:
            data.append([float(r[ix[c]]) for c in need])
        except (ValueError, IndexError):
            raise InputError(f"{p}:{lineno}:1: row is not numeric") from None
    a = np.array(data)
    pos = (a[:, 0:3] + sign * a[:, 3:6]) * 1e-3
    q = np.radians(a[:, 6:13])
    return Measurements(
        q=q, pos=pos, meta={"source": p.name, "instrument": "GTS3800 laser tracker"}
    )
