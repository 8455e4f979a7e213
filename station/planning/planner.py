"""The fixed-loop planner (METHOD.md §1, paper Sec. 3 and Fig. 3), steps 1–6.

1. Draw ``n`` random target poses in the cell's work volume above the table: positions
   uniform in the box, the marker normal aimed at the stereo midpoint and tilted by up to
   ``orientation_spread`` (uniform over the cap), rolled about itself uniformly.
2. Analytic IK (8 solutions); per candidate drop, in this order of reasons: ``unreachable``,
   ``joint-limits``, ``outside-fov``, ``not-facing``, ``occluded`` (by an obstacle or the
   table), ``collision`` (every in-limit solution collides), ``occluded`` (every
   collision-free solution hides the target behind its own links).
3. Order the survivors for a short closed loop: nearest neighbour, then 2-opt, in the time
   of a synchronous joint move (trapezoidal profile of the largest joint change, the
   cell's joint speed and acceleration) between the closest feasible configurations.
4. Walk the loop: for every pose and each feasible configuration test a linear (moveL) leg
   (Cartesian straight line of the target centre, slerp of its orientation; IK tracked
   sample by sample, every joint change ≤ ``continuity_max``, limits and collisions at
   every sample, sub-sampled so that no robot point moves more than ``clearance`` between
   checks) and a joint-space (moveJ) leg; a pose with neither is dropped
   (``no-feasible-leg``).  The loop's return leg to the first pose is checked the same way.
5. Among the feasible (configuration, leg) options choose the lowest
   ``score = E(q) − linear_preference·[leg is linear]`` with the evenness penalty
   ``E(q) = Σ_j (h_j(bin_j(q)) + 1) / (k/B + 1)``: the counts of the joint histograms (B
   bins over each joint's usable range, k poses kept so far) at the bins the new pose
   would fill, relative to a uniform fill.  Ties go to the shorter move.
6. Results as a :class:`PlanResult`; :mod:`.planfile` writes plan.json with its content hash
   and :mod:`.urscript` the program.

Everything is a pure function of (cell, n, seed).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from functools import cache

import numpy as np
from numpy.typing import NDArray

from ...identify.design import DesignPrior
from ...identify.errors import InputError
from ...identify.robot import RobotModel, ur5
from ...identify.transforms import exp_so3, inv_T, log_so3, make_T
from ..hardware.legs import Leg
from .cell import Cell
from .collision import CollisionWorld
from .ik_ur import ik_ur, within_limits
from .sight import PoseSight, pose_sight, robot_blockers, static_blockers

F = NDArray[np.float64]
Progress = Callable[[str, int, int], None]

# Largest distance of any robot or target point from each joint axis (m), for sweep sampling:
# the UR5's; other arms scale it by :func:`sweep_reach`.
_REACH = np.array([1.0, 1.0, 0.65, 0.35, 0.3, 0.25])
_TARGET_REACH = 0.15  # m the smart target reaches beyond the flange (not scaled with the arm)
USABLE_TAIL = 0.025


def _arm_reach(robot: RobotModel) -> F:
    """Per joint, the length of the links beyond it plus the target's (an upper bound of any
    point's distance from the joint's axis, m)."""
    t = np.linalg.norm(robot.links[1:, :3, 3], axis=1)  # (6,) link translations after joint i
    return np.cumsum(t[::-1])[::-1] + _TARGET_REACH


def sweep_reach(robot: RobotModel) -> F:
    """How far any robot or target point moves per radian of each joint (m/rad), for sampling
    legs: the UR5's figures scaled per joint by the arm's length beyond that joint against the
    UR5's (exactly the UR5's on the UR5)."""
    return _REACH * (_arm_reach(robot) / _ur5_arm_reach())


@cache
def _ur5_arm_reach() -> F:
    return _arm_reach(ur5())


class DropReason(StrEnum):
    """Why a generated target was not kept."""

    UNREACHABLE = "unreachable"
    JOINT_LIMITS = "joint-limits"
    OUTSIDE_FOV = "outside-fov"
    NOT_FACING = "not-facing"
    OCCLUDED = "occluded"
    COLLISION = "collision"
    NO_FEASIBLE_LEG = "no-feasible-leg"
    NOT_SELECTED = "not-selected"  # feasible, but plan --optimal kept others


@dataclass(frozen=True, eq=False)
class PlannedPose:
    """A kept pose of the loop, in execution order."""

    candidate: int  # index among the generated targets
    q: F  # (6,) rad, joint target
    leg: Leg  # how the robot arrives here from the previous pose
    branch: int  # IK solution index 0..7
    T_base_target: F  # (4, 4), target at pan 0
    T_world_target: F
    pan: float  # rad, pan motor angle facing the cameras
    facing: F  # (2,) rad, angle to left and right camera
    pixels: F  # (2, 2) target centre in left and right image, px
    leg_time_s: float  # estimated duration of the arriving leg
    name: str = ""  # the plan's name for it ("" : P001, P002 … by position)


@dataclass(frozen=True, eq=False)
class DroppedTarget:
    """A generated target that was not kept, with the reason."""

    candidate: int
    reason: DropReason
    detail: str
    T_world_target: F


@dataclass(frozen=True, eq=False)
class JointCoverage:
    """Coverage and evenness of each joint's kept values over its usable range (rad)."""

    usable_min: F  # (6,) range spanned by every feasible configuration of every candidate
    usable_max: F
    kept_min: F
    kept_max: F
    coverage: F  # (6,) part of the usable range inside the kept span
    evenness: F  # (6,) normalised entropy of the B-bin histogram over the usable range
    occupied: F  # (6,) fraction of the B bins with at least one kept pose
    bins: int
    feasible_min: F  # (6,) untrimmed extremes of every feasible configuration
    feasible_max: F
    coverage_full: F  # (6,) part of [feasible_min, feasible_max] inside the kept span


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Outcome of :func:`plan_loop`."""

    cell: Cell
    n_generated: int
    seed: int
    poses: tuple[PlannedPose, ...]
    dropped: tuple[DroppedTarget, ...]
    return_leg: Leg
    return_leg_time_s: float
    coverage: JointCoverage
    home: F | None = None  # (6,) rad; the first pose's leg_time_s is then the move from home
    design: dict[str, object] | None = None  # plan --optimal: the design's figures

    @property
    def dropped_by_reason(self) -> dict[str, int]:
        """Number of dropped targets per reason (every reason listed)."""
        out = {r.value: 0 for r in DropReason}
        for d in self.dropped:
            out[d.reason.value] += 1
        return out

    @property
    def loop_time_s(self) -> float:
        """Estimated time of one pass: legs, the return leg and the wait at each pose."""
        m = self.cell.motion
        return float(
            sum(p.leg_time_s for p in self.poses[1:])
            + self.return_leg_time_s
            + len(self.poses) * m.settle_s
        )

    def summary(self) -> list[str]:
        """The lines the command line prints."""
        by = ", ".join(f"{k} {v}" for k, v in self.dropped_by_reason.items() if v)
        n_lin = sum(p.leg == Leg.LINEAR for p in self.poses[1:])
        c = self.coverage
        cov = " ".join(f"{x * 100:.0f}%" for x in c.coverage)
        full = " ".join(f"{x * 100:.0f}%" for x in c.coverage_full)
        ev = " ".join(f"{x:.2f}" for x in c.evenness)
        return [
            f"generated {self.n_generated}, kept {len(self.poses)}, dropped {len(self.dropped)}"
            + (f" ({by})" if by else ""),
            f"legs: {n_lin} linear, {len(self.poses) - 1 - n_lin} joint-space, return {self.return_leg.value};"
            f" estimated loop time {self.loop_time_s:.0f} s",
            f"joint coverage of usable range (j1..j6): {cov}"
            f" (of the untrimmed feasible extremes: {full})",
            f"joint evenness (normalised entropy, {c.bins} bins; 1 = uniform): {ev}",
        ] + (
            []
            if self.design is None
            else [
                f"optimal design: {self.design['chosen']} of {self.design['candidates']} feasible "
                f"configurations ({self.design['information_poses']} by information, "
                f"{self.design['spread_poses']} to represent the workspace; prior: "
                f"{self.design['prior']}), predicted TCP band "
                f"{self.design['predicted_band_mm']:.4f} mm (random: "
                f"{self.design['random_band_mm']:.4f} mm)"
            ]
        )


def plan_loop(
    cell: Cell,
    n: int,
    seed: int = 0,
    progress: Progress | None = None,
    *,
    optimal: int | None = None,
    design_prior: DesignPrior | None = None,
) -> PlanResult:
    """Plan a fixed measurement loop of up to ``n`` poses in ``cell`` (steps 1–6).

    Parameters
    ----------
    cell : Cell
    n : int
        Number of random target poses to generate (the paper: 150).
    seed : int
        Seed of the random generator; the plan is a pure function of (cell, n, seed).
    progress : callable(stage, done, total), optional
    optimal : int, optional
        Keep only this many of the feasible targets, chosen by the optimal design of
        :mod:`.optimal` (``plan --optimal K``); the others are dropped as ``not-selected``.
    design_prior : DesignPrior, optional
        The design's prior (``plan --optimal K --baseline RUN_DIR``); default the stated one.

    Returns
    -------
    PlanResult

    Raises
    ------
    InputError
        ``n`` < 1 or > 100000, a camera whose view of the work volume is blocked, or no
        target survives.
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise InputError(f"--n: need at least 1 target pose, got {n}")
    if n > 100000:
        raise InputError(f"--n: {n} target poses is more than the planner handles (≤ 100000)")
    world = CollisionWorld(cell)
    _check_camera_view(cell, world)
    rng = np.random.default_rng(seed)
    T_wt = sample_targets(cell, n, rng)
    return _plan(cell, world, T_wt, seed, progress or (lambda s, i, k: None), optimal, design_prior)


def sample_targets(cell: Cell, n: int, rng: np.random.Generator) -> F:
    """Step 1: ``n`` random target poses ``T_world_target`` (n, 4, 4) in the work volume."""
    p = cell.work_min + rng.random((n, 3)) * (cell.work_max - cell.work_min)
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    z0 = mid - p
    z0 /= np.linalg.norm(z0, axis=1, keepdims=True)
    x0 = np.cross(z0, [0.0, 0.0, 1.0])
    bad = np.linalg.norm(x0, axis=1) < 1e-6
    x0[bad] = np.cross(z0[bad], [1.0, 0.0, 0.0])
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    y0 = np.cross(z0, x0)
    cos_t = 1.0 - rng.random(n) * (1.0 - math.cos(cell.orientation_spread))
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = rng.uniform(-np.pi, np.pi, n)
    z = (
        (sin_t * np.cos(phi))[:, None] * x0
        + (sin_t * np.sin(phi))[:, None] * y0
        + cos_t[:, None] * z0
    )
    roll = rng.uniform(-np.pi, np.pi, n)
    xr = np.cross(y0, z)
    xr /= np.linalg.norm(xr, axis=1, keepdims=True)
    yr = np.cross(z, xr)
    x = np.cos(roll)[:, None] * xr + np.sin(roll)[:, None] * yr
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=-1), p)


def _check_camera_view(cell: Cell, world: CollisionWorld) -> None:
    """Refuse a cell whose camera cannot see the work volume past the obstacles."""
    lo, hi = cell.work_min, cell.work_max
    g = np.stack(np.meshgrid(*[np.linspace(0.1, 0.9, 3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    probes = lo + g * (hi - lo)
    for side, Tc in (("left", cell.T_world_cam_left), ("right", cell.T_world_cam_right)):
        c = Tc[:3, 3]
        for o in cell.obstacles:
            local = inv_T(o.T_world_obstacle) @ np.r_[c, 1.0]
            if o.shape == "box" and np.all(np.abs(local[:3]) <= o.size / 2):  # type: ignore[operator]
                raise InputError(
                    f"{cell.source}: camera.{side}.position_mm: inside obstacle {o.name!r}"
                )
            if (
                o.shape == "cylinder"
                and np.hypot(local[0], local[1]) <= o.radius
                and abs(local[2]) <= o.length / 2
            ):
                raise InputError(
                    f"{cell.source}: camera.{side}.position_mm: inside obstacle {o.name!r}"
                )
        blockers = []
        for p in probes:
            d = p - c
            u = d / np.linalg.norm(d)
            blockers.append(
                world.static_sight_blocker(c + 0.05 * u, p - 0.05 * u, cell.planner.sight_radius)
            )
        if all(b is not None for b in blockers):
            counts: dict[str, int] = {}
            for b in blockers:
                if b is not None:
                    counts[b] = counts.get(b, 0) + 1
            names = sorted(counts, key=lambda x: (-counts[x], x))
            raise InputError(
                f"{cell.source}: camera.{side}: view of the work volume blocked by {', '.join(repr(x) for x in names)}"
                f" (0 of {len(probes)} probe lines clear); move the camera or the obstacle"
            )


def _plan(
    cell: Cell,
    world: CollisionWorld,
    T_wt: F,
    seed: int,
    progress: Progress,
    optimal: int | None = None,
    design_prior: DesignPrior | None = None,
) -> PlanResult:
    robot = cell.robot
    n = len(T_wt)
    T_bw = inv_T(cell.T_world_base)
    T_bt = T_bw @ T_wt
    T_bf = T_bt @ inv_T(cell.T_flange_target)
    Q, valid = ik_ur(robot, T_bf)  # (n, 8, 6)
    inlim = valid & within_limits(np.where(valid[..., None], Q, 0.0), robot)
    sight = pose_sight(cell, T_wt)
    p_world = T_wt[:, :3, 3]

    reason, feasible = feasible_configurations(
        cell, world, Q, valid, inlim, sight, p_world, progress
    )
    alive = np.flatnonzero(feasible.any(1))
    dropped = [
        DroppedTarget(i, r[0], r[1], T_wt[i]) for i in range(n) if (r := reason[i]) is not None
    ]
    if len(alive) == 0:
        worst = max(DropReason, key=lambda r: sum(d.reason == r for d in dropped))
        raise InputError(
            f"{cell.source}: no target pose is feasible ({n} generated; most dropped as {worst.value!r}:"
            f" {next(d.detail for d in dropped if d.reason == worst)}); raise --n or check the cell"
        )

    q_feas = Q[alive][feasible[alive]]
    usable_min, usable_max = usable_range(q_feas)
    design = None
    if optimal is None:
        kept, ret = _order_and_legs(cell, world, Q, feasible, alive, T_bt, T_wt,
                                    (usable_min, usable_max), dropped, progress)  # fmt: skip
    else:  # plan --optimal K: an optimal design among the feasible, topped up for lost legs
        from .optimal import choose

        out: list[int] = []  # chosen targets that had no feasible leg: not chosen again
        for _ in range(3):
            progress("optimal design", 0, 1)
            pool = feasible.copy()
            pool[out] = False
            pick = choose(cell, Q, pool, optimal, design_prior)
            progress("optimal design", 1, 1)
            # the chosen targets, each with the configuration the design chose and, should
            # no leg reach that one, its other feasible configurations
            chosen = np.zeros_like(feasible)
            for i, _k in pick.pairs:
                chosen[i] = pool[i]
            prefer = dict(pick.pairs)
            trial: list[DroppedTarget] = []
            kept, ret = _order_and_legs(cell, world, Q, chosen, np.flatnonzero(chosen.any(1)),
                                        T_bt, T_wt, (usable_min, usable_max), trial, progress,
                                        prefer)  # fmt: skip
            lost = [d.candidate for d in trial]
            if len(kept) >= min(optimal, len(pick.pairs)) or not lost:
                break
            out += lost
        design = {**pick.as_dict(), "kept": len(kept)}
        taken = {i for i, _ in pick.pairs}
        dropped += trial
        dropped += [
            DroppedTarget(int(i), DropReason.NOT_SELECTED,
                          "feasible, not chosen by the optimal design", T_wt[i])
            for i in alive if int(i) not in taken
        ]  # fmt: skip
    poses = []
    for j, (i, k, leg, t) in enumerate(kept):
        poses.append(
            PlannedPose(
                candidate=i,
                q=Q[i, k].copy(),
                leg=Leg.JOINT if j == 0 else leg,
                branch=k,
                T_base_target=T_bt[i],
                T_world_target=T_wt[i],
                pan=float(sight.pan[i]),
                facing=sight.facing[i].copy(),
                pixels=sight.pixels[i].copy(),
                leg_time_s=t,
            )
        )
    dropped.sort(key=lambda d: d.candidate)
    return PlanResult(
        cell=cell,
        n_generated=n,
        seed=seed,
        poses=tuple(poses),
        dropped=tuple(dropped),
        return_leg=ret[0],
        return_leg_time_s=ret[1],
        coverage=joint_coverage(
            np.array([p.q for p in poses]),
            usable_min,
            usable_max,
            cell.planner.bins,
            q_feas.min(0),
            q_feas.max(0),
        ),
        home=cell.home,
        design=design,
    )


def _order_and_legs(
    cell: Cell,
    world: CollisionWorld,
    Q: F,
    feasible: NDArray[np.bool_],
    alive: NDArray[np.intp],
    T_bt: F,
    T_wt: F,
    usable: tuple[F, F],
    dropped: list[DroppedTarget],
    progress: Progress,
    prefer: dict[int, int] | None = None,
) -> tuple[list[tuple[int, int, Leg, float]], tuple[Leg, float]]:
    """Steps 3–5: order the ``alive`` targets, then their legs and configurations
    (``prefer``: a configuration per target tried before the others, plan --optimal's)."""
    order = order_tour(cell, Q[alive], feasible[alive])
    tour = [int(alive[k]) for k in order]
    first_k: int | None = None
    first_t = 0.0
    if cell.home is not None:
        tour, first_k, first_t = _start_from_home(cell, world, Q, feasible, tour)
    walker = _Walker(cell, world, Q, feasible, T_bt, usable[0], usable[1])
    walker.prefer = prefer or {}
    return _legs(walker, tour, (first_k, first_t), T_wt, dropped, progress)


def usable_range(q_feasible: F, tail: float = USABLE_TAIL) -> tuple[F, F]:
    """A joint's usable range in the cell: the central quantiles of its values over every
    feasible configuration (all IK branches) of every surviving candidate, (k, 6) → (6,), (6,).

    ``tail`` of the values is cut at each end so that a few isolated configurations (e.g. a
    shoulder just past ±180°) do not stretch the range.
    """
    return np.quantile(q_feasible, tail, axis=0), np.quantile(q_feasible, 1.0 - tail, axis=0)


def _start_from_home(
    cell: Cell, world: CollisionWorld, Q: F, feas: NDArray[np.bool_], tour: list[int]
) -> tuple[list[int], int, float]:
    """Rotate the loop to start at the pose closest (in moveJ time) to the home position
    that a collision-free moveJ from home reaches; returns (tour, configuration, time)."""
    home = cell.home
    assert home is not None
    hit = world.contacts(home[None])[0]
    if hit:
        raise InputError(
            f"{cell.source}: robot.home_deg: the home configuration collides ({hit[0]})"
        )
    m = cell.motion
    opts = []
    for pos, i in enumerate(tour):
        for k in np.flatnonzero(feas[i]):
            t = float(trap_time(np.abs(Q[i, k] - home).max(), m.joint_speed, m.joint_accel))
            opts.append((t, pos, int(k)))
    for t, pos, k in sorted(opts):
        if joint_leg_ok(cell, world, home, Q[tour[pos], k]):
            return tour[pos:] + tour[:pos], k, t
    raise InputError(
        f"{cell.source}: robot.home_deg: no feasible pose is reachable from home by a collision-free moveJ"
    )


def joint_coverage(
    q: F,
    usable_min: F,
    usable_max: F,
    bins: int,
    feasible_min: F | None = None,
    feasible_max: F | None = None,
) -> JointCoverage:
    """Coverage and evenness of kept joint values ``q`` (k, 6) over the usable ranges."""
    fmin = usable_min if feasible_min is None else feasible_min
    fmax = usable_max if feasible_max is None else feasible_max
    kmin, kmax = q.min(0), q.max(0)

    def part(lo: F, hi: F) -> F:
        inside = np.maximum(np.minimum(kmax, hi) - np.maximum(kmin, lo), 0.0)
        return inside / np.maximum(hi - lo, 1e-9)

    ev = np.empty(q.shape[1])
    occ = np.empty(q.shape[1])
    for j in range(q.shape[1]):
        h, _ = np.histogram(q[:, j], bins=bins, range=(usable_min[j], usable_max[j]))
        pr = h / max(h.sum(), 1)
        nz = pr[pr > 0]
        ev[j] = float(-(nz * np.log(nz)).sum() / math.log(bins))
        occ[j] = float((h > 0).mean())
    return JointCoverage(
        usable_min,
        usable_max,
        kmin,
        kmax,
        part(usable_min, usable_max),
        ev,
        occ,
        bins,
        fmin,
        fmax,
        part(fmin, fmax),
    )


def trap_time(d: F, v: float, a: float) -> F:
    """Duration of a rest-to-rest trapezoidal move of length ``d`` (elementwise)."""
    d = np.abs(d)
    return np.where(d > v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


def order_tour(cell: Cell, Q: F, feas: NDArray[np.bool_]) -> list[int]:
    """Step 3: nearest neighbour then 2-opt on the joint-move time between poses."""
    k = len(Q)
    if k <= 2:
        return list(range(k))
    Qm = np.where(feas[..., None], Q, np.nan)
    D = np.full((k, k), np.inf)
    for i in range(k):  # (k, 8, 8, 6) per row keeps memory small
        dq = np.abs(Qm[i][None, :, None, :] - Qm[:, None, :, :]).max(-1)
        D[i] = np.nanmin(np.where(np.isnan(dq), np.inf, dq).reshape(k, -1), axis=1)
    m = cell.motion
    C = trap_time(D, m.joint_speed, m.joint_accel)
    np.fill_diagonal(C, 0.0)
    # nearest neighbour from pose 0
    tour = [0]
    left = np.ones(k, dtype=bool)
    left[0] = False
    for _ in range(k - 1):
        c = np.where(left, C[tour[-1]], np.inf)
        nxt = int(np.argmin(c))
        tour.append(nxt)
        left[nxt] = False
    t = np.array(tour)
    # 2-opt on the closed loop (vectorised over the second edge)
    improved = True
    while improved:
        improved = False
        for i in range(k - 2):
            a, b = t[i], t[i + 1]
            j = np.arange(i + 2, k if i > 0 else k - 1)
            c_, d_ = t[j], t[(j + 1) % k]
            gain = C[a, b] + C[c_, d_] - C[a, c_] - C[b, d_]
            jb = int(np.argmax(gain)) if len(gain) else -1
            if jb >= 0 and gain[jb] > 1e-9:
                jj = j[jb]
                t[i + 1 : jj + 1] = t[i + 1 : jj + 1][::-1].copy()
                improved = True
    return [int(x) for x in t]


class _Walker:
    """Steps 4–5: leg feasibility and the evenness-driven choice of configurations."""

    def __init__(
        self,
        cell: Cell,
        world: CollisionWorld,
        Q: F,
        feas: NDArray[np.bool_],
        T_bt: F,
        lo: F,
        hi: F,
    ) -> None:
        self.cell = cell
        self.world = world
        self.Q = Q
        self.feas = feas
        self.T_bt = T_bt
        self.lo = lo
        self.hi = hi
        self.B = cell.planner.bins
        self.hist = np.zeros((6, self.B))
        self.k = 0
        self.T_target_flange = inv_T(cell.T_flange_target)
        self.members: list[tuple[int, int]] = []
        self.prefer: dict[int, int] = {}  # target -> configuration tried first (plan --optimal)

    def _bins(self, q: F) -> NDArray[np.intp]:
        u = (q - self.lo) / np.maximum(self.hi - self.lo, 1e-9)
        return np.clip((u * self.B).astype(int), 0, self.B - 1)

    def penalty(self, q: F) -> float:
        b = self._bins(q)
        expected = self.k / self.B
        return float(np.sum((self.hist[np.arange(6), b] + 1.0) / (expected + 1.0)))

    def add(self, choice: tuple[int, int, Leg, float]) -> None:
        i, k = choice[0], choice[1]
        b = self._bins(self.Q[i, k])
        self.hist[np.arange(6), b] += 1
        self.k += 1
        self.members.append((i, k))

    def remove(self, i: int) -> None:
        for n, (ii, k) in enumerate(self.members):
            if ii == i:
                b = self._bins(self.Q[ii, k])
                self.hist[np.arange(6), b] -= 1
                self.k -= 1
                del self.members[n]
                return

    def choose(
        self, i: int, prev: tuple[int, int, Leg, float] | None
    ) -> tuple[int, int, Leg, float] | None:
        ks = np.flatnonzero(self.feas[i])
        k0 = self.prefer.get(i)
        if k0 is not None and prev is not None:  # the design's configuration, if a leg reaches it
            leg = self.leg(prev, i, k0)
            if leg is not None:
                return (i, k0, leg[0], leg[1])
        if k0 is not None and prev is None:
            return (i, k0, Leg.JOINT, 0.0)
        if prev is None:
            pen = [self.penalty(self.Q[i, k]) for k in ks]
            return (i, int(ks[int(np.argmin(pen))]), Leg.JOINT, 0.0)
        best: tuple[float, float, tuple[int, int, Leg, float]] | None = None
        opts = sorted(ks, key=lambda k: self.penalty(self.Q[i, k]))
        for k in opts:
            pen = self.penalty(self.Q[i, k])
            if best is not None and pen - self.cell.planner.linear_preference > best[0]:
                break  # cannot beat the best even with a linear leg
            leg = self.leg(prev, i, int(k))
            if leg is None:
                continue
            score = pen - (self.cell.planner.linear_preference if leg[0] == Leg.LINEAR else 0.0)
            cand = (score, leg[1], (i, int(k), leg[0], leg[1]))
            if best is None or (score, leg[1]) < (best[0], best[1]):
                best = cand
        return None if best is None else best[2]

    def leg(self, prev: tuple[int, int, Leg, float], i: int, k: int) -> tuple[Leg, float] | None:
        """The preferred feasible leg from ``prev`` to configuration k of target i, or None."""
        q0 = self.Q[prev[0], prev[1]]
        q1 = self.Q[i, k]
        t = linear_leg_time(self.cell, self.T_bt[prev[0]], self.T_bt[i])
        if linear_leg_ok(self.cell, self.world, self.T_bt[prev[0]], q0, self.T_bt[i], q1):
            return (Leg.LINEAR, t)
        if joint_leg_ok(self.cell, self.world, q0, q1):
            m = self.cell.motion
            return (
                Leg.JOINT,
                float(trap_time(np.abs(q1 - q0).max(), m.joint_speed, m.joint_accel)),
            )
        return None


def linear_leg_time(cell: Cell, T_a: F, T_b: F) -> float:
    """Estimated duration of a moveL between two target poses (position-limited)."""
    d = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    m = cell.motion
    return float(trap_time(np.array(d), m.linear_speed, m.linear_accel))


def interpolate_linear(T_a: F, T_b: F, s: F) -> F:
    """Poses along a moveL: straight line of the origin, slerp of the orientation; (m, 4, 4)."""
    w = log_so3(T_a[:3, :3].T @ T_b[:3, :3])
    R = T_a[:3, :3] @ exp_so3(s[:, None] * w[None])
    p = T_a[:3, 3] + s[:, None] * (T_b[:3, 3] - T_a[:3, 3])
    return make_T(R, p)


def track_linear(cell: Cell, T_a: F, q_a: F, T_b: F, step: float, step_rot: float) -> tuple[F, F]:
    """Follow a moveL of the target from ``T_a`` (at ``q_a``) to ``T_b`` by IK.

    Returns the samples' parameters ``s`` (m,) and the tracked joints (m, 6): at every sample
    the IK solution nearest the previous one (NaN rows where no solution exists).
    """
    dist = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    ang = float(np.linalg.norm(log_so3(T_a[:3, :3].T @ T_b[:3, :3])))
    m = max(2, math.ceil(dist / step), math.ceil(ang / step_rot)) + 1
    s = np.linspace(0.0, 1.0, m)
    T_f = interpolate_linear(T_a, T_b, s) @ inv_T(cell.T_flange_target)
    Qs, V = ik_ur(cell.robot, T_f)
    out = np.full((m, 6), np.nan)
    cur = q_a
    out[0] = q_a
    for j in range(1, m):  # sequential by nature; 8 candidates per sample
        cand = Qs[j][V[j]]
        if len(cand) == 0:
            break
        d = cand - cur
        d = (d + np.pi) % (2 * np.pi) - np.pi  # nearest 2π-equivalent
        best = int(np.argmin(np.abs(d).max(1)))
        cur = cur + d[best]
        out[j] = cur
    return s, out


def linear_leg_ok(cell: Cell, world: CollisionWorld, T_a: F, q_a: F, T_b: F, q_b: F) -> bool:
    """Step 4: is the moveL from (T_a, q_a) to (T_b, q_b) continuous, in limits and free?"""
    pl = cell.planner
    _, qs = track_linear(cell, T_a, q_a, T_b, pl.leg_step, pl.leg_step_rot)
    if np.isnan(qs).any():
        return False
    dq = np.abs(np.diff(qs, axis=0))
    if dq.max() > pl.continuity_max or np.abs(qs[-1] - q_b).max() > 1e-6:
        return False
    if not within_limits(qs, cell.robot).all():
        return False
    if not line_within_joint_speeds(cell, T_a, q_a, T_b, qs):
        return False
    return world.first_collision(_sweep(qs, pl.clearance, sweep_reach(cell.robot))) < 0


#: Share of a joint's speed limit a linear leg may ask of it at the plan's linear speed.  The
#: controller refuses a line whose joints would exceed their limits at its cruise speed (a
#: protective stop); it checks on its own kinematics (its calibration) and samples, so the
#: plan keeps a margin.  Measured: the planner's peak and the simulated controller's agree
#: within 5 % (the reference plan's fastest line: 0.907 and 0.869 of the limit; the UR10e's
#: line past the shoulder: 1.459 and 1.44).
LINE_JOINT_SPEED_SHARE = 0.95
#: Sample spacing of that check (m, rad): as fine as the controller's own samples of a line
#: (the simulator's 5 mm / 0.02 rad).  Near a singularity a joint's rate peaks sharply and
#: the collision check's coarser samples average the peak away (1.24 x the limit at 10 mm
#: where the controller saw 1.44 x).
LINE_SPEED_STEP = (0.005, 0.02)


def line_within_joint_speeds(cell: Cell, T_a: F, q_a: F, T_b: F, qs: F) -> bool:
    """Does every joint stay within ``LINE_JOINT_SPEED_SHARE`` of its speed limit (the arm's
    ``qd_max``) along the line at the cell's linear speed?  A line near a singularity turns a
    joint fast at a modest TCP speed (the UR10e's base at 173 deg/s, limit 120 deg/s, on a
    250 mm/s line past the shoulder): such a leg goes in joint space.  ``qs`` is the line
    tracked at the collision check's spacing; a line that asks more than half a limit there
    is tracked again at :data:`LINE_SPEED_STEP` to find its peak."""
    qd_max = cell.robot.qd_max
    dist = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    if qd_max is None or dist <= 0.0 or len(qs) < 2:
        return True

    def share(q: F) -> float:
        rate = np.abs(np.diff(q, axis=0)).max(axis=0) * (len(q) - 1) / dist  # rad per m
        return float(np.max(rate * cell.motion.linear_speed / qd_max))

    if share(qs) <= 0.5:
        return True
    _, fine = track_linear(cell, T_a, q_a, T_b, *LINE_SPEED_STEP)
    return not np.isnan(fine).any() and share(fine) <= LINE_JOINT_SPEED_SHARE


def joint_leg_ok(cell: Cell, world: CollisionWorld, q_a: F, q_b: F) -> bool:
    """Step 4: is the moveJ (straight line in joint space) from q_a to q_b collision-free?"""
    d = np.abs(q_b - q_a)
    m = max(2, math.ceil(d.max() / cell.planner.joint_step)) + 1
    qs = q_a + np.linspace(0.0, 1.0, m)[:, None] * (q_b - q_a)
    reach = sweep_reach(cell.robot)
    return world.first_collision(_sweep(qs, cell.planner.clearance, reach)) < 0


def _sweep(qs: F, clearance: float, reach: F = _REACH) -> F:
    """Insert joint-space sub-samples so no robot point moves more than ``clearance`` between
    them (``reach``: m per rad of each joint, :func:`sweep_reach`)."""
    seg = np.abs(np.diff(qs, axis=0)) @ reach
    sub = np.maximum(1, np.ceil(seg / max(clearance, 1e-3)).astype(int))
    if np.all(sub == 1):
        return qs
    parts = [qs[:1]]
    for a, b, k in zip(qs[:-1], qs[1:], sub, strict=True):
        s = np.arange(1, k + 1)[:, None] / k
        parts.append(a + s * (b - a))
    return np.concatenate(parts)


def feasible_configurations(
    cell: Cell,
    world: CollisionWorld,
    Q: F,
    valid: NDArray[np.bool_],
    inlim: NDArray[np.bool_],
    sight: PoseSight,
    p_world: F,
    progress: Progress,
) -> tuple[list[tuple[DropReason, str] | None], NDArray[np.bool_]]:
    """Step 2: why each target is dropped (None: kept), and which of its IK configurations
    (n, 8) are collision-free and see the target."""
    n = len(Q)
    reason: list[tuple[DropReason, str] | None] = [None] * n
    for i in range(n):
        if not valid[i].any():
            reason[i] = (DropReason.UNREACHABLE, "no inverse-kinematics solution")
        elif not inlim[i].any():
            reason[i] = (
                DropReason.JOINT_LIMITS,
                f"all {int(valid[i].sum())} IK solutions outside the planning limits",
            )
        elif not sight.in_fov[i].all():
            sides = [s for s, ok in zip(("left", "right"), sight.in_fov[i], strict=True) if not ok]
            reason[i] = (
                DropReason.OUTSIDE_FOV,
                f"outside the {' and '.join(sides)} camera's image",
            )
        elif not sight.facing_ok[i]:
            f = np.degrees(sight.facing[i])
            reason[i] = (
                DropReason.NOT_FACING,
                f"marker turned {f.max():.0f}° from a camera (max {math.degrees(cell.facing_max):.0f}°)",
            )
    todo = [i for i in range(n) if reason[i] is None]
    blk = static_blockers(world, p_world[todo]) if todo else []
    for i, b in zip(todo, blk, strict=True):
        if b is not None:
            reason[i] = (DropReason.OCCLUDED, f"line of sight blocked by {b}")
    # per-configuration checks: collisions and self-occlusion
    feasible = np.zeros((n, 8), dtype=bool)
    todo = [i for i in range(n) if reason[i] is None]
    for c, i in enumerate(todo):
        progress("checking targets", c, len(todo))
        ks = np.flatnonzero(inlim[i])
        hits = world.contacts(Q[i, ks])
        free = [k for k, h in zip(ks, hits, strict=True) if not h]
        if not free:
            reason[i] = (
                DropReason.COLLISION,
                f"every in-limit IK solution collides ({hits[0][0]})",
            )
            continue
        bl = robot_blockers(world, Q[i, free], np.repeat(p_world[i][None], len(free), 0))
        seen = [k for k, b in zip(free, bl, strict=True) if b is None]
        if not seen:
            reason[i] = (DropReason.OCCLUDED, f"the robot hides the target ({bl[0]})")
            continue
        feasible[i, seen] = True
    progress("checking targets", len(todo), len(todo))

    return reason, feasible


def _legs(
    walker: _Walker,
    tour: list[int],
    first: tuple[int | None, float],
    T_wt: F,
    dropped: list[DroppedTarget],
    progress: Progress,
) -> tuple[list[tuple[int, int, Leg, float]], tuple[Leg, float]]:
    """Steps 4-5: a leg and configuration for each target of the tour (``first``: the first
    pose's configuration and time from home, if fixed), then the return leg, dropping
    trailing poses until it is feasible; the dropped targets are added to ``dropped``."""
    first_k, first_t = first
    kept: list[tuple[int, int, Leg, float]] = []
    for step, i in enumerate(tour):
        progress("checking legs", step, len(tour))
        if step == 0 and first_k is not None:
            choice: tuple[int, int, Leg, float] | None = (i, first_k, Leg.JOINT, first_t)
        else:
            choice = walker.choose(i, kept[-1] if kept else None)
        if choice is None:
            dropped.append(
                DroppedTarget(
                    i,
                    DropReason.NO_FEASIBLE_LEG,
                    "neither a linear nor a joint-space leg is collision-free",
                    T_wt[i],
                )
            )
            continue
        kept.append(choice)
        walker.add(choice)
    progress("checking legs", len(tour), len(tour))
    # the return leg closes the loop; drop trailing poses until it is feasible
    ret: tuple[Leg, float] | None = None
    while len(kept) > 1:
        ret = walker.leg(kept[-1], kept[0][0], kept[0][1])
        if ret is not None:
            break
        i_last = kept.pop()[0]
        walker.remove(i_last)
        dropped.append(
            DroppedTarget(
                i_last,
                DropReason.NO_FEASIBLE_LEG,
                "no collision-free return leg to the first pose",
                T_wt[i_last],
            )
        )
    if ret is None:
        ret = (Leg.JOINT, 0.0)

    return kept, ret
