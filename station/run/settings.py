"""The tunables of a run (SI)."""

from __future__ import annotations

from dataclasses import dataclass

from ..hardware.robot import REST_TOL_RAD, REST_WINDOW_S


@dataclass(frozen=True)
class RunSettings:
    """Tunables of a run (SI).

    Attributes
    ----------
    settle_window_s : float
        The joints must stay within ``settle_tol_rad`` for this long (controller time).
    settle_tol_rad : float
        Peak-to-peak joint motion allowed inside the window.
    settle_timeout_s : float
        Longest wait for rest before the run stops.
    capture_attempts : int
        Captures per pose before it is recorded as failed.
    min_markers : int
        Markers each camera must see in the quick check.
    selfcheck_limit_mm, selfcheck_limit_deg : float
        Largest acceptable drift of the self-check board between start and end.
    png_level : int
        PNG compression (0–9); 1 is fast and still halves the size.
    bytes_per_pose : int or None
        Disk needed per pose (None: estimated from the image size).
    """

    settle_window_s: float = REST_WINDOW_S
    settle_tol_rad: float = REST_TOL_RAD
    settle_timeout_s: float = 10.0
    capture_attempts: int = 3
    min_markers: int = 6
    selfcheck_limit_mm: float = 0.05
    selfcheck_limit_deg: float = 0.02
    png_level: int = 1
    bytes_per_pose: int | None = None
    selfcheck: bool = True
