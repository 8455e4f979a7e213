"""Benchmark: the quick check's error rates and robot time on the digital twin.

The twin is the simulated reference cell's robot (twin seed 1, its camera and target) and
the check runs what ``quickhealth check`` runs, through the library: the reference plan (150
candidates, seed 0: 74 poses); a baseline "run" of the twin at every plan pose, fitted as
``identify fit`` fits (BIC order search); then checks that choose each next pose by
:func:`quickhealth.station.services.checking.rank_candidates` (information on change per
second of robot time) and stop as :class:`quickhealth.identify.quickcheck.CheckRun` says.
What the library leaves out of the simulated robot: collision checks of the legs (the plan's
poses have free legs on the simulated cell; a check skips a pose whose leg is not free) and
the images (the twin's measurement noise stands for the camera's).

Noise: ``--noise sim`` (default): per-row uncertainties of the simulated cell's stereo camera
at image scale 0.5, as measured on its reference run (median 1.1, 0.9, 3.3 µm in camera x, y,
z; 0.043, 0.036, 0.018 mrad in pitch, yaw, roll), drawn with exactly those uncertainties.
``--noise twin``: the twin's default instrument (0.03 mm per axis, 0.1 mrad).

Robot time: every move at the plan's joint speed and acceleration (the controller's
trapezoid), plus 0.70 s at each pose (settling, pan, capture: the median measured on the
simulated cell), plus the move home; the full loop the same way (its legs as planned).

Tables: the false-alarm rate over healthy checks (baselines × checks, new noise each); power
and median robot time for tilts (εx, εy) of 0.1 and 0.5 mrad on joints 1–3; and for each
effect family appearing after the baseline.

    .venv/bin/python benchmarks/quick_check.py [--noise sim|twin] [--baselines 10] [--checks 20]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

from quickhealth.identify import quickcheck as qc  # noqa: E402
from quickhealth.identify.measurements import Measurements  # noqa: E402
from quickhealth.identify.transforms import R_to_rpy  # noqa: E402
from quickhealth.identify.twin import make_twin, twin_from_truth  # noqa: E402
from quickhealth.station.services import checking  # noqa: E402
from quickhealth.station.services.fitting import assess  # noqa: E402
from quickhealth.station.services.options import FitOptions  # noqa: E402

SIM_SIGMA_POS = np.array([1.1e-6, 0.9e-6, 3.3e-6])  # m, camera x y z
SIM_SIGMA_RPY = np.array([4.3e-5, 3.6e-5, 1.8e-5])  # rad, pitch yaw roll
DWELL_S = 0.70


def reference_plan():  # type: ignore[no-untyped-def]
    from quickhealth.station.planning import load_cell
    from quickhealth.station.planning.planfile import plan_from_dict, plan_to_dict
    from quickhealth.station.planning.planner import plan_loop

    cell = load_cell("reference")
    return plan_from_dict(plan_to_dict(plan_loop(cell, 150, 0)), "reference plan"), cell


class Instrument:
    """Measures a twin at joints in execution order with the chosen noise."""

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def measure(self, twin, q, ids, rng, time_s=None):  # type: ignore[no-untyped-def]
        n = len(q)
        T = twin.true_pose(q, time=time_s)
        if self.kind == "twin":
            sp, sr = np.full((n, 3), 3e-5), np.full((n, 3), 1e-4)
        else:
            sp, sr = np.tile(SIM_SIGMA_POS, (n, 1)), np.tile(SIM_SIGMA_RPY, (n, 1))
        pos = T[:, :3, 3] + rng.normal(size=(n, 3)) * sp
        rpy = R_to_rpy(T[:, :3, :3]) + rng.normal(size=(n, 3)) * sr
        return Measurements(
            q=q, pos=pos, rpy=rpy, sigma_pos=sp, sigma_rpy=sr, pose_id=tuple(ids),
            time=None if time_s is None else np.asarray(time_s, float),
        )  # fmt: skip


def baseline_of(twin, plan, inst, rng) -> checking.Baseline:  # type: ignore[no-untyped-def]
    q = plan.q
    ids = [p.name for p in plan.poses]
    m = inst.measure(twin, q, ids, rng, time_s=np.arange(len(q)) * 3.0)
    fitted = assess(replace(m, time=None), twin.robot, FitOptions(workspace_samples=200)).fitted
    return checking.Baseline(Path("."), fitted, replace(m, time=None), "twin", "", "twin")


def run_check(twin, plan, base, model, inst, rng, time_effect=False):  # type: ignore[no-untyped-def]
    """One check; returns (verdict, poses, robot time s, changes, named family)."""
    run = qc.CheckRun(model, base.fitted)
    q_now = plan.home.copy()
    left = list(plan.poses)
    visited: list = []
    t = 0.0
    times: list[float] = []
    meas = None
    while left:
        if run.stop_reason() is not None:
            break
        rows = base.measurements.subset(
            np.array([model.pairs[p.name] for p in left])
        )  # noise of the baseline's measurement of the pose
        rows = replace(rows, q=np.array([p.q for p in left]), time=None)
        ranked = checking.rank_candidates(model, base, plan, meas, q_now, left, rows, DWELL_S)
        p = ranked[0]
        t += checking.joint_move_s(plan, q_now, p.q) + DWELL_S
        visited.append(p)
        times.append(t)
        left.remove(p)
        q_now = p.q
        q = np.array([v.q for v in visited])
        meas = inst.measure(twin, q, [v.name for v in visited], rng,
                            time_s=np.array(times) if time_effect else None)  # fmt: skip
        meas = replace(meas, time=None)
        run.update(meas)
    t += checking.joint_move_s(plan, q_now, plan.home)
    ch = run.status.changes() if run.status is not None else []
    if run.status is not None and run.status.omnibus_probability > (ch[0].probability if ch else 0):
        ch = [replace(ch[0], family="other") if ch else _Other()]
    return run.verdict, len(visited), t, ch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--noise", choices=("sim", "twin"), default="sim")
    ap.add_argument("--baselines", type=int, default=10)
    ap.add_argument("--checks", type=int, default=20, help="healthy checks per baseline")
    ap.add_argument("--power-checks", type=int, default=20, help="checks per changed robot")
    ap.add_argument("--skip", default="", help="comma list: healthy,tilts,effects")
    a = ap.parse_args()
    skip = set(a.skip.split(","))
    inst = Instrument(a.noise)
    plan, cell = reference_plan()
    full = checking.plan_loop_s(plan, DWELL_S)
    print(f"reference plan: {len(plan.poses)} poses, full loop {full:.1f} s of robot time "
          f"(dwell {DWELL_S} s), noise {a.noise}", flush=True)  # fmt: skip
    from quickhealth.station.sim.world import build_world

    w = build_world("reference", twin_seed=1).twin
    T_ib, T_ft = w.truth.T_instr_base, w.truth.T_flange_target
    settings = qc.CheckSettings()

    # ---- healthy: false alarms
    bases = []
    for b in range(a.baselines):
        rng = np.random.default_rng(1000 + b)
        twin = make_twin(w.robot, seed=1 + b, T_instr_base=T_ib, T_flange_target=T_ft)
        base = baseline_of(twin, plan, inst, rng)
        bases.append((twin, base, qc.change_model(base.fitted, settings, base.measurements)))
    if "healthy" not in skip:
        res = []
        t0 = time.perf_counter()
        for b, (twin, base, model) in enumerate(bases):
            rng = np.random.default_rng(2000 + b)
            for _ in range(a.checks):
                v, n, t, ch = run_check(twin, plan, base, model, inst, rng)
                res.append((v, n, t))
        v = [r[0] for r in res]
        n_fa = sum(x is qc.Decision.CHANGED for x in v)
        n_und = sum(x is qc.Decision.CONTINUE for x in v)
        ts = np.array([r[2] for r in res])
        ns = np.array([r[1] for r in res])
        lo, hi = _wilson(n_fa, len(res))
        print(f"\n## healthy robots ({a.baselines} baselines × {a.checks} checks; "
              f"{time.perf_counter() - t0:.0f} s)\n")  # fmt: skip
        print("| checks | changed (false alarms) | 95 % interval | undecided at the full loop "
              "| median poses | median robot time | 95th percentile robot time |")  # fmt: skip
        print("| --- | --- | --- | --- | --- | --- | --- |")
        print(f"| {len(res)} | {n_fa} ({100 * n_fa / len(res):.1f} %) | {100 * lo:.1f}–"
              f"{100 * hi:.1f} % | {n_und} | {np.median(ns):.0f} | {np.median(ts):.1f} s "
              f"({100 * np.median(ts) / full:.1f} % of the loop) | "
              f"{np.percentile(ts, 95):.1f} s ({100 * np.percentile(ts, 95) / full:.1f} %) |",
              flush=True)  # fmt: skip

    # ---- changed robots
    cases: list[tuple[str, dict, dict]] = []
    if "tilts" not in skip:
        for j in (1, 2, 3):
            for m in ("ex", "ey"):
                for size in (1e-4, 5e-4):
                    cases.append((f"j{j}.{m} {size * 1e3:.1f} mrad", {f"j{j}.{m}.c0": size}, {}))
    if "effects" not in skip:
        for name, size, words in (
            ("backlash:j2", 2e-4, "0.2 mrad play"),
            ("backlash:j2", 1e-3, "1.0 mrad play"),
            ("compliance:j2", 2e-6, "2e-6 rad/(N·m)"),
            ("compliance:j2", 1e-5, "1e-5 rad/(N·m)"),
            ("cyclic:j1:h11", 1e-4, "0.1 mrad"),
            ("cyclic:j1:h11", 5e-4, "0.5 mrad"),
            ("thermal", 1e-5, "1e-5 /K, 5 K warmer"),
            ("thermal", 4e-5, "4e-5 /K, 5 K warmer"),
            ("depthscale", 1e-4, "1e-4"),
            ("depthscale", 5e-4, "5e-4"),
            ("drift", 1e-6, "1 µm/s"),
        ):
            cases.append((f"{name} {words}", {}, {name: size}))
    if cases:
        print(f"\n## changed robots ({a.power_checks} checks each, over "
              f"{min(len(bases), 5)} baselines)\n")  # fmt: skip
        print("| change | changed (power) | named first (share of changed) | median poses | "
              "median robot time | % of the full loop |")  # fmt: skip
        print("| --- | --- | --- | --- | --- | --- |")
    for label, degrade, effects in cases:
        res = []
        for k in range(a.power_checks):
            twin, base, model = bases[k % min(len(bases), 5)]
            truth = twin.truth
            if degrade:
                from quickhealth.station.sim.world import degrade_truth

                tw = twin_from_truth(degrade_truth(truth, degrade), twin.robot)
            else:
                b = k % min(len(bases), 5)
                tw = make_twin(w.robot, seed=1 + b, T_instr_base=T_ib, T_flange_target=T_ft,
                               effects=effects)  # fmt: skip
            rng = np.random.default_rng(3000 + k)
            needs_time = any(e in effects for e in ("drift",))
            if "thermal" in effects:
                tw = _thermal(tw)
            v, n, t, ch = run_check(tw, plan, base, model, inst, rng, time_effect=needs_time)
            res.append((v, n, t, ch[0].family if ch else "-"))
        hit = [r for r in res if r[0] is qc.Decision.CHANGED]
        names: dict[str, int] = {}
        for r in hit:
            names[r[3]] = names.get(r[3], 0) + 1
        top = sorted(names.items(), key=lambda x: -x[1])[:2]
        tmed = float(np.median([r[2] for r in res]))
        print(f"| {label} | {len(hit)}/{len(res)} ({100 * len(hit) / len(res):.0f} %) | "
              f"{', '.join(f'{k} {v}' for k, v in top) or '–'} | "
              f"{np.median([r[1] for r in res]):.0f} | {tmed:.1f} s | {100 * tmed / full:.1f} % |",
              flush=True)  # fmt: skip


def _thermal(tw):  # type: ignore[no-untyped-def]
    """The twin 5 K warmer than at its baseline (thermal needs a temperature)."""

    class Warm:
        robot = tw.robot
        truth = tw.truth

        def true_pose(self, q, time=None):  # type: ignore[no-untyped-def]
            return tw.true_pose(q, temp=np.full(len(q), 25.0))

    return Warm()


class _Other:
    family = "other (omnibus)"


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


if __name__ == "__main__":
    main()
