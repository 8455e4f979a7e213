"""What every file format shares: the read limits and the one atomic write.

Every file the station reads is bounded (docs/identify.md, "Limits"): a file over its size
limit, a non-regular file (a FIFO, /dev/zero behind a symlink), a cell over MAX_CELL_CHARS,
more rows than the command handles, or JSON nested deeper than MAX_JSON_DEPTH is refused
with one line (exit 2) before it can cost memory, and so is JSON that would parse into more
than ``MAX_JSON_VALUES`` values (its memory is bounded against the file limit, not only its
size).  Every file a format writes goes through
:func:`write_text_atomic`, i.e. :func:`quickhealth.station.fsio.write_atomic`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import stat as _stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...identify.errors import InputError
from ..fsio import write_atomic

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
MAX_LINE_CHARS = MAX_CELL_CHARS * 64  # one line of a CSV file, comments included (16 384)
MAX_JSON_DEPTH = 32  # model.json and report.json are at most 5 levels deep
#: Most values (numbers, strings, lists, objects) a JSON file may parse into, counted before
#: parsing (commas plus opening brackets: an upper bound).  The largest model the fit can
#: write (order 40 on every motion of a 6-joint arm: a 1 488 x 1 488 covariance, 2.2 M
#: numbers, and 20 000 poses' residuals) stays below it; parsed, 3 M values of the costliest
#: kind (empty objects) take about 0.3 GB, against 1.56 GB for the 20 M empty objects a
#: 57 MiB model.json (inside the 64 MiB limit) once held (docs/identify.md, "Limits").
MAX_JSON_VALUES = 3_000_000
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


def _json_depth_ok(text: str, limit: int = MAX_JSON_DEPTH) -> bool:
    """True when no bracket nesting of ``text`` is deeper than ``limit`` (strings skipped)."""
    # strip string literals, then track the depth over the brackets alone (vectorised; a few
    # bytes per character of the file, not the 12 a step array of every character took)
    stripped = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)
    b = np.frombuffer(stripped.encode("utf-8", "replace"), dtype=np.uint8)
    opens = (b == ord("[")) | (b == ord("{"))
    at = np.flatnonzero(opens | (b == ord("]")) | (b == ord("}")))
    step = np.where(opens[at], 1, -1).astype(np.int32)
    return int(np.cumsum(step, dtype=np.int32).max(initial=0)) <= limit


def json_values_at_most(text: str) -> int:
    """An upper bound of the number of values ``text`` parses into (every value but the first
    follows a comma or opens a bracket; commas inside strings only raise the bound)."""
    return text.count(",") + text.count("[") + text.count("{") + 1


def load_json_limited(path: str | os.PathLike[str], what: str = "json") -> Any:
    """A JSON document within the size and depth limits; every failure is one line."""
    p = Path(path)
    text = read_text_limited(p, what)
    n = json_values_at_most(text)
    if n > MAX_JSON_VALUES:
        raise InputError(
            f"{p}: up to {n:,} JSON values, over the {MAX_JSON_VALUES:,} a {what} file may hold "
            "(the largest model the fit writes has 2.4 M); not parsed"
        )
    if not _json_depth_ok(text):
        raise InputError(f"{p}: JSON nested deeper than {MAX_JSON_DEPTH} levels; not a {what} file")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of 100 000 digits
        raise InputError(f"{p}: not a usable {what} file: {str(exc).splitlines()[0]}") from None


def json_plain(x: Any, *, finite_only: bool = False) -> Any:
    """A JSON-able copy of ``x``: numpy scalars and arrays to Python values, tuples to lists,
    keys to strings; NaN and infinity to ``None``, or ``ValueError`` with ``finite_only`` (the
    journal, whose records must never hold a non-finite number)."""
    if isinstance(x, Mapping):
        return {str(k): json_plain(v, finite_only=finite_only) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_plain(v, finite_only=finite_only) for v in x]
    if isinstance(x, np.ndarray):
        return json_plain(x.tolist(), finite_only=finite_only)
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        if math.isfinite(x):
            return float(x)
        if finite_only:
            raise ValueError(f"a non-finite number ({x}) where only finite ones are allowed")
        return None
    return x


def finite_float(text: str) -> float:
    """argparse type of every float option: a finite number (``nan``, ``inf`` are refused)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


def findings(lines: list[str], kind: type[Exception] = InputError) -> Exception:
    """One error reporting several findings, one line each (each refused target of a
    program): the command line prints ``lines`` as they are, each made one line, so a file
    name holding a newline never splits a finding in two."""
    exc = kind("\n".join(lines))
    exc.findings = list(lines)  # type: ignore[attr-defined]
    return exc


# ------------------------------------------------------------------ text that goes into files

#: Every character ``str.splitlines`` starts a new line at: a value holding one would begin a
#: new line in the file that records it (a forged ``# calibration_id: …`` comment, a CSV row).
LINE_BREAKS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"
_NOT_ONE_LINE = re.compile("[" + re.escape(LINE_BREAKS) + "\x00-\x1f\x7f-\x9f]")


def excerpt(value: object, n: int = 40) -> str:
    """A short prefix of ``value`` for a message, quoted when it is a text (never the whole of
    a hostile value: a calibration's million-element list, an alias bomb's expansion)."""
    s = str(value)
    cut = s[:n] if isinstance(value, str) else s[:n].replace("\n", " ")
    return (repr(cut) if isinstance(value, str) else cut) + ("…" if len(s) > n else "")


def one_line(value: object, what: str) -> str:
    """``value`` as text, refused when it holds a line break (any of :data:`LINE_BREAKS`) or
    another control character.  The one check of every value that goes into a ``# key:
    value`` line, a CSV cell or an index row (the journal's JSON escapes them itself).

    Raises
    ------
    InputError
        One line naming ``what``, a prefix of the value and the character.
    """
    s = str(value)
    m = _NOT_ONE_LINE.search(s)
    if m is not None:
        raise InputError(
            f"{what} {excerpt(s)} holds a line break or control character "
            f"(U+{ord(m.group()):04X} at character {m.start() + 1}): it would start a new line "
            "in the files that record it; not accepted"
        )
    return s


# OWASP "CSV injection": a cell a spreadsheet would run as a formula begins with = + - @, tab
# or CR (after any apostrophes this writer added, or a quote a spreadsheet strips).
_FORMULA = re.compile(r"'*\"?[=+\-@\t\r]")


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")  # as repr(float) writes them


def _number(text: str) -> bool:
    return _NUMBER.fullmatch(text) is not None


def csv_cell(text: str) -> str:
    """``text`` as a spreadsheet must not run it: one apostrophe before a cell that begins
    like a formula (``=HYPERLINK(…)``, ``@SUM(…)``, ``+…``, ``-…``, tab, CR), as OWASP
    recommends; numbers (``-1.5``) stay numbers.  :func:`csv_text` gives the text back
    exactly (a cell that already begins with such apostrophes gains one more)."""
    if text and _FORMULA.match(text) and not _number(text):
        return "'" + text
    return text


def csv_text(cell: str) -> str:
    """The text :func:`csv_cell` neutralised (any other cell unchanged)."""
    if cell.startswith("'") and _FORMULA.match(cell, 1) and not _number(cell[1:]):
        return cell[1:]
    return cell


def meta_value(text: str) -> str:
    """A ``# key: value`` comment's value as the file holds it: each comma-separated piece
    through :func:`csv_cell` (a spreadsheet splits the comment line at its commas)."""
    return ",".join(csv_cell(p) for p in text.split(","))


def meta_text(value: str) -> str:
    """The value :func:`meta_value` wrote."""
    return ",".join(csv_text(p) for p in value.split(","))


_META = re.compile(r"#\s*([^:]+?)\s*:\s*(.*)$")


def read_meta_line(line: str) -> tuple[str, str] | None:
    """``(key, value)`` of a ``# key: value`` comment line as :func:`meta_line` wrote it,
    else None: the one reader of metadata lines (the measurement reader, the archive)."""
    m = _META.match(line.strip())
    return None if m is None else (m.group(1), meta_text(m.group(2).strip()))


def meta_line(key: str, value: object) -> str:
    """One ``# key: value`` metadata line (with its newline), refused when the key or the
    value holds a line break (:func:`one_line`) or the key a colon."""
    k = one_line(key, "metadata key")
    if ":" in k or not k.strip():
        raise InputError(f"metadata key {excerpt(k)}: empty or holds a colon; not written")
    return f"# {k}: {meta_value(one_line(value, f'metadata {k}:'))}\n"


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically, respecting the umask (:func:`..fsio.write_atomic`)."""
    write_atomic(path, text)
