"""``plan --optimal K``: the planner's feasible candidates thinned to K by an optimal design.

Step 2 of the planner leaves every generated target with the IK configurations that are in
limits, collision-free and see the target (line of sight, facing, field of view).  Among all
of those (target, configuration) pairs, :func:`choose` keeps ``K``, at most one configuration
per target, by the criterion of ``quickhealth plan select``
(:func:`quickhealth.identify.design.select_poses`: the first poses I-optimal over the error
model's coefficients with the stated prior for the orders, or a baseline's (``--baseline``),
the rest chosen to represent the feasible candidates; 7D measurements of the cell's target
with the instrument's default noise).  The planner then orders the chosen poses, checks their
legs (collisions, linear or joint) and reports the joint coverage and evenness as for any plan:
the design's spread is what keeps the coverage even; a chosen pose without a feasible leg is
dropped as for any plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...identify.design import (
    Criterion,
    DesignPrior,
    DesignResult,
    DesignSettings,
    select_poses,
)
from .cell import Cell

F = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class OptimalChoice:
    """The (target, configuration) pairs kept and the design's figures."""

    pairs: tuple[tuple[int, int], ...]
    result: DesignResult

    def as_dict(self) -> dict[str, object]:
        """For plan.json's summary (mm)."""
        r = self.result
        return {
            "criterion": "the first poses I-optimal (mean predicted TCP error variance over the "
            "feasible candidates), the rest the most representative of them (kernel herding in "
            "joint space); quickhealth plan select; docs/plan.md",
            "chosen": len(self.pairs),
            "candidates": r.n_candidates,
            "parameters": r.n_params,
            "identifiable": r.identifiable,
            "information_poses": r.n_information,
            "spread_poses": r.n_spread,
            "prior": r.prior_source,
            "effects": list(r.effects),
            "effects_left_out": list(r.left_out),
            "predicted_band_mm": round(r.band_mm, 6),
            "random_band_mm": round(r.random_band_mm, 6),
        }


def choose(
    cell: Cell, Q: F, feasible: NDArray[np.bool_], k: int, prior: DesignPrior | None = None
) -> OptimalChoice:
    """``k`` (target, configuration) pairs of the feasible ones (``Q`` (n, 8, 6) rad,
    ``feasible`` (n, 8)), at most one per target; ``prior``: the design's (default stated)."""
    ti, ci = np.nonzero(feasible)
    q = Q[ti, ci]
    settings = DesignSettings(
        criterion=Criterion.I_OPTIMAL,
        orientation=True,
        T_flange_target=cell.T_flange_target,
        prior=prior or DesignPrior(),
    )
    n_targets = len(np.unique(ti))
    res = select_poses(cell.robot, q, min(k, n_targets), settings, allowed_groups=ti)
    pairs = tuple((int(ti[j]), int(ci[j])) for j in res.indices)
    return OptimalChoice(pairs, res)
