"""Fixed-loop measurement planning (METHOD.md §1, paper Sec. 3, Figs. 3 and 6).

Stages, in order:

- ``cell``: load and validate a cell file (TOML) → :class:`Cell`
- ``ik_ur``: analytic UR inverse kinematics, all 8 solutions
- ``collision``: the UR5's collision meshes, the target body, obstacles and table in fcl
- ``sight``: field of view, facing angle and occlusion from both cameras
- ``planner``: steps 1–5 (sample, filter, order, legs, even joint distribution) → ``PlanResult``
- ``planfile``: plan.json with its content hash; :func:`load_plan` validates it → ``Plan``
- ``urscript``: the URScript program of the loop from validated numbers and fixed templates
- ``figures``: Fig. 6 plots (joint histograms, Cartesian scatter)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["load_cell", "load_plan", "ik_ur", "plan_loop"]

if TYPE_CHECKING:  # pragma: no cover
    from .cell import load_cell
    from .ik_ur import ik_ur
    from .planfile import load_plan
    from .planner import plan_loop


def __getattr__(name: str) -> Any:
    """Lazy access to the public API (keeps ``quickhealth --help`` fast)."""
    if name == "load_cell":
        from .cell import load_cell

        return load_cell
    if name == "ik_ur":
        from .ik_ur import ik_ur

        return ik_ur
    if name == "load_plan":
        from .planfile import load_plan

        return load_plan
    if name == "plan_loop":
        from .planner import plan_loop

        return plan_loop
    raise AttributeError(name)
