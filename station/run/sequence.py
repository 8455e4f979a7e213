"""Which pose a run visits next: :class:`PoseSequence`, and the plan's fixed loop."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from ..hardware.robot import Leg
from .journal import JournalState

if TYPE_CHECKING:  # types only: the planner loads the collision library, a run needs none of it
    from ..planning.planfile import Plan, PlanPose

F = NDArray[np.float64]


class PoseSequence(Protocol):
    """Which pose a run visits next: the plan's loop order, or a choice made as the data come
    in (the quick check, :mod:`.services.checking`).

    ``order`` is how measurements.csv orders the poses: ``"plan"`` (plan index) or
    ``"capture"`` (the order they were captured in: the execution order of a sequence that
    chooses).  With ``wait_for_measurements`` every pose's 7D measurement is journalled
    before :meth:`next_pose` is asked.
    """

    order: str
    wait_for_measurements: bool

    def next_pose(self, state: JournalState) -> PlanPose | None:
        """The next pose (its ``leg`` says how to move there), or None: the run is done."""
        ...

    def resume_pose(self, state: JournalState) -> PlanPose | None:
        """The pose to re-approach (joint leg) before resuming, so every joint approaches the
        next pose from the side it would have in an uninterrupted run; None: nowhere."""
        ...

    def finish(self, state: JournalState) -> tuple[F, Leg] | None:
        """Where the arm goes after the last pose, and how (None: it stays)."""
        ...


class PlanOrder:
    """The plan's fixed loop: every pose with no record, in plan order, then back home."""

    order = "plan"
    wait_for_measurements = False

    def __init__(self, plan: Plan, done: set[int]) -> None:
        self.plan = plan
        self.todo = [p for p in plan.poses if p.index not in done]
        self.first = self.todo[0].index if self.todo else None
        self.pos = 0

    def next_pose(self, state: JournalState) -> PlanPose | None:
        if self.pos >= len(self.todo):
            return None
        self.pos += 1
        return self.todo[self.pos - 1]

    def resume_pose(self, state: JournalState) -> PlanPose | None:
        if self.first is None:
            return None
        before = [p for p in self.plan.poses if p.index < self.first]
        return before[-1] if before else None

    def finish(self, state: JournalState) -> tuple[F, Leg] | None:
        home = getattr(self.plan, "home", None)
        return None if home is None else (home, Leg(self.plan.return_leg))
