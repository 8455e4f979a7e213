"""The archive's names, places and records: what a robot name or run id may be, where the
archive lives by default, and the index's rows as typed records (figures in mm, time in UTC).

Every door (the command line, the TUI, the nightly job) opens the archive at
:func:`default_root` unless told otherwise: ``$QUICKHEALTH_ARCHIVE`` if set, else
``~/quickhealth-archive``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from ...identify.errors import InputError
from ..formats.common import excerpt
from ..provenance import version_number

ENV_VAR = "QUICKHEALTH_ARCHIVE"
#: the main figures, as ``identify.trend.FIGURES`` (a test checks): importing the trend costs
#: scipy.stats, about 2 s, which listing or adding a run does not need
FIGURES: tuple[str, ...] = ("mean", "std", "max")
INDEX_FILE = "index.sqlite"
#: the mark an archived run folder carries: the identity of the index that put it there
MARKER = ".quickhealth-archive.json"
META_KEYS: tuple[str, ...] = ("plan_hash", "cell", "calibration_id", "software_version")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
#: Names Windows keeps for devices (with any extension): a folder of that name cannot be
#: made on a Windows share, or opens the device.
RESERVED_NAMES = frozenset(
    ["con", "prn", "aux", "nul"] + [f"{d}{i}" for d in ("com", "lpt") for i in range(1, 10)]
)


class NoArchive(InputError):
    """No archive at the place named (nothing archived there yet): a reader is refused."""


def safe_name(name: str, what: str) -> str:
    """Check that a robot name or run id is a plain name that stays inside the archive and
    is one folder on every file system.  (Unique ignoring case within one archive and one
    index: :meth:`~.index.Index.check_names`.)

    Raises
    ------
    InputError
        For empty names, path separators, ``..``, characters outside ``[A-Za-z0-9._-]``, a
        trailing ``.`` (Windows drops it) or a name Windows keeps for a device (``CON``,
        ``NUL``, ``COM1`` …, with any extension).
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name) or ".." in name:
        raise InputError(
            f"{what} {excerpt(name)} is not allowed: use letters, digits, '.', '_' and '-' "
            "(at most 100, starting with a letter or digit, no '..')"
        )
    if name.endswith("."):
        raise InputError(
            f"{what} {name!r} is not allowed: it ends with '.', which Windows drops from a "
            "folder name (it would be another name's folder)"
        )
    if name.split(".")[0].lower() in RESERVED_NAMES:
        raise InputError(
            f"{what} {name!r} is not allowed: Windows keeps {name.split('.')[0].upper()} for a "
            "device (CON, PRN, AUX, NUL, COM1-9, LPT1-9, with any extension)"
        )
    return name


def default_root() -> Path:
    """``$QUICKHEALTH_ARCHIVE`` if set, else ``~/quickhealth-archive``."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path.home() / "quickhealth-archive"


@dataclass(frozen=True)
class RunRecord:
    """One archived run as the index holds it (figures in mm, time in UTC)."""

    robot: str
    run_id: str
    time_utc: str  # ISO 8601
    path: str  # relative to the archive root
    plan_hash: str = ""
    cell: str = ""
    calibration_id: str = ""
    software_version: str = ""
    mean_mm: float = math.nan
    std_mm: float = math.nan
    max_mm: float = math.nan
    healthy: bool | None = None
    baseline: bool = False

    @property
    def t_s(self) -> float:
        """Unix time of the run (s)."""
        return parse_time(self.time_utc).timestamp()

    @property
    def figures_mm(self) -> dict[str, float]:
        """``{"mean": …, "std": …, "max": …}`` (mm)."""
        return {"mean": self.mean_mm, "std": self.std_mm, "max": self.max_mm}

    @property
    def meta(self) -> dict[str, str]:
        """Plan hash, cell, calibration id and software version (the version's number only:
        rows written as "quickhealth 0.1.0" and as "0.1.0" name the same version)."""
        out = {k: getattr(self, k) for k in META_KEYS}
        if out.get("software_version"):
            out["software_version"] = version_number(out["software_version"])
        return out


@dataclass(frozen=True)
class CheckRecord:
    """One archived quick check (``quickhealth check``): not an assessment, so it has no
    figures and never becomes a baseline; the trend lists it apart from the runs."""

    robot: str
    check_id: str
    time_utc: str  # ISO 8601
    path: str  # relative to the archive root
    baseline_run_id: str
    verdict: str  # "unchanged" | "changed"
    decided: bool
    poses: int
    robot_time_s: float
    full_loop_robot_time_s: float
    changes: str  # the named changes in words ("" when none)
    plan_hash: str = ""
    root: str = ""  # the archive root (not stored)

    @property
    def t_s(self) -> float:
        """Unix time of the check (s)."""
        return parse_time(self.time_utc).timestamp()


def parse_time(s: str) -> datetime:
    """An ISO 8601 time (``Z`` or an offset; naive means UTC) as an aware UTC datetime.

    Raises
    ------
    InputError
        Not ISO 8601, or outside years 1..9999.
    """
    try:
        t = datetime.fromisoformat(str(s).replace("Z", "+00:00"))
        t = (t if t.tzinfo else t.replace(tzinfo=UTC)).astimezone(UTC)
        t.timestamp()
    except (ValueError, OverflowError, OSError):
        raise InputError(
            f"time {str(s)[:40]!r} is not an ISO 8601 time of years 1..9999 "
            "(e.g. 2026-11-22T10:30:00Z)"
        ) from None
    return t


def iso_utc(t: datetime) -> str:
    """``YYYY-MM-DDTHH:MM:SSZ``, the index's time format."""
    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
