"""Digital twin: a "true" robot with known errors that produces measurements.

The twin is what the tests, the demo and the station's simulated cell measure.  It is a robot
(any :class:`~quickhealth.identify.robot.RobotModel`, the UR5 by default) with

- random small geometric errors (every joint's six constant error motions),
- position-dependent joint errors of the paper's kind (a few low-order Chebyshev terms:
  angular positioning, radial run-out, wobble),
- any set of physical effects (:mod:`quickhealth.identify.effects`) with given parameters,
- encoder noise on the joint readings and instrument noise on the measured pose,

seen by an instrument (a stereo camera) about 2 m in front of the robot.  Everything is drawn
from one seed, so a twin and its measurements are reproducible.  :class:`TwinTruth` holds
what the twin really is, as plain numbers (``to_dict`` / ``from_dict`` for a truth JSON file).

SYNOPSIS::

    from quickhealth.identify.twin import make_twin, random_joints
    twin = make_twin(seed=1, effects={"backlash:j2": 4e-4})
    q = random_joints(twin.robot, 150, seed=2, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=3)                 # Measurements, execution order = row order
    T = twin.true_pose(q)                          # noise-free T_instr_target, (n, 4, 4)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import (
    Effect,
    EffectContext,
    Perturbation,
    effect_context,
    missing_channels,
    parse_effect,
    total_perturbation,
)
from .errormodel import ErrorModelSpec
from .linearize import loop_pose
from .measurements import Measurements
from .robot import RobotModel, ur5
from .transforms import R_to_rpy, exp_so3, inv_T, make_T, rot_x, rot_z

F = NDArray[np.float64]

#: Instrument noise of the acceptance data sets: 0.03 mm per axis, 0.1 mrad per axis.
SIGMA_POS = 3e-5
SIGMA_ROT = 1e-4


def camera_pose(
    distance: float = 2.0, height: float = 0.6, azimuth: float = 0.0, look_at_z: float = 0.25
) -> F:
    """``T_instr_base`` of a camera ``distance`` m from the robot base, looking at it.

    The camera stands at azimuth ``azimuth`` (rad, about base z, 0 = base +x), ``height`` m
    above the base, with its optical axis (instrument z) through the point ``look_at_z`` m
    above the base; instrument x is horizontal, y points down-ish (image convention).
    """
    c = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), height])
    z = np.array([0.0, 0.0, look_at_z]) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T_base_cam = make_T(np.stack([x, y, z], axis=1), c)
    return inv_T(T_base_cam)


@dataclass(frozen=True, eq=False)
class TwinTruth:
    """What the twin really is (SI units).  Serialisable with :meth:`to_dict`.

    Attributes
    ----------
    robot : str
        Robot name (``ur5`` for the built-in).
    T_instr_base : ndarray, shape (4, 4)
        True robot base in the instrument frame.
    T_flange_target : ndarray, shape (4, 4)
        True target on the flange.
    orders : ndarray of int, shape (nj + 2, 6)
        Chebyshev orders of the true error model (base and tool rows are -1: the true base
        and tool are the two transforms above).
    q_lo, q_hi : ndarray, shape (nj,), rad
        Ranges the true Chebyshev series are mapped over.
    coeffs : ndarray, shape (n_params,)
        True Chebyshev coefficients (m, rad), in :meth:`ErrorModelSpec.index` order.
    effects : dict of str to list of float
        Physical effects and their true parameters (SI, in each effect's ``param_names`` order).
    sigma_pos : float, m
        Instrument noise per position axis.
    sigma_rot : float, rad
        Instrument noise per rotation axis (rotation vector in the instrument frame).
    sigma_q : float, rad
        Encoder noise per joint reading.
    seed : int
    """

    robot: str
    T_instr_base: F
    T_flange_target: F
    orders: NDArray[np.int64]
    q_lo: F
    q_hi: F
    coeffs: F
    effects: dict[str, list[float]] = field(default_factory=dict)
    sigma_pos: float = SIGMA_POS
    sigma_rot: float = SIGMA_ROT
    sigma_q: float = 0.0
    seed: int = 0

    @property
    def spec(self) -> ErrorModelSpec:
        """The true error model's orders and ranges."""
        return ErrorModelSpec(self.orders, self.q_lo, self.q_hi)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (SI units, with ``units`` saying so)."""
        return {
            "schema": "quickhealth.twin-truth/1",
            "units": "SI (m, rad, s, 1/K); effects in each effect's param_names order",
            "robot": self.robot,
            "T_instr_base": self.T_instr_base.tolist(),
            "T_flange_target": self.T_flange_target.tolist(),
            "chebyshev": {
                "orders": self.orders.tolist(),
                "q_lo": self.q_lo.tolist(),
                "q_hi": self.q_hi.tolist(),
                "coeffs": self.coeffs.tolist(),
                "labels": self.spec.labels(),
            },
            "effects": {k: list(map(float, v)) for k, v in self.effects.items()},
            "sigma_pos": self.sigma_pos,
            "sigma_rot": self.sigma_rot,
            "sigma_q": self.sigma_q,
            "seed": self.seed,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TwinTruth:
        """Inverse of :meth:`to_dict`."""
        ch = d["chebyshev"]
        return cls(
            robot=str(d["robot"]),
            T_instr_base=np.asarray(d["T_instr_base"], dtype=float),
            T_flange_target=np.asarray(d["T_flange_target"], dtype=float),
            orders=np.asarray(ch["orders"], dtype=np.int64),
            q_lo=np.asarray(ch["q_lo"], dtype=float),
            q_hi=np.asarray(ch["q_hi"], dtype=float),
            coeffs=np.asarray(ch["coeffs"], dtype=float),
            effects={k: list(map(float, v)) for k, v in d.get("effects", {}).items()},
            sigma_pos=float(d["sigma_pos"]),
            sigma_rot=float(d["sigma_rot"]),
            sigma_q=float(d.get("sigma_q", 0.0)),
            seed=int(d.get("seed", 0)),
        )


@dataclass(frozen=True, eq=False)
class Twin:
    """A robot with known errors and an instrument that measures it (see module docstring)."""

    robot: RobotModel
    truth: TwinTruth
    effects: tuple[Effect, ...] = ()

    def context(
        self,
        q: ArrayLike,
        time: ArrayLike | None = None,
        temp: ArrayLike | None = None,
        approach: ArrayLike | None = None,
        *,
        joint_temp: ArrayLike | None = None,
        joint_torque: ArrayLike | None = None,
    ) -> EffectContext:
        """The effects' context for joints ``q`` (n, nj) in execution order."""
        return effect_context(self.robot, q, approach, time, temp, joint_temp, joint_torque)  # type: ignore[arg-type]

    def perturbation(self, ctx: EffectContext) -> Perturbation:
        """Sum of the true effects' perturbations."""
        params = [np.asarray(self.truth.effects[e.name]) for e in self.effects]
        return total_perturbation(self.effects, params, ctx)

    def true_pose(
        self,
        q: ArrayLike,
        time: ArrayLike | None = None,
        temp: ArrayLike | None = None,
        approach: ArrayLike | None = None,
        *,
        seen: bool = True,
        joint_temp: ArrayLike | None = None,
        joint_torque: ArrayLike | None = None,
    ) -> F:
        """Noise-free true ``T_instr_target`` (n, 4, 4) for encoder angles ``q`` (rad).

        ``q`` is in execution order: unless ``approach`` is given, each joint's approach
        direction comes from the previous row (the first row counts as approached from
        below).  ``time`` (s), ``temp`` (°C), ``joint_temp`` (°C) and ``joint_torque`` (N·m,
        both (n, nj)) are needed when the twin has effects that use them
        (:func:`joint_schedules` makes the last two).  With ``seen`` (the default) a
        depth-scale effect is applied: this is the pose the instrument *sees*;
        ``seen=False`` is where the target really is (the instrument's own errors left out).
        """
        ctx = self.context(
            q, time, temp, approach, joint_temp=joint_temp, joint_torque=joint_torque
        )
        self._check_columns(ctx)
        pert = self.perturbation(ctx)
        if not seen:
            pert = replace(pert, instr_scale_z=None)
        t = self.truth
        return loop_pose(
            self.robot,
            t.spec,
            t.coeffs,
            t.T_instr_base,
            t.T_flange_target,
            ctx.q,
            pert,
        )

    def measure(
        self,
        q: ArrayLike,
        time: ArrayLike | None = None,
        temp: ArrayLike | None = None,
        seed: int | None = None,
        orientation: bool = True,
        meta: Mapping[str, str] | None = None,
        *,
        joint_temp: ArrayLike | None = None,
        joint_torque: ArrayLike | None = None,
    ) -> Measurements:
        """Measurements of the twin at encoder angles ``q`` (n, nj), rad, in execution order.

        The instrument adds Gaussian noise (``sigma_pos`` per axis, ``sigma_rot`` per
        rotation axis); the joint readings carry ``sigma_q`` encoder noise.  ``seed``
        defaults to the twin's seed + 1.  ``orientation=False`` gives position-only data.
        The conditions given (``time``, ``temp``, ``joint_temp``, ``joint_torque``) act on
        the true pose and are recorded with the measurements, as a controller reports them.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rng = np.random.default_rng(self.truth.seed + 1 if seed is None else seed)
        T = self.true_pose(q, time, temp, joint_temp=joint_temp, joint_torque=joint_torque)
        n = q.shape[0]
        pos = T[:, :3, 3] + rng.normal(0.0, self.truth.sigma_pos, (n, 3))
        rpy = None
        if orientation:
            R = exp_so3(rng.normal(0.0, self.truth.sigma_rot, (n, 3))) @ T[:, :3, :3]
            rpy = R_to_rpy(R)
        q_read = q + rng.normal(0.0, self.truth.sigma_q, q.shape) if self.truth.sigma_q else q
        return Measurements(
            q=q_read,
            pos=pos,
            rpy=rpy,
            time=None if time is None else np.asarray(time, dtype=float).reshape(-1).copy(),
            temp=None if temp is None else np.asarray(temp, dtype=float).reshape(-1).copy(),
            joint_temp=None if joint_temp is None else np.array(joint_temp, dtype=float),
            joint_torque=None if joint_torque is None else np.array(joint_torque, dtype=float),
            pose_id=tuple(f"p{i:04d}" for i in range(n)),
            meta={"instrument": "digital twin", "twin_seed": str(self.truth.seed), **(meta or {})},
        )

    def _check_columns(self, ctx: EffectContext) -> None:
        for e in self.effects:
            for col in missing_channels(e, ctx):
                raise ValueError(f"the twin's effect {e.name} needs a {col!r} schedule")


def simulate(
    twin: Twin,
    q: ArrayLike,
    time: ArrayLike | None = None,
    temp: ArrayLike | None = None,
    seed: int | None = None,
    orientation: bool = True,
) -> tuple[Measurements, TwinTruth]:
    """Measurements of ``twin`` at joints ``q`` (execution order) and the truth behind them."""
    return twin.measure(q, time, temp, seed=seed, orientation=orientation), twin.truth


def effect_params(effect: Effect, size: float | Sequence[float], rng: np.random.Generator) -> F:
    """Parameters of ``effect`` from a size (SI) or an explicit parameter list.

    A scalar size is read by the effect (:meth:`~quickhealth.identify.effects.Effect.
    twin_params`): e.g. compliance ``c`` (rad/(N·m)); backlash play ``b`` (rad); cyclic
    amplitude (rad) at a random phase; thermal ``α`` (1/K); drift translation rate (m/s) in a
    random direction, with a rotation rate of size / 1 m (rad/s) about a random axis;
    depthscale ``s``.
    """
    if not np.isscalar(size):
        p = np.asarray(size, dtype=float)
        if p.shape != (effect.n_params,):
            raise ValueError(f"{effect.name} takes {effect.n_params} parameters, got {p.shape}")
        return p
    return np.asarray(effect.twin_params(float(size), rng), dtype=float)  # type: ignore[arg-type]


def make_twin(
    robot: RobotModel | None = None,
    *,
    seed: int = 0,
    effects: Mapping[str, float | Sequence[float]] | None = None,
    geometric_pos: float = 1e-4,
    geometric_rot: float = 3e-4,
    position_dependent: bool = True,
    sigma_pos: float = SIGMA_POS,
    sigma_rot: float = SIGMA_ROT,
    sigma_q: float = 0.0,
    T_instr_base: ArrayLike | None = None,
    T_flange_target: ArrayLike | None = None,
) -> Twin:
    """A twin with random errors drawn from ``seed``.

    Parameters
    ----------
    robot : RobotModel, optional
        The nominal robot (default: the built-in UR5).
    seed : int
        Draws every error and, by default, the measurement noise.
    effects : mapping of effect name to size or parameter list, optional
        Hidden physical effects (see :func:`effect_params` for what a scalar size means).
    geometric_pos, geometric_rot : float, m and rad
        Standard deviation of the constant (geometric) error motions of every joint.
    position_dependent : bool
        Add the paper's kind of position-dependent joint errors: per joint an angular
        positioning error with orders 1–3 and a radial run-out/wobble of order 1–2, each a
        few tens of µm or µrad.
    sigma_pos, sigma_rot, sigma_q : float
        Instrument position (m), instrument rotation (rad) and encoder (rad) noise.
    T_instr_base : array (4, 4), optional
        Robot base in the instrument (default: :func:`camera_pose`, 2 m away); the twin
        adds a small random error to it.
    T_flange_target : array (4, 4), optional
        Target on the flange (default: 40 mm out, 60 mm along the flange axis).

    Returns
    -------
    Twin
    """
    robot = ur5() if robot is None else robot
    rng = np.random.default_rng(seed)
    nj = robot.n_joints
    orders = np.full((nj + 2, 6), -1, dtype=np.int64)
    orders[1:-1] = 0
    if position_dependent:
        for j in range(1, nj + 1):
            orders[j, 5] = rng.integers(1, 4)  # angular positioning, order 1..3
            m = rng.integers(0, 5)  # one radial / tilt motion with order 1..2
            orders[j, m] = max(orders[j, m], rng.integers(1, 3))
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    spec = ErrorModelSpec(orders, lo, hi)
    coeffs = np.empty(spec.n_params)
    for i, (_, m, k) in enumerate(spec.index()):
        scale = geometric_pos if m < 3 else geometric_rot
        coeffs[i] = rng.normal(0.0, scale if k == 0 else 0.5 * scale)
    T_ib = camera_pose() if T_instr_base is None else np.asarray(T_instr_base, dtype=float)
    T_ib = T_ib @ make_T(
        exp_so3(rng.normal(0.0, 2e-3, 3)), rng.normal(0.0, 2e-3, 3)
    )  # the set-up is never where the drawing says
    if T_flange_target is None:
        T_ft = make_T(rot_z(0.3) @ rot_x(0.2), [0.04, 0.0, 0.06])
    else:
        T_ft = np.asarray(T_flange_target, dtype=float)
    parsed: list[Effect] = []
    true_params: dict[str, list[float]] = {}
    for name, size in (effects or {}).items():
        e = parse_effect(name, robot)
        parsed.append(e)
        true_params[e.name] = list(map(float, effect_params(e, size, rng)))
    truth = TwinTruth(
        robot=robot.name,
        T_instr_base=T_ib,
        T_flange_target=T_ft,
        orders=orders,
        q_lo=lo,
        q_hi=hi,
        coeffs=coeffs,
        effects=true_params,
        sigma_pos=sigma_pos,
        sigma_rot=sigma_rot,
        sigma_q=sigma_q,
        seed=seed,
    )
    return Twin(robot=robot, truth=truth, effects=tuple(parsed))


def twin_from_truth(truth: TwinTruth, robot: RobotModel | None = None) -> Twin:
    """Rebuild a twin from its truth (e.g. a truth JSON file read by the station)."""
    robot = ur5() if robot is None else robot
    return Twin(
        robot=robot,
        truth=truth,
        effects=tuple(parse_effect(n, robot) for n in truth.effects),
    )


def random_joints(
    robot: RobotModel,
    n: int,
    seed: int = 0,
    T_instr_base: ArrayLike | None = None,
    T_flange_target: ArrayLike | None = None,
    fov_half_angle: float = np.deg2rad(30.0),
    min_height: float = 0.05,
) -> F:
    """``n`` random reachable joint sets (rad) with the target in view of the instrument.

    Joints are drawn uniformly (UR5-like ranges: shoulder pan and wrists over ±π, shoulder
    lift over [−π, 0], elbow over ±2.8 rad); a set is kept when the target is at least
    ``min_height`` above the base plane, not inside the robot's own column (radius 0.15 m),
    and within ``fov_half_angle`` of the instrument's optical axis (its z).  The order of
    rows is random, so approach directions of every joint are mixed.
    """
    rng = np.random.default_rng(seed)
    T_ib = camera_pose() if T_instr_base is None else np.asarray(T_instr_base, dtype=float)
    T_ft = (
        make_T(rot_z(0.3) @ rot_x(0.2), [0.04, 0.0, 0.06])
        if T_flange_target is None
        else np.asarray(T_flange_target, dtype=float)
    )
    nj = robot.n_joints
    lo = np.full(nj, -np.pi)
    hi = np.full(nj, np.pi)
    if nj >= 3:
        lo[1], hi[1] = -np.pi, 0.0
        lo[2], hi[2] = -2.8, 2.8
    lo = np.maximum(lo, robot.q_min)
    hi = np.minimum(hi, robot.q_max)
    out: list[F] = []
    have = 0
    for _ in range(200):
        q = rng.uniform(lo, hi, (max(4 * n, 64), nj))
        p_base = (robot.fk(q) @ T_ft)[:, :3, 3]
        p_cam = p_base @ T_ib[:3, :3].T + T_ib[:3, 3]
        ang = np.arctan2(np.linalg.norm(p_cam[:, :2], axis=1), p_cam[:, 2])
        ok = (
            (p_base[:, 2] > min_height)
            & (np.linalg.norm(p_base[:, :2], axis=1) > 0.15)
            & (p_cam[:, 2] > 0)
            & (ang < fov_half_angle)
        )
        out.append(q[ok])
        have += int(ok.sum())
        if have >= n:
            break
    q_all = np.concatenate(out)[:n]
    if q_all.shape[0] < n:
        raise ValueError(f"only {q_all.shape[0]} of {n} joint sets were in view")
    return q_all


def schedules(n: int, duration: float = 900.0, temp_rise: float = 6.0) -> tuple[F, F]:
    """Time (s) and temperature (°C) of ``n`` poses of a run: even steps, warm-up curve.

    The temperature starts at 21 °C and rises by ``temp_rise`` K towards a plateau
    (time constant a third of the run), as a cold robot warming up does.
    """
    t = np.linspace(0.0, duration, n)
    temp = 21.0 + temp_rise * (1.0 - np.exp(-3.0 * t / max(duration, 1e-9)))
    return t, temp


def joint_schedules(
    robot: RobotModel,
    q: ArrayLike,
    time: ArrayLike,
    temp: ArrayLike,
    payload_kg: float | ArrayLike = 0.0,
) -> tuple[F, F]:
    """Each joint's temperature (°C) and measured torque (N·m) at the poses ``q`` (n, nj) of
    a run at ``time`` (s) and ambient ``temp`` (°C): what a controller reports
    (:mod:`~quickhealth.identify.jointload`).

    The drives hold the arm and ``payload_kg`` (one mass, or one per pose: a gripper that
    picks and places) against gravity; the joints start at the ambient temperature (an arm
    just powered on) and warm with their duty.  Needs the robot's link masses.
    """
    from .jointload import drive_torques, warm_up

    tau = drive_torques(robot, q, payload_kg)
    return warm_up(time, q, tau, temp), tau


def payloads(n: int, max_kg: float, seed: int = 0) -> F:
    """``n`` payloads (kg) of a pick-and-place cell: each pose empty or carrying a part of up
    to ``max_kg``, drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    return np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0.2, 1.0, n) * max_kg)


def warm_run(
    twin: Twin,
    q: ArrayLike,
    seed: int,
    *,
    duration: float = 3600.0,
    temp_rise: float = 1.0,
    payload_kg: float = 2.0,
) -> Measurements:
    """Measurements of a run of the twin at ``q`` (n, nj) with every channel a controller
    reports: over ``duration`` s the air warms by ``temp_rise`` K and each joint by its duty
    (:func:`joint_schedules`), each pose empty or carrying up to ``payload_kg`` (the joint
    torques); noise drawn from ``seed``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    t, temp = schedules(len(q), duration, temp_rise)
    jt, tau = joint_schedules(twin.robot, q, t, temp, payloads(len(q), payload_kg, seed=seed))
    return twin.measure(q, t, temp, seed=seed, joint_temp=jt, joint_torque=tau)
