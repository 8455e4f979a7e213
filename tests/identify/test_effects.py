"""Effects library: physics of each perturbation, Jacobians against finite differences."""

import dataclasses

import numpy as np
import pytest

from quickhealth.identify.diagnose import (
    LoopState,
    chebyshev_jacobian,
    context_for,
    effect_jacobian,
    model_pose,
    sensitivities,
)
from quickhealth.identify.effects import (
    CHANNELS,
    CONDITIONS,
    EffectContext,
    Perturbation,
    effect_type,
    effect_types,
    parse_effect,
    parse_effects,
    total_perturbation,
)
from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.errors import InputError
from quickhealth.identify.jointload import drive_torques
from quickhealth.identify.linearize import loop_pose
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import (
    GRAVITY,
    first_moments,
    from_dh,
    gravity_regressor,
    gravity_torques,
    ur5,
)
from quickhealth.identify.transforms import log_so3
from quickhealth.identify.twin import camera_pose, payloads, random_joints

# every registered type's example joins the hand-picked names: a new effect is checked here
# (Jacobian, linearity, its declarations) without an edit to this file
ALL = list(
    dict.fromkeys(
        [
            "compliance:j2",
            "compliance:j3",
            "compliance:j2:lumped",
            "compliance:j5:lumped",
            "backlash:j1",
            "cyclic:j3:h7",
            "thermal",
            "drift",
            "depthscale",
        ]
        + [t.example.partition("=")[0] for t in effect_types() if t.example]
    )
)


@pytest.fixture(scope="module")
def setup():
    robot = ur5()
    T_ib = camera_pose()
    q = random_joints(robot, 40, seed=3, T_instr_base=T_ib)
    n = q.shape[0]
    meas = Measurements(
        q=q,
        pos=np.zeros((n, 3)),
        rpy=np.zeros((n, 3)),
        time=np.linspace(0, 600, n),
        temp=np.linspace(21, 27, n),
        # every channel an effect may need (effects.CHANNELS), so any registered effect is
        # tested here: each joint warming at its own rate, torques of a changing payload
        joint_temp=25.0 + np.linspace(0, 1, n)[:, None] * np.array([8.0, 12.0, 9.0, 4.0, 3.0, 2.0]),
        joint_torque=drive_torques(robot, q, payloads(n, 2.0, seed=4)),
    )
    rng = np.random.default_rng(0)
    spec = ErrorModelSpec.uniform(6, 2, q.min(0) - 0.01, q.max(0) + 0.01)
    coeffs = rng.normal(0, 1e-4, spec.n_params)
    T_ft = np.eye(4)
    T_ft[:3, 3] = [0.04, 0.0, 0.06]
    # a model that already has two effects, so Jacobians are taken at a perturbed state
    effects = tuple(parse_effects("backlash:j2,thermal", robot))
    state = LoopState(
        robot, spec, coeffs, T_ib, T_ft, effects, (np.array([3e-4]), np.array([2e-5]))
    )
    return robot, meas, state


def _pose6(T1, T0, h):
    dp = (T1[:, :3, 3] - T0[:, :3, 3]) / h
    dw = log_so3(T1[:, :3, :3] @ np.swapaxes(T0[:, :3, :3], -1, -2)) / h
    return np.concatenate([dp, dw], axis=1)


@pytest.mark.parametrize("name", ALL)
def test_effect_jacobian_matches_finite_differences(setup, name) -> None:
    robot, meas, state = setup
    effect = parse_effect(name, robot)
    ctx = context_for(robot, meas)
    J = effect_jacobian(effect, ctx, sensitivities(state, ctx))
    p0 = 0.5 * np.asarray(effect.prior_sigma) * 1e-2  # evaluate away from zero

    def pose(p):
        return model_pose(state.with_effect(effect, p), ctx)

    for i in range(effect.n_params):
        h = effect.prior_sigma[i] * 1e-3
        dp = np.zeros(effect.n_params)
        dp[i] = h
        fd = _pose6(pose(p0 + dp), pose(p0 - dp), 2 * h)
        scale = np.abs(fd).max()
        assert scale > 0
        np.testing.assert_allclose(J[:, :, i], fd, atol=2e-3 * scale)


def test_chebyshev_jacobian_matches_finite_differences(setup) -> None:
    robot, meas, state = setup
    ctx = context_for(robot, meas)
    J = chebyshev_jacobian(state, ctx, sensitivities(state, ctx))
    rng = np.random.default_rng(1)
    for i in rng.choice(state.spec.n_params, 12, replace=False):
        h = 1e-6
        cp, cm = state.coeffs.copy(), state.coeffs.copy()
        cp[i] += h
        cm[i] -= h
        Tp = model_pose(LoopState(**{**state.__dict__, "coeffs": cp}), ctx)
        Tm = model_pose(LoopState(**{**state.__dict__, "coeffs": cm}), ctx)
        fd = _pose6(Tp, Tm, 2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-6 * max(np.abs(fd).max(), 1.0))


@pytest.mark.parametrize("name", ALL)
def test_perturbation_is_linear_in_params(setup, name) -> None:
    robot, meas, _ = setup
    e = parse_effect(name, robot)
    ctx = context_for(robot, meas)
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=e.n_params), rng.normal(size=e.n_params)
    pa, pb, pab = (e.perturbation(ctx, x) for x in (a, b, 2 * a - 3 * b))
    for field in (f.name for f in dataclasses.fields(Perturbation)):
        fa, fb, fab = (getattr(p, field) for p in (pa, pb, pab))
        if fab is None:
            assert fa is None and fb is None
            continue
        np.testing.assert_allclose(fab, 2 * fa - 3 * fb, atol=1e-15)
    assert e.regressor(ctx).shape == (ctx.n_poses,)
    assert len(e.param_names) == len(e.param_units) == e.n_params == e.prior_sigma.size


@pytest.mark.parametrize("name", ALL)
def test_every_effect_declares_what_its_consumers_need(setup, name) -> None:
    """The protocol's declarations (effects/__init__.py ``Effect``), checked for each effect:
    the consumers read them and nothing else."""
    robot, meas, _ = setup
    e = parse_effect(name, robot)
    t = effect_type(name)
    assert set(e.requires()) <= set(CHANNELS) and e.requires() == t.requires
    assert e.joint is None or 0 <= e.joint < robot.n_joints
    assert all(0 <= j < robot.n_joints for j in e.nuisance_joints(robot.n_joints))
    assert parse_effect(e.physical, robot).physical == e.physical  # a form of a real name
    assert isinstance(e.form, str) and isinstance(e.instrument, bool)
    assert e.family and ":" not in e.family
    bin_ = e.spectrum_bin()
    assert bin_ is None or (bin_[0] == f"j{e.joint + 1}" and bin_[1] >= 1)
    if e.check_family is not None:
        assert e.joint is not None and t.check is not None and e.check_family.kind == t.check[0]
    if t.twin is not None:
        p = e.twin_params(1e-4, np.random.default_rng(0))
        assert p.shape == (e.n_params,) and np.all(np.isfinite(p)) and np.any(p != 0)
    # a program's conditions (compensate): scalars, a temperature per joint, the torque's source
    conditions = {"temp": 27.0, "time": 900.0, "joint_temp": (35.0,) * 6, "joint_torque": "masses"}
    assert set(conditions) == set(CONDITIONS)
    assert e.correction(conditions).startswith(e.name)
    ctx = context_for(robot, meas)
    x, label = e.regressor_at(ctx, np.ones(e.n_params), np.tile(np.eye(4), (ctx.n_poses, 1, 1)))
    assert x.shape == (ctx.n_poses,) and label
    assert isinstance(e.info(), dict)
    if t.example:  # the example is a name of this type with a size the twin reads
        name_, _, size = t.example.partition("=")
        assert effect_type(name_) is t and t.twin is not None and float(size) > 0


def test_effects_compose_with_each_other_and_the_chebyshev_model(setup) -> None:
    robot, meas, state = setup
    ctx = context_for(robot, meas)
    effs = parse_effects("compliance:j2,cyclic:j3:h7,drift,depthscale", robot)
    params = [np.array([2e-5]), np.array([1e-4, -2e-4]), np.full(6, 1e-7), np.array([3e-4])]
    total = total_perturbation(effs, params, ctx)
    summed = effs[0].perturbation(ctx, params[0])
    for e, p in zip(effs[1:], params[1:], strict=True):
        summed = summed + e.perturbation(ctx, p)
    np.testing.assert_array_equal(total.dq, summed.dq)
    np.testing.assert_array_equal(total.base_twist, summed.base_twist)
    # the joint perturbations of compliance and cyclic add on the same dq array
    np.testing.assert_allclose(total.dq[:, 1], 2e-5 * ctx.gravity_torque[:, 1])
    assert np.all(total.dq[:, 2] != 0)
    # to first order the pose changes add up (small effects: cross terms are second order)
    T0 = model_pose(state, ctx)
    T_all = loop_pose(
        robot,
        state.spec,
        state.coeffs,
        state.T_instr_base0,
        state.T_flange_target0,
        ctx.q,
        total_perturbation(state.effects, state.effect_params, ctx) + total,
    )
    d_sum = sum(
        model_pose(state.with_effect(e, p), ctx)[:, :3, 3] - T0[:, :3, 3]
        for e, p in zip(effs, params, strict=True)
    )
    np.testing.assert_allclose(
        T_all[:, :3, 3] - T0[:, :3, 3], d_sum, atol=1e-3 * np.abs(d_sum).max()
    )


def test_each_effect_follows_its_physics(setup) -> None:
    robot, meas, _ = setup
    ctx = context_for(robot, meas)
    n = ctx.n_poses
    tau = gravity_torques(robot, meas.q)
    c = parse_effect("compliance:j3", robot).perturbation(ctx, np.array([1e-5]))
    np.testing.assert_allclose(c.dq[:, 2], 1e-5 * tau[:, 2])
    assert np.all(c.dq[:, [0, 1, 3, 4, 5]] == 0)
    b = parse_effect("backlash:j1", robot).perturbation(ctx, np.array([4e-4]))
    np.testing.assert_allclose(b.dq[:, 0], 2e-4 * meas.approach_sign()[:, 0])
    y = parse_effect("cyclic:j3:h7", robot).perturbation(ctx, np.array([1.0, 2.0]))
    np.testing.assert_allclose(y.dq[:, 2], np.sin(7 * meas.q[:, 2]) + 2 * np.cos(7 * meas.q[:, 2]))
    t = parse_effect("thermal", robot).perturbation(ctx, np.array([2e-5]))
    np.testing.assert_allclose(t.link_scale, 2e-5 * (meas.temp - 20.0))
    xi = np.array([1e-6, 2e-6, 3e-6, 4e-6, 5e-6, 6e-6])
    d = parse_effect("drift", robot).perturbation(ctx, xi)
    np.testing.assert_allclose(d.base_twist, meas.time[:, None] * xi[None])
    s = parse_effect("depthscale", robot).perturbation(ctx, np.array([1e-3]))
    np.testing.assert_allclose(s.instr_scale_z, np.full(n, 1e-3))


def test_perturbed_loop_applies_depth_scale_and_link_growth() -> None:
    robot = ur5()
    q = random_joints(robot, 5, seed=1)
    spec = ErrorModelSpec.uniform(6, 0, np.full(6, -7.0), np.full(6, 7.0))
    coeffs = np.zeros(spec.n_params)
    T_ib = camera_pose()
    from quickhealth.identify.effects import Perturbation

    T0 = loop_pose(robot, spec, coeffs, T_ib, np.eye(4), q)
    Ts = loop_pose(
        robot, spec, coeffs, T_ib, np.eye(4), q, Perturbation(instr_scale_z=np.full(5, 1e-3))
    )
    np.testing.assert_allclose(Ts[:, 2, 3], 1.001 * T0[:, 2, 3])
    np.testing.assert_allclose(Ts[:, :2, 3], T0[:, :2, 3])
    # a uniform link growth of g scales the flange position in the base frame by 1 + g
    Tg = loop_pose(
        robot, spec, coeffs, np.eye(4), np.eye(4), q, Perturbation(link_scale=np.full(5, 1e-3))
    )
    T1 = loop_pose(robot, spec, coeffs, np.eye(4), np.eye(4), q)
    np.testing.assert_allclose(Tg[:, :3, 3], 1.001 * T1[:, :3, 3], atol=1e-12)


def test_names_are_checked_and_uniform_scale_is_explained() -> None:
    robot = ur5()
    assert parse_effect(" cyclic:j6:h11 ", robot).name == "cyclic:j6:h11"
    with pytest.raises(InputError, match="j7 does not exist"):
        parse_effect("backlash:j7", robot)
    with pytest.raises(InputError, match="at least 1"):
        parse_effect("cyclic:j1:h0", robot)
    with pytest.raises(InputError, match="indistinguishable"):
        parse_effect("uniformscale", robot)
    with pytest.raises(InputError, match="given twice"):
        parse_effects("thermal,thermal", robot)
    ctx = EffectContext(robot, np.zeros((2, 6)), np.ones((2, 6)))
    with pytest.raises(InputError, match="temp"):
        parse_effect("thermal", robot).perturbation(ctx, np.array([1e-5]))
    with pytest.raises(InputError, match="time"):
        parse_effect("drift", robot).regressor(ctx)


def _bare(robot):
    """The same robot with its inertial data withheld."""
    return dataclasses.replace(robot, masses=None, coms=None)


def _wam():
    """The WAM's DH table (fixtures/robots/wam.toml) with made-up masses, for the algebra."""
    return from_dh(
        "wam",
        a=[0, 0, 0.045, -0.045, 0, 0, 0],
        d=[0, 0, 0.55, 0, 0.3, 0, 0.06],
        alpha=np.array([-1, 1, -1, 1, -1, 1, 0]) * np.pi / 2,
        q_min=np.radians([-150, -113, -157, -50, -275, -90, -172]),
        q_max=np.radians([150, 113, 157, 180, 75, 90, 172]),
        masses=[10.0, 3.9, 1.7, 2.4, 0.3, 0.4, 0.07],
        coms=np.random.default_rng(5).normal(0, 0.05, (7, 3)),
    )


@pytest.mark.parametrize("make", [ur5, _wam])
def test_gravity_torque_is_linear_in_the_first_moments(make) -> None:
    """τ_k = |g| Σ_j Y_kj · h_j exactly, for every joint, from kinematics and moments alone."""
    robot = make()
    q = np.random.default_rng(4).uniform(-3, 3, (60, robot.n_joints))
    tau = gravity_torques(robot, q)
    h = first_moments(robot)
    for k in range(robot.n_joints):
        Y = gravity_regressor(robot, q, k)
        np.testing.assert_allclose(
            np.linalg.norm(GRAVITY) * np.einsum("nja,ja->n", Y, h[k:]),
            tau[:, k],
            atol=1e-12 * max(np.abs(tau).max(), 1.0),
        )


@pytest.mark.parametrize("make", [ur5, _wam])
def test_lumped_form_expresses_the_mass_form_exactly(make) -> None:
    """The mass form's deflection c·τ_K lies in the span of the lumped base set, for every
    joint gravity loads: the base set loses nothing (its parameters are c·|g|·M·h)."""
    robot = make()
    bare = _bare(robot)
    q = random_joints(robot, 50, seed=8)
    ctx_m = context_for(robot, Measurements(q=q, pos=np.zeros((50, 3))))
    ctx_b = context_for(bare, Measurements(q=q, pos=np.zeros((50, 3))))
    h = first_moments(robot)
    for k in range(1, robot.n_joints):
        mass = parse_effect(f"compliance:j{k + 1}", robot)
        lump = parse_effect(f"compliance:j{k + 1}", bare)  # falls back to the lumped form
        assert (mass.form, lump.form) == ("masses", "lumped")
        assert lump.name == f"compliance:j{k + 1}:lumped" and "no link masses" in lump.reason
        c = 3e-5
        theta = lump.basis.M @ (c * np.linalg.norm(GRAVITY) * h[k:].reshape(-1))
        np.testing.assert_allclose(
            lump.perturbation(ctx_b, theta).dq,
            mass.perturbation(ctx_m, np.array([c])).dq,
            atol=1e-12,
        )


def test_lumped_base_set_names_its_combinations() -> None:
    robot = ur5()
    e = parse_effect("compliance:j2:lumped", robot)  # available with masses too
    assert e.form == "lumped" and e.reason == ""
    # UR5 joint 2: every link's moment along its own axis is lumped into the one before it or
    # loads nothing (axes 2, 3, 4 are parallel)
    assert e.param_names == ("h2x", "h2y", "h3x", "h3y", "h4x", "h4y", "h5x", "h5y", "h6x", "h6y")
    assert set(e.basis.zero) == {"h2z", "h3z", "h4z"}
    combos = e.basis.combinations()
    assert "h4y = h4y − 1·h5z" in combos and "h5y = h5y + 1·h6z" in combos
    assert e.param_units == ("rad",) * 10 and e.info()["form"] == "lumped"
    with pytest.raises(InputError, match="vertical"):
        parse_effect("compliance:j1:lumped", robot)
    with pytest.raises(InputError, match="j7 does not exist"):
        parse_effect("compliance:j7:lumped", robot)
    with pytest.raises(InputError, match="two forms of compliance:j2"):
        parse_effects("compliance:j2,compliance:j2:lumped", robot)
    assert len(parse_effects("compliance:j2,compliance:j3:lumped", robot)) == 2
