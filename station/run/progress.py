"""What a run tells while it goes: :class:`Progress` events for progress bars and the TUI."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum


class ProgressKind(StrEnum):
    """What a :class:`Progress` event is about (the value is what ``quickhealth run`` prints)."""

    PREFLIGHT = "preflight"
    SELFCHECK = "selfcheck"
    RESUME = "resume"
    MOVE = "move"
    POSE = "pose"
    MEASURED = "measured"
    STOP = "stop"
    DONE = "done"


@dataclass(frozen=True)
class Progress:
    """What the run is doing, for progress bars and the TUI.

    ``kind``: a :class:`ProgressKind`.  ``index`` is the 1-based plan index (0 when not about
    a pose).
    """

    kind: ProgressKind
    index: int
    n_poses: int
    name: str = ""
    status: str = ""
    message: str = ""


ProgressFn = Callable[[Progress], None]
