"""A 20-pose plan of the reference cell for the station tests, planned once per session.

Planned with the real planner (so it always matches the current plan schema and cell), then
cut to its first 20 poses with the content hash recomputed (a shorter loop of the same cell).
"""

from __future__ import annotations

import fcntl
import json
from pathlib import Path


def plan_file(cache_dir: Path, n_poses: int = 20) -> Path:
    """Path of the cached plan of ``n_poses`` ≤ 20 poses (created on first use)."""
    path = cache_dir / f"station_plan{n_poses}.json"
    if n_poses < 20:
        if not path.exists():
            from quickhealth.station.planning.planfile import content_hash

            doc = json.loads(plan_file(cache_dir, 20).read_text())
            doc["poses"] = doc["poses"][:n_poses]
            doc["hash"] = content_hash(doc)
            path.write_text(json.dumps(doc))
        return path
    with open(cache_dir / ".station_plan.lock", "w") as lk:
        fcntl.flock(lk, fcntl.LOCK_EX)
        if not path.exists():
            from quickhealth.station.planning.cell import load_cell
            from quickhealth.station.planning.planfile import (
                content_hash,
                plan_from_dict,
                plan_to_dict,
            )
            from quickhealth.station.planning.planner import plan_loop

            cell = load_cell("reference")
            for seed in range(1, 10):
                doc = plan_to_dict(plan_loop(cell, 40, seed=seed))
                if len(doc["poses"]) >= n_poses:
                    break
            else:  # pragma: no cover - the reference cell keeps ~60 % of its targets
                raise RuntimeError("the planner kept too few poses for the station tests")
            doc["poses"] = doc["poses"][:n_poses]
            doc["hash"] = content_hash(doc)
            plan_from_dict(json.loads(json.dumps(doc)), "test plan")  # validates
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(doc))
            tmp.replace(path)
    return path
