"""What the cameras are: the backend, each camera's identity and settings, the trigger.

One typed :class:`CameraConfig` for every door: the cell file's ``[cameras]`` section
(:func:`from_cell_table`) and the command line's ``--cameras`` (:func:`parse_cameras_option`,
the one parser ``run``, ``check`` and ``tui`` use) give it; :func:`choose` merges them (the
option names the backend and may name the cameras, the cell gives the rest).  Standard
library only: the cell parser and ``--help`` load it without a camera SDK.

``--cameras`` takes ``BACKEND[:LEFT,RIGHT]`` or, as before, ``LEFT,RIGHT`` (OpenCV devices)::

    --cameras pylon                      the cell's cameras, or the first two the SDK finds
    --cameras pylon:40012345,40012346    by serial number (or user id)
    --cameras aravis:Basler-40012345,Basler-40012346
    --cameras opencv:0,1                 device indices or paths (``0,1`` alone: the same)
    --cameras files:RUN_DIR/images       a recorded image folder (offline)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

from ....identify.errors import InputError

BACKENDS = ("pylon", "aravis", "opencv", "files")

#: ``--cameras``' help, the same for every door.
OPTION_HELP = (
    "camera backend and cameras: pylon, aravis, opencv or files, optionally :LEFT,RIGHT "
    "(serial numbers, user ids or devices; files:FOLDER), e.g. pylon:40012345,40012346; "
    "default: the cell file's [cameras] section (--sim: rendered images)"
)


class Trigger(StrEnum):
    """What starts an exposure of both cameras (one event for the pair)."""

    SOFTWARE = "software"  # the station sends one trigger command to each camera, back to back
    LINE = "line"  # the robot's digital output drives both cameras' trigger line
    EXTERNAL = "external"  # a master (strobe controller, a third camera) drives the line
    FREE = "free"  # no trigger: free-running grabs (webcams), paired by time


#: Pixel formats and their bit depth.
PIXEL_BITS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono16": 16}


@dataclass(frozen=True)
class CameraSpec:
    """One camera: who it is and how it is set.

    Attributes
    ----------
    id : str
        Serial number or user id (pylon, aravis), device index or path (opencv); empty: the
        ``index``-th camera the SDK finds.
    index : int
        0 left, 1 right.
    exposure_us : float or None
        Fixed exposure, µs; None: searched at the first pose (:mod:`.exposure`).
    gain_db : float
    """

    id: str = ""
    index: int = 0
    exposure_us: float | None = None
    gain_db: float = 0.0

    @property
    def side(self) -> str:
        return ("left", "right")[self.index]


@dataclass(frozen=True)
class CameraConfig:
    """The stereo pair's backend and settings (see the module docstring).

    Attributes
    ----------
    backend : str
        One of :data:`BACKENDS`.
    left, right : CameraSpec
    pixel_format : str
        ``Mono8`` … ``Mono16`` (:data:`PIXEL_BITS`); the images keep its depth.
    trigger : Trigger
    trigger_line : str
        The cameras' input line (``Line1``) for LINE and EXTERNAL.
    robot_output : int
        The robot's standard digital output wired to that line (LINE).
    pulse_s : float
        The width of the robot's trigger pulse (LINE; controller time, at least two
        controller cycles: 16 ms on a CB3, 4 ms on an e-Series).
    timeout_s : float
        Longest wait for a frame after its trigger.
    max_skew_s : float
        Largest difference between the two cameras' exposure times (camera clocks, or this
        computer's where the camera has none) in one pair.
    attempts : int
        Captures of a pose before the camera fault stops the run.
    folder : str
        The recorded image folder (``files``).
    source : str
        Where the configuration came from, for messages.
    """

    backend: str = "opencv"
    left: CameraSpec = field(default_factory=lambda: CameraSpec("0", 0))
    right: CameraSpec = field(default_factory=lambda: CameraSpec("1", 1))
    pixel_format: str = "Mono8"
    trigger: Trigger = Trigger.SOFTWARE
    trigger_line: str = "Line1"
    robot_output: int = 0
    pulse_s: float = 0.02
    timeout_s: float = 1.0
    max_skew_s: float = 0.001
    attempts: int = 3
    folder: str = ""
    source: str = "default"

    @property
    def bits(self) -> int:
        """Bits per pixel of the images (8 … 16)."""
        return PIXEL_BITS[self.pixel_format]

    @property
    def cameras(self) -> tuple[CameraSpec, CameraSpec]:
        return (self.left, self.right)

    @property
    def ids(self) -> tuple[str, str]:
        return (self.left.id, self.right.id)

    def describe(self) -> str:
        """One line for messages and the journal."""
        if self.backend == "files":
            who = self.folder
        elif any(self.ids):
            who = ",".join(i or "?" for i in self.ids)
        else:
            who = "the first two cameras"
        how = self.trigger.value
        if self.trigger is Trigger.LINE:
            how += f" (robot output {self.robot_output}, {self.pulse_s * 1e3:.0f} ms pulse)"
        return f"{self.backend}:{who} {self.pixel_format}, trigger {how}"


def parse_cameras_option(text: str) -> tuple[str, tuple[str, str] | None]:
    """``--cameras`` as ``(backend, (left, right) or None)``; one line refuses anything else."""
    s = text.strip()
    head, sep, rest = s.partition(":")
    if head in BACKENDS:
        if head == "files":
            if not rest:
                raise InputError("--cameras files:FOLDER: name the recorded image folder")
            return head, (rest, rest)
        if not sep:
            return head, None
        ids = [p.strip() for p in rest.split(",")]
    elif re.fullmatch(r"[a-z]+", head) and not sep and "," not in s:
        raise InputError(f"--cameras {s[:40]!r}: unknown backend (choose {', '.join(BACKENDS)})")
    else:  # LEFT,RIGHT: OpenCV devices, as before backends had names
        head, ids = "opencv", [p.strip() for p in s.split(",")]
    if len(ids) != 2 or not all(ids):
        raise InputError(f"--cameras {s[:40]!r}: needs two cameras, LEFT,RIGHT")
    for i in ids:
        if not re.fullmatch(r"[\w.:/\-@]{1,120}", i):
            raise InputError(f"--cameras: camera id {i[:40]!r} has characters that are not allowed")
    return head, (ids[0], ids[1])


def for_simulation(cell: CameraConfig | None, option: str | None) -> CameraConfig | None:
    """The backend the simulated cell is seen through: None (the rendered pair directly)
    unless the cell or ``--cameras`` names one."""
    return None if cell is None and option is None else choose(cell, option)


def choose(cell: CameraConfig | None, option: str | None) -> CameraConfig:
    """The pair to use: the cell's ``[cameras]`` section, changed by ``--cameras``.

    The option's backend replaces the cell's (the cell's settings stay where the backend is the
    same; another backend starts from the defaults); cameras it names replace the cell's."""
    base = cell or CameraConfig()
    if option is None:
        return base
    backend, ids = parse_cameras_option(option)
    cfg = base if backend == base.backend else CameraConfig(backend=backend)
    cfg = replace(cfg, source="--cameras" if cell is None else f"{cell.source} and --cameras")
    if backend == "files":
        return replace(cfg, folder=ids[0] if ids else "")
    if ids is not None:
        cfg = replace(cfg, left=replace(cfg.left, id=ids[0]), right=replace(cfg.right, id=ids[1]))
    elif backend != "opencv" and cfg is not base:
        cfg = replace(cfg, left=CameraSpec("", 0), right=CameraSpec("", 1))
    return cfg


def from_cell_table(t: Any) -> CameraConfig:
    """The cell file's ``[cameras]`` section (``t``: the cell parser's checked table)."""
    backend = t.text("backend", "opencv")
    if backend not in BACKENDS:
        raise t.err("backend", f"{backend!r}: choose one of {', '.join(BACKENDS)}")
    fmt = t.text("pixel_format", "Mono8")
    if fmt not in PIXEL_BITS:
        raise t.err("pixel_format", f"{fmt!r}: choose one of {', '.join(PIXEL_BITS)}")
    trig = t.text("trigger", Trigger.SOFTWARE.value)
    try:
        trigger = Trigger(trig)
    except ValueError:
        raise t.err(
            "trigger", f"{trig!r}: choose one of {', '.join(x.value for x in Trigger)}"
        ) from None
    if trigger in (Trigger.LINE, Trigger.EXTERNAL) and backend in ("opencv", "files"):
        raise t.err(
            "trigger",
            f"{trig!r} needs cameras with a trigger input (backend pylon or aravis); "
            f"{backend!r} has none: choose trigger = 'software' or 'free'",
        )
    exposure = _exposure(t, "exposure_us", None)
    gain = t.num("gain_db", 0.0, 0.0, 48.0)
    specs = []
    for i, side in enumerate(("left", "right")):
        if t.has(side):
            s = t.sub(side)
            spec = CameraSpec(
                id=s.text("id", "", pattern=r"[\w.:/\-@]{0,120}"),
                index=i,
                exposure_us=_exposure(s, "exposure_us", exposure),
                gain_db=s.num("gain_db", gain, 0.0, 48.0),
            )
            s.done()
        else:
            spec = CameraSpec("" if backend in ("pylon", "aravis") else str(i), i, exposure, gain)
        specs.append(spec)
    cfg = CameraConfig(
        backend=backend,
        left=specs[0],
        right=specs[1],
        pixel_format=fmt,
        trigger=trigger,
        trigger_line=t.text("trigger_line", "Line1", pattern=r"Line[0-9]{1,2}"),
        robot_output=t.integer("robot_output", 0, 0, 7),
        pulse_s=t.num("pulse_ms", 20.0, 4.0, 1000.0) / 1e3,
        timeout_s=t.num("timeout_ms", 1000.0, 1.0, 60_000.0) / 1e3,
        max_skew_s=t.num("max_skew_us", 1000.0, 0.0, 1e6) / 1e6,
        attempts=t.integer("attempts", 3, 1, 20),
        folder=t.text("folder", "", pattern=r"[\w .,:()/+\-]{0,400}"),
        source=f"{t.label} [cameras]",
    )
    t.done()
    return cfg


def _exposure(t: Any, key: str, default: float | None) -> float | None:
    if t.has(key) and t.get(key) == "auto":
        return None
    if not t.has(key):
        return default
    v = t.num(key, default, 1.0, 10_000_000.0)
    return None if v is None or math.isnan(v) else v
