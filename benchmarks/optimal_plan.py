"""Benchmark: held-out error against the number of poses, for random and chosen poses.

Four data sets, each a pool of candidate poses and a held-out set (never chosen from, never
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
- **WAM**: the Barrett WAM laser-tracker set (fixtures/wam): pool grid.csv (216 poses),
  held out random.csv (20 poses), as published; position only, the tracker's point 44 mm out
  on the flange axis (the set's SOURCE.md).

"Random N": N poses drawn from the pool (one configuration of a random target; for the real
sets random rows), over ``--draws`` draws (each a new draw and, on the twin, new noise):
median and quartiles.  "Chosen N": ``quickhealth plan select``'s design (identify/design.py),
twice: with the stated prior (no baseline) and with a baseline's prior (``--baseline``: the
twin's paper loop, 150 random pool poses measured once; the UR10's and the WAM's whole pool
fitted, i.e. the previous session), each the median over noise draws on the twin; and the
method's spread over pools: the median (and range) of the designs from ``--pool-draws``
random 90 % subsets of the pool.  Every model is fitted as ``identify fit`` fits
(``services.fitting.assess``: BIC order search, defaults).

"Random poses for the same error / N": the number of random poses whose median error
(log-log interpolation of the random curve, made monotone) equals the chosen N's error,
divided by N; its spread: the same against the random draws' lower and upper quartile curves.
Beyond the curve's ends it is given as a bound (``>``, ``<``).

Random curves are cached in ``--cache`` (keyed by the set, the draws and the identify
package's source): a rerun after a design change recomputes only the chosen poses.

    nice -n 10 .venv/bin/python benchmarks/optimal_plan.py [--sets twin7d,twinpos,ur10,wam]
        [--draws 25] [--twin-draws 40] [--noise-draws 15] [--pool-draws 5] [--quick]

About 40 min on this shared 2-core machine from scratch (the random curves: most of it),
10 min with them cached.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

from quickhealth.identify.design import (  # noqa: E402
    DesignPrior,
    DesignResult,
    DesignSettings,
    prior_from_baseline,
    select_poses,
)
from quickhealth.identify.linearize import InstrumentNoise  # noqa: E402
from quickhealth.identify.transforms import inv_T, make_T  # noqa: E402
from quickhealth.identify.twin import make_twin  # noqa: E402
from quickhealth.station import formats  # noqa: E402
from quickhealth.station.services.fitting import assess  # noqa: E402
from quickhealth.station.services.options import FitOptions  # noqa: E402

NOISE = InstrumentNoise(3e-5, 1e-4)


def cell_pool(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Feasible (target, configuration) joints of ``n`` random targets of the reference cell."""
    from quickhealth.station.planning import load_cell
    from quickhealth.station.planning.collision import CollisionWorld
    from quickhealth.station.planning.ik_ur import ik_ur, within_limits
    from quickhealth.station.planning.planner import feasible_configurations, sample_targets
    from quickhealth.station.planning.sight import pose_sight

    cell = load_cell("reference")
    world = CollisionWorld(cell)
    T_wt = sample_targets(cell, n, np.random.default_rng(seed))
    T_bf = inv_T(cell.T_world_base) @ T_wt @ inv_T(cell.T_flange_target)
    Q, valid = ik_ur(cell.robot, T_bf)
    inlim = valid & within_limits(np.where(valid[..., None], Q, 0.0), cell.robot)
    sight = pose_sight(cell, T_wt)
    _, feas = feasible_configurations(
        cell, world, Q, valid, inlim, sight, T_wt[:, :3, 3], lambda *a: None
    )
    ti, ci = np.nonzero(feas)
    return Q[ti, ci], ti


def one_per_group(groups: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random member of every group (random configuration of every target)."""
    out: dict[int, int] = {}
    for i in rng.permutation(len(groups)):
        out.setdefault(int(groups[i]), int(i))
    return np.array(sorted(out.values()))


def rms_mm(p: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((p - ref) ** 2, axis=1)))) * 1e3


class TwinSet:
    """The reference cell's twin, a pool and a held-out set."""

    noisy = True
    ns = [25, 35, 50, 70, 100, 140, 200, 280, 400]

    def __init__(self, orientation: bool) -> None:
        from quickhealth.station.sim.world import build_world

        world = build_world("reference", twin_seed=1).twin
        self.robot = world.robot
        truth = world.truth
        self.twin = make_twin(self.robot, seed=3, T_instr_base=truth.T_instr_base,
                              T_flange_target=truth.T_flange_target)  # fmt: skip
        self.orientation = orientation
        self.key = "twin7d" if orientation else "twinpos"
        self.name = "twin 7D" if orientation else "twin position-only"
        self.q, self.groups = cell_pool(2000, 101)
        qh, gh = cell_pool(700, 202)
        self.held = qh[one_per_group(gh, np.random.default_rng(9))]
        self.truth = self.twin.true_pose(self.held)[:, :3, 3]
        self.settings = DesignSettings(orientation=orientation,
                                       T_flange_target=truth.T_flange_target)  # fmt: skip

    def random(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.choice(one_per_group(self.groups, rng), n, replace=False)

    def fit(self, rows: np.ndarray, seed: int):  # type: ignore[no-untyped-def]
        m = self.twin.measure(self.q[rows], seed=seed, orientation=self.orientation)
        return assess(m, self.robot, FitOptions(noise=NOISE, workspace_samples=200)).fitted

    def error(self, rows: np.ndarray, seed: int) -> float:
        return rms_mm(self.fit(rows, seed).predict(self.held)[:, :3, 3], self.truth)

    def baseline(self) -> DesignPrior:
        """The paper's loop: 150 random pool poses, measured once, fitted."""
        rows = self.random(150, np.random.default_rng(77))
        return prior_from_baseline(self.fit(rows, 77), "the twin's 150-pose loop")


class MeasuredSet:
    """A real series: a pool of measured rows and held-out rows."""

    noisy = False
    robot_file: Path
    tool_mm: tuple[float, float, float]

    def __init__(self) -> None:
        self.robot = formats.load_robot(str(self.robot_file))
        self.pool, self.heldm = self.split()
        self.q = self.pool.q
        self.groups = np.arange(self.pool.n_poses)
        self.orientation = self.pool.has_orientation
        tool = make_T(np.eye(3), np.array(self.tool_mm) * 1e-3)
        self.settings = DesignSettings(orientation=self.orientation, T_flange_target=tool)
        self.ns = [n for n in self.ns if n < self.pool.n_poses] + [self.pool.n_poses]

    def split(self):  # type: ignore[no-untyped-def]
        raise NotImplementedError

    def random(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.choice(self.pool.n_poses, n, replace=False)

    def fit(self, rows: np.ndarray):  # type: ignore[no-untyped-def]
        m = self.pool.subset(np.sort(rows))
        return assess(m, self.robot, FitOptions(workspace_samples=200)).fitted

    def error(self, rows: np.ndarray, seed: int) -> float:
        return rms_mm(self.fit(rows).predict(self.heldm.q)[:, :3, 3], self.heldm.pos)

    def baseline(self) -> DesignPrior:
        """The previous session: the whole pool fitted."""
        return prior_from_baseline(self.fit(np.arange(self.pool.n_poses)), "the pool's fit")


class Ur10Set(MeasuredSet):
    key, name = "ur10", "UR10 (fixtures/ipa-ur10)"
    ns = [25, 35, 50, 70, 100, 140, 200, 280, 400]
    tool_mm = (0.0, 0.0, 100.0)

    def __init__(self) -> None:
        import qh_real

        self.robot_file = qh_real.UR10_ROBOT
        super().__init__()

    def split(self):  # type: ignore[no-untyped-def]
        import qh_real

        return qh_real.ur10_split()


class WamSet(MeasuredSet):
    key, name = "wam", "Barrett WAM (fixtures/wam)"
    ns = [20, 25, 35, 50, 70, 100, 140, 200]
    tool_mm = (0.0, 0.0, 44.0)

    def __init__(self) -> None:
        import qh_real

        self.robot_file = qh_real.WAM_ROBOT
        super().__init__()

    def split(self):  # type: ignore[no-untyped-def]
        import qh_real

        from quickhealth.station.services.wam import wam_sign

        sign, _ = wam_sign(self.robot, qh_real.WAM_DIR / "grid.csv")  # decided on the pool
        grid = formats.read_wam_csv(qh_real.WAM_DIR / "grid.csv", sign)
        return grid, formats.read_wam_csv(qh_real.WAM_DIR / "random.csv", sign)


def code_key() -> str:
    """Hash of the identify package's source (the fit the random curves come from)."""
    h = hashlib.sha256()
    for p in sorted((ROOT / "identify").rglob("*.py")):
        if p.name != "design.py":  # the random curves do not depend on the design
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def random_curve(ds, draws: int, cache: Path) -> dict[int, list[float]]:  # type: ignore[no-untyped-def]
    """Held-out error of ``draws`` random draws at every N of the set (cached)."""
    f = cache / f"random_{ds.key}_{draws}_{code_key()}.json"
    if f.exists():
        return {int(k): v for k, v in json.loads(f.read_text()).items()}
    rng = np.random.default_rng(0)
    out: dict[int, list[float]] = {}
    for n in ds.ns:
        t0 = time.perf_counter()
        if not ds.noisy and n >= ds.pool.n_poses:  # the whole pool: one fit
            out[n] = [ds.error(np.arange(ds.pool.n_poses), 0)]
        else:
            out[n] = [ds.error(ds.random(n, rng), 1000 + 10 * n + k) for k in range(draws)]
        print(f"  random {n:4d}: median {np.median(out[n]):.4f} mm ({time.perf_counter() - t0:.0f} s)",
              flush=True)  # fmt: skip
    cache.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps(out))
    return out


def needed(err: float, curve: dict[int, list[float]], q: float = 50.0) -> tuple[float, str]:
    """Random poses whose ``q``-th percentile error equals ``err`` (log-log, monotone); with
    ``>``/``<`` when ``err`` is beyond the curve's ends."""
    ns = sorted(curve)
    y = np.minimum.accumulate(np.log([np.percentile(curve[n], q) for n in ns]))
    x = np.log(ns)
    e = np.log(err)
    if e < y[-1]:
        return float(ns[-1]), ">"
    if e > y[0]:
        return float(ns[0]), "<"
    return float(np.exp(np.interp(e, y[::-1], x[::-1]))), ""


def ratio_text(err: float, n: int, curve: dict[int, list[float]]) -> str:
    mid, lo, hi = (needed(err, curve, q) for q in (50, 25, 75))
    return f"{mid[1]}{mid[0] / n:.2f} [{lo[1]}{lo[0] / n:.2f}, {hi[1]}{hi[0] / n:.2f}]"


def choose(ds, n: int, prior: DesignPrior, rows: np.ndarray | None = None) -> DesignResult:  # type: ignore[no-untyped-def]
    """The design's ``n`` poses of the pool (or of its ``rows``), as pool indices."""
    rows = np.arange(len(ds.q)) if rows is None else rows
    settings = replace(ds.settings, prior=prior)
    res = select_poses(ds.robot, ds.q[rows], n, settings, allowed_groups=ds.groups[rows])
    return replace(res, indices=rows[res.indices])


def chosen_errors(ds, n: int, prior: DesignPrior, noise_draws: int, pool_draws: int):  # type: ignore[no-untyped-def]
    """Held-out error of the design from the whole pool (median over noise draws on the
    twin), and of the designs from ``pool_draws`` random 90 % subsets of the pool (each with
    its own noise draw; for N near the pool's size, all but half of the rest): the method's
    spread over pools."""
    res = choose(ds, n, prior)
    k = noise_draws if ds.noisy else 1
    full = float(np.median([ds.error(res.indices, 5000 + 10 * n + j) for j in range(k)]))
    rng = np.random.default_rng(n)
    sub = []
    m = len(ds.q)
    size = max(int(0.9 * m), (n + m) // 2)  # near the pool's size: half of what is left out
    for j in range(pool_draws):
        rows = np.sort(rng.choice(m, size, replace=False))
        sub.append(ds.error(choose(ds, n, prior, rows).indices, 7000 + 10 * n + j))
    return res, full, np.array(sub)


def run(ds, ns: list[int], draws: int, noise_draws: int, pool_draws: int, cache: Path) -> None:  # type: ignore[no-untyped-def]
    print(f"\n## {ds.name}: pool {len(ds.q)} candidates", flush=True)
    curve = random_curve(ds, draws, cache)
    b = ds.baseline()
    print(f"  baseline prior ({b.source}): unexplained share {b.unexplained:.3f}, "
          f"{len(b.fitted_sizes)} fitted coefficients, effects {[e.name for e, _ in b.effects]}",
          flush=True)  # fmt: skip
    for label, prior in (("stated prior", ds.settings.prior), ("baseline prior", b)):
        rows = []
        for n in ns:
            med = float(np.median(curve[n]))
            q25, q75 = np.percentile(curve[n], [25, 75])
            t0 = time.perf_counter()
            res, full, sub = chosen_errors(ds, n, prior, noise_draws, pool_draws)
            m = float(np.median(sub))
            print(f"  chosen {n:4d} ({label}): {full:.4f} mm, over pools {m:.4f} mm; "
                  f"{res.n_information} by information + {res.n_spread} spread "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
            rows.append([f"{n}", f"{med:.4f} [{q25:.4f}, {q75:.4f}]",
                         f"{full:.4f}", "yes" if full <= med else "**no**",
                         ratio_text(full, n, curve),
                         f"{m:.4f} [{sub.min():.4f}, {sub.max():.4f}]",
                         "yes" if m <= med else "**no**", ratio_text(m, n, curve),
                         f"{res.n_information}+{res.n_spread}"])  # fmt: skip
        print(f"\n{ds.name}, {label}:\n")
        print("| N | random N: median [quartiles] (mm) | chosen N (mm) | ≤ random median | "
              "random poses for the same error / N [spread] | chosen N from 90 % pools: median "
              f"of {pool_draws} [range] (mm) | ≤ random median | random poses / N [spread] | "
              "information + spread poses |")  # fmt: skip
        print("|" + " --- |" * 9)
        for cells in rows:
            print("| " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", default="twin7d,twinpos,ur10,wam")
    ap.add_argument("--draws", type=int, default=25, help="random draws per N, real sets")
    ap.add_argument("--twin-draws", type=int, default=40, help="random draws per N, twin")
    ap.add_argument("--noise-draws", type=int, default=15, help="noise draws of a twin choice")
    ap.add_argument("--pool-draws", type=int, default=5, help="90 %% pool subsets per choice")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/quickhealth-bench-optimal"))
    ap.add_argument("--quick", action="store_true", help="N = 50 only, 7 draws")
    a = ap.parse_args()
    if min(a.draws, a.twin_draws) < 5:
        ap.error("at least 5 random draws")
    ns = [50] if a.quick else [25, 50, 100, 200]
    sets = {"twin7d": lambda: TwinSet(True), "twinpos": lambda: TwinSet(False),
            "ur10": Ur10Set, "wam": WamSet}  # fmt: skip
    for key in a.sets.split(","):
        ds = sets[key]()
        draws = a.twin_draws if ds.noisy else a.draws
        run(ds, ns, 7 if a.quick else draws, 5 if a.quick else a.noise_draws, a.pool_draws, a.cache)


if __name__ == "__main__":
    main()
