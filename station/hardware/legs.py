"""How the robot travels to a pose: the one leg vocabulary of the planner, plan.json and the driver.

The values are plan.json's ``leg`` and ``return_leg`` and the driver's move request (``joint``:
movej, ``linear``: movel).  Standard library only, so the driver imports it without the
planner's modules and the planner without the driver's.
"""

from __future__ import annotations

from enum import StrEnum


class Leg(StrEnum):
    """How the robot travels to a pose (the plan's ``leg``)."""

    JOINT = "joint"
    LINEAR = "linear"
