"""What the technician's screens show: small frozen records the :class:`Station` facade returns.

The screens read only these; the facade fills them from the station, planner, fit engine,
diagnosis and archive.  Units follow the screen: mm and degrees (the file and CLI boundary),
seconds for durations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from ..reporting.verdict import HealthVerdict, ThresholdFigure

F = NDArray[np.float64]


@dataclass(frozen=True)
class Connection:
    """One device the station talks to, and how it is doing.

    ``state`` is ``"ok"``, ``"warn"`` (answering but not ready, e.g. robot idle or in a
    protective stop) or ``"down"`` (not answering).  ``detail`` says what, in words.
    """

    name: str
    state: str
    detail: str


@dataclass(frozen=True)
class Check:
    """One pre-flight check: passed or not, and why."""

    name: str
    ok: bool
    why: str


@dataclass(frozen=True)
class Preflight:
    """All pre-flight checks; the run may move the arm only when :attr:`go` is true."""

    checks: tuple[Check, ...]

    @property
    def go(self) -> bool:
        """True when every check passed (and there is at least one)."""
        return bool(self.checks) and all(c.ok for c in self.checks)

    @property
    def reasons(self) -> tuple[str, ...]:
        """Why not, one sentence per failed check."""
        return tuple(f"{c.name}: {c.why}" for c in self.checks if not c.ok)


@dataclass(frozen=True)
class JointCoverage:
    """Kept poses of one joint over its usable range, for a text histogram.

    ``counts`` has one entry per bin over ``[lo_deg, hi_deg]``; ``covered`` is the fraction
    of the usable range the kept poses span.
    """

    joint: str
    counts: tuple[int, ...]
    lo_deg: float
    hi_deg: float
    covered: float


@dataclass(frozen=True)
class PlanView:
    """The plan the station will run, as the planner summarised it."""

    cell: str
    path: str
    plan_hash: str
    n_generated: int
    n_kept: int
    dropped: dict[str, int]
    n_linear: int
    n_joint: int
    coverage: tuple[JointCoverage, ...]
    evenness: float | None = None
    loop_time_s: float | None = None


@dataclass(frozen=True)
class DryRun:
    """Result of running the plan on the simulator without capture."""

    ok: bool
    n_poses: int
    duration_s: float
    problems: tuple[str, ...]


@dataclass(frozen=True)
class PoseStatus:
    """What happened at one pose of the run."""

    index: int
    pose_id: str
    status: str  # "pending", "moving", "measuring", "done", "failed", "skipped"
    q_deg: tuple[float, ...] = ()
    markers: int | None = None
    reproj_px: float | None = None
    reason: str = ""


@dataclass(frozen=True)
class Fault:
    """A condition that stopped the arm, what it is and what the technician should do."""

    kind: str  # "connection-lost", "protective-stop", "error"
    message: str
    what_to_do: str


class CellState(StrEnum):
    """Where the run of the Run screen is."""

    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    ABORTED = "aborted"
    FAULT = "fault"
    FINISHED = "finished"


@dataclass(frozen=True)
class RunProgress:
    """The run as the Run screen shows it, after every pose event."""

    state: CellState
    done: int
    total: int
    eta_s: float | None
    current: PoseStatus | None
    last_measured: PoseStatus | None
    run_dir: str
    fault: Fault | None = None


@dataclass(frozen=True, eq=False)
class JointCurve:
    """One identified error motion of one joint over its range with its band (paper Fig. 8)."""

    joint: str
    motion: str  # "dx" … "ez"
    words: str
    unit: str  # "mm" or "mrad"
    q_deg: F = field(repr=False)
    value: F = field(repr=False)
    band: F = field(repr=False)  # half-width of the 95 % band, same unit as value


@dataclass(frozen=True)
class Region:
    """A part of the workspace where the predicted error is largest."""

    where: str
    err_mm: float


@dataclass(frozen=True)
class Health:
    """The health summary of one run (workspace error from the model, not only measured poses)."""

    run_id: str
    robot: str
    mean_mm: float
    std_mm: float
    max_mm: float
    spec_mm: float | None  # the accuracy spec judged against (None: none set)
    spec_figure: ThresholdFigure  # which figure the spec applies to
    verdict: HealthVerdict  # the run's report's (healthy, degraded, flagged)
    reason: str  # the verdict's one-line reason
    verdict_lines: tuple[str, ...]  # the verdict in words, as every door shows it
    baseline_mean_mm: float | None
    hist_counts: tuple[int, ...]
    hist_edges_mm: tuple[float, ...]
    curves: tuple[JointCurve, ...]
    worst: tuple[Region, ...]
    rms_pos_mm: float
    n_poses: int
    effects: tuple[str, ...] = ()
    pngs: tuple[str, ...] = ()

    @property
    def change_mm(self) -> float | None:
        """Mean workspace error minus the baseline's (mm), or None without a baseline."""
        if self.baseline_mean_mm is None:
            return None
        return self.mean_mm - self.baseline_mean_mm


@dataclass(frozen=True)
class PoseResidual:
    """Measured versus model at one pose (mm, robot base frame)."""

    pose_id: str
    measured_mm: tuple[float, float, float]
    model_mm: tuple[float, float, float]
    err_mm: float


@dataclass(frozen=True)
class Candidate:
    """A physical effect the diagnosis proposes, with its evidence."""

    effect: str
    score: float
    predicted_rms_drop_mm: float
    evidence: str


@dataclass(frozen=True)
class Diagnosis:
    """The diagnosis of the current model: per-pose residuals and the ranked candidates."""

    verdict: str  # "adequate" or "missing-effect"
    effects: tuple[str, ...]
    residuals: tuple[PoseResidual, ...]
    candidates: tuple[Candidate, ...]


@dataclass(frozen=True)
class Refit:
    """Held-out error before and after adding effects (per axis and overall), mm."""

    effects_before: tuple[str, ...]
    effects_after: tuple[str, ...]
    before_mm: float
    after_mm: float
    before_axes_mm: tuple[float, float, float]
    after_axes_mm: tuple[float, float, float]
    heldout: str  # how the held-out error was measured, in words

    @property
    def drop_fraction(self) -> float:
        """Relative drop of the held-out error (positive = better)."""
        return 1.0 - self.after_mm / self.before_mm if self.before_mm > 0 else 0.0


@dataclass(frozen=True)
class HistoryRow:
    """One archived run (an assessment) or quick check of this robot."""

    run_id: str
    when: str
    mean_mm: float  # NaN for a quick check (no figures)
    std_mm: float
    max_mm: float
    verdict: str  # a run's report verdict (healthy, degraded, flagged), a check's
    # (unchanged, changed), or "not judged" (no report yet)
    baseline: bool = False
    kind: str = "run"  # "run" or "check"
    reason: str = ""  # the verdict's reason (a check: its summary)


@dataclass(frozen=True)
class History:
    """This robot's runs over time and the trend of the main figures."""

    robot: str
    rows: tuple[HistoryRow, ...]  # runs and quick checks, oldest first
    trend: str  # the trend in words (e.g. "mean error rising 0.02 mm/run; crosses 0.5 mm in ~30 d")
    flagged: bool = False  # the latest run's verdict is "flagged"
    pngs: tuple[str, ...] = ()
    checks: tuple[str, ...] = ()  # the robot's quick checks, one line each (not assessments)
    latest: tuple[str, ...] = ()  # the latest run's verdict lines, as its report says them
    archive: str = ""  # the archive folder read
