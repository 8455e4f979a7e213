"""Whether a plan can support the error model it is meant for, and why not (docs/plan.md,
"Plans that are too small").

The rule, stated once here and printed by ``plan``:

- **poses**: the model of order ``K`` (every error motion of every joint a Chebyshev series
  of order ``K``: ``6 · N · (K + 1)`` coefficients for ``N`` joints) must be seen at least
  twice over: each pose measures 6 numbers (position and orientation), so the plan keeps at
  least ``ceil(2 · 6 · N · (K + 1) / 6)`` poses (36 for a six-joint arm at the default
  ``K = 2``);
- **coverage**: every joint's kept angles span at least :data:`MIN_COVERAGE` of its usable
  range in the cell (a series fitted on part of a joint's range extrapolates over the rest).

Pure: the planner's result in, words out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .planner import PlanResult

#: Default Chebyshev order of the model a plan is checked for (``plan --model-order``).
MODEL_ORDER = 2
#: Each parameter seen this many times over.
REDUNDANCY = 2
#: Numbers one pose measures (the 7D target: position and orientation).
PER_POSE = 6
#: Share of each joint's usable range the kept poses must span.
MIN_COVERAGE = 0.6


@dataclass(frozen=True)
class Adequacy:
    """What a plan supports: the poses it keeps and needs, each joint's coverage and the
    problems in words (empty: adequate)."""

    model_order: int
    kept: int
    needed: int
    coverage: tuple[float, ...]
    problems: tuple[str, ...]

    @property
    def adequate(self) -> bool:
        """True when the plan supports the model."""
        return not self.problems

    def rule(self) -> str:
        """The rule, in one line."""
        return (
            f"rule: at least {self.needed} poses (the order-{self.model_order} model's "
            f"coefficients each seen {REDUNDANCY}x over, {PER_POSE} numbers per pose) and every "
            f"joint spanning {MIN_COVERAGE:.0%} of its usable range"
        )


def adequacy(result: PlanResult, model_order: int = MODEL_ORDER) -> Adequacy:
    """Check ``result`` against the rule (module docstring) for the order-``model_order``
    model."""
    nj = result.cell.robot.n_joints
    n_params = 6 * nj * (model_order + 1)
    needed = math.ceil(REDUNDANCY * n_params / PER_POSE)
    kept = len(result.poses)
    cov = tuple(float(c) for c in np.asarray(result.coverage.coverage, float))
    problems = []
    if kept < needed:
        problems.append(
            f"the plan keeps {kept} poses; the order-{model_order} error model ({n_params} "
            f"coefficients) needs at least {needed}: raise --n, or plan with --model-order "
            f"{max(0, model_order - 1)} for a simpler model"
        )
    low = [(j + 1, c) for j, c in enumerate(cov) if not c >= MIN_COVERAGE]
    if low:
        problems.append(
            "joint coverage too small: "
            + ", ".join(f"joint {j} {c:.0%}" for j, c in low)
            + f" of the usable range (need {MIN_COVERAGE:.0%}): its error curves would be "
            "extrapolated; widen the cell's [workspace] box or raise --n"
        )
    return Adequacy(model_order, kept, needed, cov, tuple(problems))
