"""Does a compensated program land?  The digital twin runs it, with and without each effect.

One trial per effect family (``benchmarks/compensate_effects.py`` prints the table, the tests
assert on the same numbers):

1. a twin robot (:func:`~quickhealth.identify.twin.make_twin`: geometric and position-dependent
   joint errors) hides one effect; it is measured at the measurement plan's poses with the
   instrument's noise (time and temperature from :func:`~quickhealth.identify.twin.schedules`);
2. the real fit (:func:`~quickhealth.identify.select.select_orders`, as ``identify fit`` runs
   it) makes two models: the joint error model alone, and the model with the effect added;
3. a reference program (joint targets in program order) is compensated with
   :func:`~quickhealth.identify.compensate.compensate_program`: by the joint model; by the
   model with the effect but the effect left out; by the model with the effect; the tool
   centre point is the measured target as each model identified it (:func:`fitted_tool`);
4. the twin executes each program at the stated conditions (``temp_c``, ``time_s``; every
   target at those conditions, approach directions from the program's own order) and the
   remaining TCP error is its true, noise-free target pose against the program's nominal
   pose.

**Where the nominal pose is.**  A joint-space compensation works in the frames of the nominal
robot registered to the model (:attr:`~quickhealth.identify.fit.FittedModel.registration`:
the base and tool that bring the nominal kinematics closest to the model over its identified
ranges), so it does not depend on how the fit split error between base, tool and joint
constants.  The yardstick uses the same frame, taken from a *reference fit* that no noise
disturbs: the twin's true model structure (its orders and its true effects) fitted to its
noise-free poses, which reproduces the twin to ~1e-8 m.  The nominal pose of target k is that
fit's ``nominal_pose(q_k)`` (registered base and tool, the links at 20 °C, the instrument at
time 0); every column of the table is measured against it.

**What the instrument noise allows** (the allowance): what remains when the model has the
right effects and only the noise limits it.  Two parts:

- the *paired* trial (``TrialRow.paired``): the twin with the same seed — the same geometric
  errors, poses and noise draws — without the effect, compensated by its joint model.  It
  holds the noise of the joint coefficients and the small joint terms the noise hides from
  the BIC search (about half of it on the reference trial: the fit covariance alone,
  :func:`tcp_sigma`, gives ~0.011 mm RMS against ~0.02 mm remaining);
- the noise of the effect's own parameters: the TCP variance they add, propagated from the
  fit's covariance (``TrialRow.effect_sigma``, ``sqrt(mean(σ_with² − σ_paired²))``).  A drift
  rate extrapolated to the end of the run, for one, is only known to the noise's precision.

``allowance = paired × sqrt(rms_paired² + effect_sigma²) / rms_paired`` (mean and max alike);
the acceptance compares the compensation with the effect against 1.3 × that.

SYNOPSIS::

    row = run_trial("backlash:j3", 4e-4, q_train, q_program, seed=11)
    row.with_effect.mean_pos, row.allowance_mean_pos          # m
    row.ratio                                                  # (mean, max), ≤ 1.3
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensate import Compensation, compensate_program, fitted_tool, pose_error
from .effects import parse_effects, total_perturbation
from .fit import FittedModel, fit_model
from .linearize import (
    InstrumentNoise,
    coefficient_columns,
    effect_jacobian,
    forward,
    motion_jacobian,
    sensitivities,
)
from .measurements import Measurements
from .select import data_spec, select_orders
from .transforms import R_to_rpy
from .twin import Twin, make_twin, schedules

F = NDArray[np.float64]

#: Conditions the twin runs the compensated program at: a warm afternoon (the training run
#: warmed from 21 to 27 °C) at the end of the measurement run's 900 s.
TRIAL_TEMP_C = 30.0
TRIAL_TIME_S = 900.0

#: The trial's cases: (effect name or None for the geometric model, size in SI, masses
#: withheld).  The sizes are those of the every-effect CLI test, each a few times the noise
#: floor in held-out RMS; the last row fits the compliance with the link masses withheld (the
#: lumped form).
FAMILIES: tuple[tuple[str | None, float, bool], ...] = (
    (None, 0.0, False),
    ("backlash:j3", 4e-4, False),
    ("compliance:j2", 2.5e-5, False),
    ("cyclic:j1:h9", 2e-4, False),
    ("thermal", 5e-5, False),
    ("drift", 2e-7, False),
    ("compliance:j2", 2.5e-5, True),
)


@dataclass(frozen=True, eq=False)
class TcpErrors:
    """Remaining TCP error of one executed program, per target: position (m), rotation (rad)."""

    pos: F
    rot: F

    @property
    def mean_pos(self) -> float:
        """Mean position error (m)."""
        return float(self.pos.mean())

    @property
    def max_pos(self) -> float:
        """Largest position error (m)."""
        return float(self.pos.max())

    @property
    def rms_pos(self) -> float:
        """Root mean square position error (m)."""
        return float(np.sqrt(np.mean(self.pos**2)))

    @property
    def mean_rot(self) -> float:
        """Mean rotation error (rad)."""
        return float(self.rot.mean())

    @property
    def max_rot(self) -> float:
        """Largest rotation error (rad)."""
        return float(self.rot.max())


@dataclass(frozen=True, eq=False)
class TrialRow:
    """One effect family's trial (module docstring); ``effect`` None is the geometric case,
    else the name the fit gave it (``compliance:j2:lumped`` when the masses were withheld).

    ``left_out`` and ``with_effect`` are None for the geometric case, where ``paired`` is the
    joint model's own result.  ``sigma_fit`` (m) is the RMS over targets of :func:`tcp_sigma`
    of the model that compensates (with the effect); ``effect_sigma`` (m) the part of it the
    effect's parameters add, ``sqrt(mean(σ_with² − σ_paired²))`` (0 if negative).
    ``n_dropped`` counts program targets ``compensate`` would refuse with one of the models
    (outside an identified joint range, no convergence near a singularity, a correction above
    1°); the trial leaves them out of the program.
    """

    effect: str | None
    size: float
    n_targets: int
    n_dropped: int
    uncompensated: TcpErrors
    joint_model: TcpErrors
    left_out: TcpErrors | None
    with_effect: TcpErrors | None
    paired: TcpErrors
    sigma_fit: float
    effect_sigma: float = 0.0
    effect_params: F | None = None  # fitted (SI)
    true_params: F | None = None

    @property
    def allowance_factor(self) -> float:
        """``sqrt(rms_paired² + effect_sigma²) / rms_paired``: the paired result widened by the
        noise of the effect's own parameters."""
        r0 = self.paired.rms_pos
        return float(np.sqrt(r0**2 + self.effect_sigma**2) / r0) if r0 > 0 else 1.0

    @property
    def allowance_mean_pos(self) -> float:
        """What the instrument noise allows, mean over the targets (m)."""
        return self.paired.mean_pos * self.allowance_factor

    @property
    def allowance_max_pos(self) -> float:
        """What the instrument noise allows, largest over the targets (m)."""
        return self.paired.max_pos * self.allowance_factor

    @property
    def ratio(self) -> tuple[float, float] | None:
        """Compensated with the effect over the allowance: (mean, max); None without effect."""
        if self.with_effect is None:
            return None
        return (
            self.with_effect.mean_pos / self.allowance_mean_pos,
            self.with_effect.max_pos / self.allowance_max_pos,
        )


def reference_fit(twin: Twin, q: ArrayLike, time: ArrayLike, temp: ArrayLike) -> FittedModel:
    """The twin's true model structure fitted to its noise-free poses at ``q`` (the yardstick's
    base and tool; module docstring)."""
    q = np.atleast_2d(np.asarray(q, float))
    T = twin.true_pose(q, time, temp)
    meas = Measurements(
        q=q,
        pos=T[:, :3, 3],
        rpy=R_to_rpy(T[:, :3, :3]),
        time=np.asarray(time, float),
        temp=np.asarray(temp, float),
    )
    orders = twin.truth.orders.copy()
    orders[[0, -1]] = 0  # base and tool corrections, as every fit has them
    # the series over the data's range, as the fit maps them: which constant of joint 1's
    # angular error is the base's rotation (held at zero) depends on the range
    spec = data_spec(twin.robot, meas).with_orders(orders)
    noise = InstrumentNoise(twin.truth.sigma_pos, twin.truth.sigma_rot)
    return fit_model(twin.robot, meas, spec, twin.effects, noise)


def executed_errors(twin: Twin, q_command: F, T_goal: F, temp_c: float, time_s: float) -> TcpErrors:
    """The twin runs ``q_command`` in order at ``temp_c`` / ``time_s``: its true target pose
    against ``T_goal`` (n, 4, 4), both in the instrument frame, without the instrument's own
    errors (an effect that perturbs only the instrument is not applied)."""
    n = len(q_command)
    T = twin.true_pose(q_command, np.full(n, time_s), np.full(n, temp_c), seen=False)
    e = pose_error(T, T_goal)
    return TcpErrors(np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1))


def tcp_sigma(
    fitted: FittedModel,
    q: ArrayLike,
    *,
    temp_c: float | None = None,
    time_s: float | None = None,
) -> F:
    """Standard uncertainty (m, 3D: ``sqrt(trace Σ)``) of the modelled target position at
    commands ``q`` from the fit's covariance of the joint coefficients and effect parameters.

    The linearised loop of the fit (:mod:`~quickhealth.identify.linearize`): coefficient
    columns from the motion Jacobian, effect columns from the channel sensitivities.
    """
    q = np.atleast_2d(np.asarray(q, float))
    n = len(q)
    time = None if time_s is None else np.full(n, time_s)
    temp = None if temp_c is None else np.full(n, temp_c)
    ctx = fitted.context(q, time=time, temp=temp)
    pert = total_perturbation(fitted.effects, fitted.effect_params, ctx)
    args = (
        fitted.robot,
        fitted.spec,
        fitted.coeffs,
        fitted.T_instr_base0,
        fitted.T_flange_target0,
        q,
        pert,
    )
    T, A, mot = forward(*args)
    assert A is not None
    cols = [coefficient_columns(fitted.spec, q, motion_jacobian(T, A, mot))[:, :3]]
    if fitted.effects:
        sens = sensitivities(*args)
        cols += [effect_jacobian(e, ctx, sens)[:, :3] for e in fitted.effects]
    J = np.concatenate(cols, axis=-1)  # (n, 3, n_all)
    base = fitted.spec.index()[:, 0] == 0
    sel = np.flatnonzero(np.concatenate([~base, np.ones(J.shape[-1] - base.size, bool)]))
    Js = J[:, :, sel]
    C = fitted.cov[np.ix_(sel, sel)]
    return np.sqrt(np.clip(np.einsum("nip,pq,niq->n", Js, C, Js), 0.0, None))


def _compensate(
    fitted: FittedModel, q: F, temp_c: float, time_s: float, leave_out: tuple[str, ...] = ()
) -> Compensation:
    kw = {"temp_c": temp_c, "time_s": time_s}
    return compensate_program(fitted, q, fitted_tool(fitted), leave_out=leave_out, **kw)


def _compensated_errors(
    twin: Twin,
    fitted: FittedModel,
    q: F,
    T_goal: F,
    temp_c: float,
    time_s: float,
    leave_out: tuple[str, ...] = (),
) -> tuple[TcpErrors, Compensation]:
    comp = _compensate(fitted, q, temp_c, time_s, leave_out)
    if not _accepted(comp).all():
        raise RuntimeError("a compensated target was not accepted")  # _usable removed them
    return executed_errors(twin, comp.q, T_goal, temp_c, time_s), comp


def _accepted(comp: Compensation) -> NDArray[np.bool_]:
    """Targets whose compensation converged with a settled approach direction."""
    ok = comp.converged.copy()
    if comp.approach_settled is not None:
        ok &= comp.approach_settled
    return ok


def _usable(
    fits: list[tuple[FittedModel, tuple[str, ...]]], q: F, temp_c: float, time_s: float
) -> NDArray[np.bool_]:
    """Program targets every model identified and ``compensate`` accepts with every model:
    inside each identified joint range; then, repeatedly (a removed target changes the next
    one's approach), those whose compensation converges, settles and stays within 1°."""
    ok = np.ones(len(q), bool)
    for f, _ in fits:
        ok &= np.all((q >= f.spec.q_lo) & (q <= f.spec.q_hi), axis=1)
    for _ in range(5):
        idx = np.flatnonzero(ok)
        good = np.ones(idx.size, bool)
        for f, leave in fits:
            comp = _compensate(f, q[idx], temp_c, time_s, leave)
            good &= _accepted(comp) & np.all(np.abs(comp.q - q[idx]) <= np.radians(1.0), axis=1)
        if good.all():
            return ok
        ok[idx[~good]] = False
    raise RuntimeError("the program's usable targets did not settle")


def run_trial(
    effect: str | None,
    size: float,
    q_train: ArrayLike,
    q_program: ArrayLike,
    *,
    seed: int = 11,
    temp_c: float = TRIAL_TEMP_C,
    time_s: float = TRIAL_TIME_S,
    noise: InstrumentNoise = InstrumentNoise(),
    withhold_masses: bool = False,
) -> TrialRow:
    """The trial of one effect family (module docstring); ``effect`` None: geometric only.

    ``q_train`` (m, nj) are the measured poses in execution order (time and temperature from
    :func:`~quickhealth.identify.twin.schedules`), ``q_program`` (k, nj) the reference
    program's targets, both rad.  ``size`` as :func:`~quickhealth.identify.twin.effect_params`
    reads it.  ``withhold_masses``: the fits see the robot without its link masses (the
    twin keeps them), so ``compliance:jK`` is fitted and compensated in its lumped form.
    """
    q_train = np.atleast_2d(np.asarray(q_train, float))
    q_prog = np.atleast_2d(np.asarray(q_program, float))
    t, temp = schedules(len(q_train))

    def fits(twin: Twin, effects: list[str]) -> FittedModel:
        meas = twin.measure(q_train, t, temp, seed=seed + 1)
        robot = replace(twin.robot, masses=None, coms=None) if withhold_masses else twin.robot
        return select_orders(robot, meas, parse_effects(effects, robot), noise=noise).fitted

    twin = make_twin(seed=seed, effects={effect: size} if effect else {})
    plain = fits(twin, [])
    with_fx = fits(twin, [effect]) if effect else None
    twin0 = make_twin(seed=seed)  # the paired twin: same errors, poses and noise, no effect
    plain0 = fits(twin0, []) if effect else plain
    models: list[tuple[FittedModel, tuple[str, ...]]] = [(plain, ()), (plain0, ())]
    if with_fx is not None:
        models += [(with_fx, ()), (with_fx, tuple(e.name for e in with_fx.effects))]
    ok = _usable(models, q_prog, temp_c, time_s)
    q = q_prog[ok]
    goal = reference_fit(twin, q_train, t, temp).nominal_pose(q)
    goal0 = reference_fit(twin0, q_train, t, temp).nominal_pose(q) if effect else goal

    none = executed_errors(twin, q, goal, temp_c, time_s)
    e_plain, c_plain = _compensated_errors(twin, plain, q, goal, temp_c, time_s)
    cond = {"temp_c": temp_c, "time_s": time_s}
    sig = tcp_sigma(plain, c_plain.q, **cond)
    paired, left, with_e, extra = e_plain, None, None, 0.0
    if effect and with_fx is not None:
        name = with_fx.effects[0].name
        left, _ = _compensated_errors(twin, with_fx, q, goal, temp_c, time_s, (name,))
        with_e, comp = _compensated_errors(twin, with_fx, q, goal, temp_c, time_s)
        paired, comp0 = _compensated_errors(twin0, plain0, q, goal0, temp_c, time_s)
        sig = tcp_sigma(with_fx, comp.q, **cond)
        sig0 = tcp_sigma(plain0, comp0.q, **cond)
        extra = float(np.sqrt(max(float(np.mean(sig**2 - sig0**2)), 0.0)))
    return TrialRow(
        effect=effect if with_fx is None else with_fx.effects[0].name,
        size=float(size),
        n_targets=int(ok.sum()),
        n_dropped=int((~ok).sum()),
        uncompensated=none,
        joint_model=e_plain,
        left_out=left,
        with_effect=with_e,
        paired=paired,
        sigma_fit=float(np.sqrt(np.mean(sig**2))),
        effect_sigma=extra,
        effect_params=None if with_fx is None else np.asarray(with_fx.effect_params[0]),
        true_params=None if not effect else np.asarray(next(iter(twin.truth.effects.values()))),
    )
