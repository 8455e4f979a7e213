"""The run journal: an append-only, fsynced record of everything a run did, for ``--resume``.

``RUN_DIR/journal.jsonl`` holds one JSON object per line.  Each line carries ``crc``, the
CRC-32 of the line's JSON without that key, and is flushed and ``fsync``-ed before the run
goes on.  Images are written atomically (temporary file, ``fsync``, rename, directory
``fsync``), never half: the ``captured`` record names them and they reach the disk while the
arm moves on; the ``measured`` record follows them.  A capture whose images are not on disk
(a crash in between) counts as not done and the pose is visited again on resume.

Records (``type``, a :class:`~.formats.journal.RecordKind`; their fields, typed in SI and
stored in mm and degrees, are :mod:`quickhealth.station.formats.journal`'s, the one encoder
and decoder):

- ``start``   run id, plan hash, cell, number of poses, software version; ``provenance``
  (quickhealth, Python, numpy, scipy, OpenCV, pinocchio versions) added by :meth:`Journal.append`.
- ``selfcheck`` instrument self-check on the reference board (``phase`` start/end).
- ``captured`` a pose was reached and imaged: index, name, joints, time, pan, image files
  (the last record of an index wins: a pose revisited on resume).
- ``measured`` the 7D measurement of a captured pose, written after its images (``ok``
  false with the reason when the vision library rejected the pair).
- ``failed``  a pose that could not be captured (target not detected after retries …).
- ``stop``    the run stopped cleanly on a fault (reason, what to do).
- ``resume``  a later process continued the run (with that process's ``provenance``).
- ``end``     the run finished.

Reading tolerates exactly one kind of damage, the one a crash or power cut can cause: a
last line cut short.  It is ignored and cut off on resume.  Any other damage (a bad line in
the middle, a checksum mismatch) is refused with the line number: nothing is guessed.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...identify.errors import InputError
from ..formats.common import json_plain
from ..formats.journal import Captured, Failed, Measured, Record, RecordKind, SelfCheck
from ..formats.journal import decode as decode_record
from ..formats.journal import encode as encode_record
from ..fsio import fsync_dir, open_append, write_atomic
from ..provenance import provenance

JOURNAL = "journal.jsonl"
SCHEMA = "quickhealth.journal/1"


def _crc(rec: dict[str, Any]) -> int:
    body = json.dumps(rec, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return zlib.crc32(body.encode("utf-8"))


def write_bytes_atomic(path: Path, data: bytes, *, sync_dir: bool = True) -> None:
    """Write ``data`` to ``path`` through a temporary file, fsync, rename (and dir fsync)."""
    write_atomic(path, data, durable=True, sync_dir=sync_dir, mkdir=False)


@dataclass
class JournalState:
    """What a journal says happened (built by :func:`read_journal`)."""

    start: dict[str, Any] | None = None
    captured: dict[int, Captured] = field(default_factory=dict)
    measured: dict[int, Measured] = field(default_factory=dict)
    failed: dict[int, Failed] = field(default_factory=dict)
    selfchecks: list[SelfCheck] = field(default_factory=list)
    stops: list[dict[str, Any]] = field(default_factory=list)
    resumes: int = 0
    ended: bool = False
    n_records: int = 0
    truncated_tail: bool = False
    valid_bytes: int = 0

    @property
    def done_indices(self) -> set[int]:
        """Poses with a capture or failure record (``run_plan`` also checks the images)."""
        return set(self.captured) | set(self.failed)

    @property
    def unmeasured(self) -> list[int]:
        """Captured poses whose measurement is not recorded yet (re-measure from images)."""
        return sorted(i for i in self.captured if i not in self.measured)

    def next_index(self, n_poses: int) -> int | None:
        """First plan index (1-based) with nothing recorded, None when all are done."""
        done = self.done_indices
        for i in range(1, n_poses + 1):
            if i not in done:
                return i
        return None


def iter_records(path: Path) -> Iterator[tuple[int, dict[str, Any], int]]:
    """(line number, record, byte offset after the line) for every intact line.

    Raises
    ------
    InputError
        A damaged line that is not the last one.
    """
    data = path.read_bytes()
    offset = 0
    lines = data.split(b"\n")
    for k, raw in enumerate(lines):
        last = k == len(lines) - 1
        if last and raw == b"":
            return
        end = offset + len(raw) + (0 if last else 1)
        try:
            if last:  # no newline: the write was cut short
                raise ValueError("unterminated line")
            rec = json.loads(raw.decode("utf-8"))
            if not isinstance(rec, dict) or "crc" not in rec:
                raise ValueError("not a journal record")
            crc = rec.pop("crc")
            if crc != _crc(rec):
                raise ValueError("checksum mismatch")
        except (ValueError, UnicodeDecodeError) as exc:
            if last:
                raise _Truncated(offset) from None
            raise InputError(f"{path}:{k + 1}: damaged journal line ({exc})") from None
        yield k + 1, rec, end
        offset = end


class _Truncated(Exception):
    def __init__(self, offset: int) -> None:
        self.offset = offset


def read_journal(path: Path) -> JournalState:
    """Replay a journal into a :class:`JournalState` (see the module docstring)."""
    st = JournalState()
    line = 0
    try:
        for line, rec, end in iter_records(path):
            st.n_records += 1
            st.valid_bytes = end
            kind = rec.get("type")
            if kind not in _KINDS:
                pass  # a kind of a later version: not this reader's
            elif kind == RecordKind.START:
                if rec.get("schema") != SCHEMA:
                    raise InputError(f"{path}:{line}: not a {SCHEMA} journal")
                st.start = rec
            elif kind == RecordKind.STOP:
                st.stops.append(rec)
            elif kind == RecordKind.RESUME:
                st.resumes += 1
            elif kind == RecordKind.END:
                st.ended = True
            else:
                _add(st, decode_record(rec))
            if st.start is None:
                raise InputError(f"{path}:{line}: journal does not begin with a start record")
    except _Truncated as tr:
        st.truncated_tail = True
        st.valid_bytes = tr.offset
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path}:{line}: malformed journal record ({exc})") from None
    return st


_KINDS = frozenset(k.value for k in RecordKind)


def _add(st: JournalState, r: Record) -> None:
    if isinstance(r, Captured):
        st.captured[r.index] = r
    elif isinstance(r, Measured):
        st.measured[r.index] = r
    elif isinstance(r, Failed):
        st.failed[r.index] = r
    elif isinstance(r, SelfCheck):
        st.selfchecks.append(r)


class Journal:
    """Append-only writer; every :meth:`append` is on disk when it returns."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / JOURNAL
        self._fd = -1

    def open(self, *, truncate_to: int | None = None) -> Journal:
        """Open for appending; ``truncate_to`` cuts a damaged tail off first."""
        new = not self.path.exists()
        self._fd = open_append(self.path)
        if truncate_to is not None and os.fstat(self._fd).st_size > truncate_to:
            os.ftruncate(self._fd, truncate_to)
            os.fsync(self._fd)
        if new:
            fsync_dir(self.path.parent)
        return self

    def append(self, record: Record) -> None:
        """Write one record and fsync it (``start``/``resume`` gain ``provenance``)."""
        rec = encode_record(record)
        if rec.get("type") in (RecordKind.START, RecordKind.RESUME) and "provenance" not in rec:
            rec = {**rec, "provenance": provenance()}
        rec = json_plain(rec, finite_only=True)
        line = dict(rec)
        line["crc"] = _crc(rec)
        data = (
            json.dumps(line, sort_keys=True, separators=(",", ":"), allow_nan=False) + "\n"
        ).encode()
        n = os.write(self._fd, data)
        if n != len(data):  # pragma: no cover - O_APPEND writes of this size are whole
            raise OSError("short journal write")
        os.fsync(self._fd)

    def close(self) -> None:
        """Close the file."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
