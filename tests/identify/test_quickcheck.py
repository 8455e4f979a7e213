"""The quick check's sequential test on the digital twin: decisions, naming, the paired
design, the H1 boundary and the information gains (the error rates over hundreds of checks
are benchmarks/quick_check.py's, docs/monitoring.md)."""

from dataclasses import replace

import numpy as np
import pytest

from quickhealth.identify import quickcheck as qc
from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.errors import InputError
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.transforms import R_to_rpy
from quickhealth.identify.twin import make_twin, random_joints, twin_from_truth

SIG_POS = np.array([1.1e-6, 0.9e-6, 3.3e-6])  # the simulated cell's stereo camera
SIG_RPY = np.array([4.3e-5, 3.6e-5, 1.8e-5])


def _measure(twin, q, ids, rng):
    n = len(q)
    T = twin.true_pose(q)
    sp, sr = np.tile(SIG_POS, (n, 1)), np.tile(SIG_RPY, (n, 1))
    return Measurements(
        q=q,
        pos=T[:, :3, 3] + rng.normal(size=(n, 3)) * sp,
        rpy=R_to_rpy(T[:, :3, :3]) + rng.normal(size=(n, 3)) * sr,
        sigma_pos=sp,
        sigma_rpy=sr,
        pose_id=tuple(ids),
    )


@pytest.fixture(scope="module")
def setup():
    twin = make_twin(seed=1)
    q = random_joints(twin.robot, 40, seed=4, T_instr_base=twin.truth.T_instr_base)
    ids = [f"P{i:03d}" for i in range(len(q))]
    base = _measure(twin, q, ids, np.random.default_rng(1))
    spec = ErrorModelSpec.uniform(6, 1, q.min(0), q.max(0))
    fitted = fit_model(twin.robot, base, spec, noise=InstrumentNoise(3e-5, 1e-4))
    model = qc.change_model(fitted, qc.CheckSettings(), base)
    return twin, q, ids, base, fitted, model


def _check(twin, setup, rng, name_probability=qc.NAME_PROBABILITY):
    """A check choosing by information gain (no robot time: the library's part)."""
    _, q, ids, base, fitted, model = setup
    run = qc.CheckRun(model, fitted)
    order: list[int] = []
    q_now = np.zeros(6)
    meas = None
    while len(order) < len(q) and run.stop_reason(name_probability) is None:
        left = [i for i in range(len(q)) if i not in order]
        g = qc.information_gains(model, fitted, meas, q_now, base.subset(np.array(left)))
        k = left[int(np.argmax(g))]
        order.append(k)
        q_now = q[k]
        meas = _measure(twin, q[order], [ids[i] for i in order], rng)
        run.update(meas)
    return run, order


def test_healthy_robot_is_unchanged_in_a_few_poses(setup):
    twin = setup[0]
    for seed in range(3):
        run, order = _check(twin, setup, np.random.default_rng(10 + seed))
        assert run.verdict is qc.Decision.UNCHANGED, (run.status.log_lr, run.status.log_sup_h1)
        assert len(order) <= 15
        assert run.status.log_sup_h1 <= run.model.settings.log_b
        assert run.status.changes() == [] or run.status.log_lr < run.model.settings.log_a


def test_tilt_of_joint_2_is_changed_and_named(setup):
    twin = setup[0]
    from quickhealth.station.sim.world import degrade_truth

    worn = twin_from_truth(degrade_truth(twin.truth, {"j2.ex.c0": 1e-4}), twin.robot)
    run, order = _check(worn, setup, np.random.default_rng(5))
    assert run.verdict is qc.Decision.CHANGED
    assert run.decision[1] <= len(order) <= 12
    top = run.status.changes()[0]
    # j2.ex.c0 twists link 2: joint 3's axis tilts about x, the fault the check names
    assert (top.family, top.joint, top.motion) == ("j3.tilt_x", 3, "tilt_x")
    named = run.status.named_changes()[0]
    assert named.fault == "j3.tilt_x" and named.words == "joint 3 tilt about x"
    assert named.z == pytest.approx(named.size / named.sigma) and named.source == "check"
    assert top.probability >= qc.NAME_PROBABILITY
    assert abs(top.size - 1e-4) < 4 * top.sigma + 1e-5  # the tilt's size, within its sigma
    assert 0.05e-3 < top.tcp < 0.2e-3  # moves the TCP by tens of micrometres


def test_the_first_boundary_crossed_is_the_decision(setup):
    """Later poses (measured to name the change) never undo a decision."""
    twin, q, ids, base, fitted, model = setup
    from quickhealth.station.sim.world import degrade_truth

    worn = twin_from_truth(degrade_truth(twin.truth, {"j3.ey.c0": 2e-4}), twin.robot)
    meas = _measure(worn, q[:20], ids[:20], np.random.default_rng(3))
    run = qc.CheckRun(model, fitted)
    for n in range(1, 21):
        run.update(meas.subset(slice(0, n)))
    first = next(
        n
        for n in range(1, 21)
        if qc.check_status(model, fitted, meas.subset(slice(0, n))).decision
        is not qc.Decision.CONTINUE
    )
    assert run.decision == (qc.Decision.CHANGED, first)
    again = qc.CheckRun(model, fitted)
    again.update(meas)  # a resumed check replays the prefixes: the same decision
    assert again.decision == run.decision


def test_paired_check_ignores_what_the_model_cannot_describe(setup):
    """A constant-order baseline misses the twin's position-dependent errors: compared with
    its model, a healthy robot's residuals carry that model error; paired with the baseline's
    own measurements they do not."""
    twin, q, ids, base, _, _ = setup
    spec0 = ErrorModelSpec.uniform(6, 0, q.min(0), q.max(0))
    poor = fit_model(twin.robot, base, spec0, noise=InstrumentNoise(3e-5, 1e-4))
    meas = _measure(twin, q, ids, np.random.default_rng(7))
    paired = qc.check_status(qc.change_model(poor, qc.CheckSettings(), base), poor, meas)
    model_only = qc.check_status(qc.change_model(poor, qc.CheckSettings()), poor, meas)
    assert paired.decision is qc.Decision.UNCHANGED
    # the model error looks like a change (its noise scaled by the fit's chi2/dof, 7: no cure)
    assert (
        model_only.log_lr > paired.log_lr + 30
        and model_only.log_lr > model_only.model.settings.log_a
    )
    with pytest.raises(InputError, match="did not measure"):
        qc.check_status(
            qc.change_model(poor, qc.CheckSettings(), base),
            poor,
            replace(meas, pose_id=("X",) + meas.pose_id[1:]),
        )


def test_check_against_the_model_takes_the_scatter_its_fit_measured(setup):
    """Compared with the model (no pairing), a pose's noise is the baseline's noise model
    scaled by what the fit's own residuals showed (its chi2/dof, at least 1): a baseline
    whose residuals scatter 1.3 times wider than its noise model says holds the check's
    residuals to that scatter (the shared UR10's sessions read as changed by the omnibus
    otherwise).  A paired check compares measurements and keeps the noise model."""
    twin, q, ids, base, fitted, paired_model = setup
    meas = _measure(twin, q, ids, np.random.default_rng(11))
    wide = replace(fitted, chi2_data=1.69 * fitted.dof)
    model = qc.change_model(wide, qc.CheckSettings())
    assert model.noise_scale == pytest.approx(1.69)
    narrow = replace(fitted, chi2_data=0.9 * fitted.dof)
    assert qc.change_model(narrow, qc.CheckSettings()).noise_scale == 1.0  # at least 1
    assert fitted.chi2_data > 2 * fitted.dof and paired_model.noise_scale == 1.0  # paired
    scaled = qc.check_status(model, wide, meas)
    plain = qc.check_status(replace(model, noise_scale=1.0), wide, meas)
    # the noise scales; the baseline's estimation error integrated out does not
    assert scaled.chi2 == pytest.approx(plain.chi2 / 1.69, rel=0.02)


def test_h1_boundary_moves_the_tcp_by_the_detectable_change(setup):
    model = setup[5]
    d = model.settings.detect
    for fam in model.families:
        tcp = np.max(np.linalg.norm(np.einsum("nik,bk->bni", fam.ws, fam.boundary), axis=2), 1)
        assert np.allclose(tcp, d, rtol=1e-9), fam.name
    names = {f.name for f in model.families}
    assert {"j2.ex", "j3.ey", "backlash:j2", "compliance:j3"} <= names
    assert {"j2.zero", "j3.tilt_x", "j2.length", "j4.offset", "j5.scale"} <= names
    assert not {"j1.zero", "j2.tilt_y", "j6.zero"} & names  # set-up changes, no faults
    assert "j1.dz" not in names or model.families[0].k >= 1  # a base shift is no family
    # a joint-1 axial constant is a base shift: only its first-order term stays in j1.dz
    j1dz = next((f for f in model.families if f.name == "j1.dz"), None)
    assert j1dz is None or j1dz.k == 1


def test_information_gains_match_the_information_of_the_data(setup):
    """The rank-d update of every candidate equals adding the pose and computing again."""
    twin, q, ids, base, fitted, model = setup
    meas = _measure(twin, q[:5], ids[:5], np.random.default_rng(2))
    cand = base.subset(np.arange(5, 12))
    gains = qc.information_gains(model, fitted, meas, q[4], cand)
    for j in (0, 3, 6):
        both = _measure(twin, np.r_[q[:5], q[5 + j : 6 + j]], ids[:5] + [ids[5 + j]],
                        np.random.default_rng(2))  # fmt: skip
        direct = _info_gain(model, fitted, meas, both)
        # the same up to the whitening of the orientation: the candidate is linearised at the
        # predicted pose, the data at the measured one (their Euler rates differ by 1e-4)
        assert gains[j] == pytest.approx(direct, rel=1e-3)
    assert np.all(gains > 0)


def _info_gain(model, fitted, before, after):
    def logdets(meas):
        rows = qc._rows(model, fitted, meas)
        n, d = rows.r.shape
        A, B = rows.A.reshape(n * d, -1), rows.B.reshape(n * d, -1)
        Fe = qc._spd_inv(model.P_eta) + A.T @ A
        Info = B.T @ B - (A.T @ B).T @ np.linalg.solve(Fe, A.T @ B)
        out = 0.0
        for fam, sl in zip(model.families, qc._family_slices(model), strict=True):
            out += 0.5 * np.linalg.slogdet(np.linalg.inv(fam.prior) + Info[sl, sl])[1]
        return out

    return logdets(after) - logdets(before)


def test_settings_are_checked():
    with pytest.raises(InputError, match="false-alarm"):
        qc.CheckSettings(false_alarm=0.0)
    with pytest.raises(InputError, match="power"):
        qc.CheckSettings(power=1.0)
    with pytest.raises(InputError, match="smallest change"):
        qc.CheckSettings(detect=float("nan"))
    s = qc.CheckSettings()
    assert s.log_a == pytest.approx(np.log(100)) and s.log_b == pytest.approx(np.log(0.05))
