"""Benchmark: held-out error against the number of poses, for random and selected poses.

Three data sets, each a pool of candidate poses and a held-out set (never selected on, never
fitted, never used to tune anything):

- **twin 7D** and **twin position-only**: the digital twin of the simulated reference cell
  (its camera and target; twin seed 3, the paper's kind of position-dependent errors,
  instrument noise 0.03 mm / 0.1 mrad).  Pool: every feasible IK configuration (limits,
  collisions, line of sight, facing: the planner's step 2) of 2,000 random targets of the
  reference cell (seed 101), at most one per target chosen; held out: one feasible
  configuration each of 700 other random targets (seed 202).  Held-out error: RMS over the
  held-out poses of |model − true| target position (the twin knows the truth: no noise floor).
- **UR10**: the shared series fixtures/ipa-ur10 (a real UR10 and a Leica T-Mac), split by goal
  pose as docs/identify.md documents it (every fifth goal held out: 295 rows; pool 1,200
  rows).  Held-out error: RMS of |measured − model| position over the held-out rows.

"Random N": N poses drawn from the pool (one configuration of a random target; for the UR10
random rows), median over draws (each a new draw and, on the twin, new noise).  "Selected
N": ``quickhealth plan select``'s I-optimal design (identify/design.py; defaults: orders up to
3 with decaying prior, full pose or position only as the data, the measured point 100 mm out
on the flange axis: the design reads joint angles only), median over noise draws on the twin.
Every model is fitted as ``identify fit`` fits (``services.fitting.assess``: BIC order search).

"Poses needed for the same held-out error": the number of random poses whose median error
(log-log interpolation of the random curve) equals the selected N's error, divided by N.

    .venv/bin/python benchmarks/optimal_plan.py [--draws 9] [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

from quickhealth.identify.design import DesignSettings, select_poses  # noqa: E402
from quickhealth.identify.linearize import InstrumentNoise  # noqa: E402
from quickhealth.identify.transforms import inv_T  # noqa: E402
from quickhealth.identify.twin import make_twin  # noqa: E402
from quickhealth.station.formats import load_robot  # noqa: E402
from quickhealth.station.services.fitting import assess  # noqa: E402
from quickhealth.station.services.options import FitOptions  # noqa: E402

NOISE = InstrumentNoise(3e-5, 1e-4)


def cell_pool(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Feasible (target, configuration) joints of ``n`` random targets of the reference cell."""
    from quickhealth.station.planning import load_cell
    from quickhealth.station.planning.collision import CollisionWorld
    from quickhealth.station.planning.ik_ur import ik_ur, within_limits
    from quickhealth.station.planning.planner import _feasible, sample_targets
    from quickhealth.station.planning.sight import pose_sight

    cell = load_cell("reference")
    world = CollisionWorld(cell)
    T_wt = sample_targets(cell, n, np.random.default_rng(seed))
    T_bf = inv_T(cell.T_world_base) @ T_wt @ inv_T(cell.T_flange_target)
    Q, valid = ik_ur(cell.robot, T_bf)
    inlim = valid & within_limits(np.where(valid[..., None], Q, 0.0), cell.robot)
    sight = pose_sight(cell, T_wt)
    _, feas = _feasible(cell, world, Q, valid, inlim, sight, T_wt[:, :3, 3], lambda *a: None)
    ti, ci = np.nonzero(feas)
    return Q[ti, ci], ti


def one_per_group(groups: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random member of every group (random configuration of every target)."""
    out: dict[int, int] = {}
    for i in rng.permutation(len(groups)):
        out.setdefault(int(groups[i]), int(i))
    return np.array(sorted(out.values()))


class TwinSet:
    """The reference cell's twin, a pool and a held-out set."""

    def __init__(self, orientation: bool) -> None:
        from quickhealth.station.sim.world import build_world

        w = build_world("reference", twin_seed=1).twin.truth
        self.robot = build_world("reference", twin_seed=1).twin.robot
        self.twin = make_twin(
            self.robot, seed=3, T_instr_base=w.T_instr_base, T_flange_target=w.T_flange_target
        )
        self.orientation = orientation
        self.name = "twin 7D" if orientation else "twin position-only"
        self.q, self.groups = cell_pool(2000, 101)
        qh, gh = cell_pool(700, 202)
        self.held = qh[one_per_group(gh, np.random.default_rng(9))]
        self.truth = self.twin.true_pose(self.held)[:, :3, 3]
        self.settings = DesignSettings(orientation=orientation)

    def random(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.choice(one_per_group(self.groups, rng), n, replace=False)

    def error(self, rows: np.ndarray, seed: int) -> float:
        m = self.twin.measure(self.q[rows], seed=seed, orientation=self.orientation)
        fm = assess(m, self.robot, FitOptions(noise=NOISE, workspace_samples=200)).fitted
        p = fm.predict(self.held)[:, :3, 3]
        return float(np.sqrt(np.mean(np.sum((p - self.truth) ** 2, axis=1)))) * 1e3


class Ur10Set:
    """The shared UR10 series on its documented split."""

    name = "UR10 (fixtures/ipa-ur10)"

    def __init__(self) -> None:
        import qh_real

        self.robot = load_robot(str(qh_real.UR10_ROBOT))
        self.pool, self.heldm = qh_real.ur10_split()
        self.q = self.pool.q
        self.groups = np.arange(self.pool.n_poses)
        self.settings = DesignSettings(orientation=True)

    def random(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.choice(self.pool.n_poses, n, replace=False)

    def error(self, rows: np.ndarray, seed: int) -> float:
        m = self.pool.subset(np.sort(rows))
        fm = assess(m, self.robot, FitOptions(workspace_samples=200)).fitted
        p = fm.predict(self.heldm.q)[:, :3, 3]
        return float(np.sqrt(np.mean(np.sum((p - self.heldm.pos) ** 2, axis=1)))) * 1e3


def needed(n_sel: float, err: float, ns: list[int], med: list[float]) -> float:
    """Random poses with median error ``err`` (log-log interpolation), over ``n_sel``."""
    x, y = np.log(ns), np.log(med)
    order = np.argsort(y)  # error falls with N: ascending error, descending N
    n = float(np.exp(np.interp(np.log(err), y[order], x[order], left=np.nan, right=np.nan)))
    return n / n_sel


def run(ds, ns: list[int], draws: int) -> None:  # type: ignore[no-untyped-def]
    print(f"\n## {ds.name}: pool {len(ds.q)} candidates", flush=True)
    rng = np.random.default_rng(0)
    rand: dict[int, float] = {}
    for n in sorted(set(ns) | {2 * n for n in ns}):
        t0 = time.perf_counter()
        e = [ds.error(ds.random(n, rng), 1000 + 10 * n + k) for k in range(draws)]
        rand[n] = float(np.median(e))
        print(f"random {n:4d}: median {rand[n]:.4f} mm  (draws {np.round(e, 4).tolist()}; "
              f"{time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
    rows = []
    is_twin = isinstance(ds, TwinSet)
    for n in ns:
        t0 = time.perf_counter()
        res = select_poses(ds.robot, ds.q, n, ds.settings, allowed_groups=ds.groups)
        ts = time.perf_counter() - t0
        k = draws if is_twin else 1
        e = [ds.error(res.indices, 5000 + 10 * n + j) for j in range(k)]
        sel = float(np.median(e))
        ratio = needed(n, sel, sorted(rand), [rand[m] for m in sorted(rand)])
        rows.append((n, sel, rand[n], rand[2 * n], ratio, ts, res.band_mm, res.random_band_mm))
        print(f"selected {n:4d}: median {sel:.4f} mm (draws {np.round(e, 4).tolist()}; "
              f"selection {ts:.1f} s)", flush=True)  # fmt: skip
    print("\n| N | selected N | random N | random 2N | selected N ≤ random 2N | "
          "random poses for the same error / N | predicted band sel / random (mm) |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for n, sel, r1, r2, ratio, _, b, rb in rows:
        print(f"| {n} | {sel:.4f} | {r1:.4f} | {r2:.4f} | {'yes' if sel <= r2 else 'no'} | "
              f"{ratio:.2f} | {b:.4f} / {rb:.4f} |", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--draws", type=int, default=9)
    ap.add_argument("--quick", action="store_true", help="N = 50 only, 3 draws")
    ap.add_argument("--sets", default="twin7d,twinpos,ur10")
    a = ap.parse_args()
    ns = [50] if a.quick else [25, 50, 100, 200]
    draws = 3 if a.quick else a.draws
    sets = {"twin7d": lambda: TwinSet(True), "twinpos": lambda: TwinSet(False), "ur10": Ur10Set}
    for key in a.sets.split(","):
        run(sets[key](), ns, draws)


if __name__ == "__main__":
    main()
