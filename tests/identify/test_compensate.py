"""Exports and compensation checked against independent kinematics (pinocchio) and the model."""

import numpy as np
import pinocchio as pin
import pytest

from quickhealth.identify.compensate import (
    compensate_joints,
    compensate_program,
    corrected_robot,
    dh_deltas,
    geometric_part,
    model_tcp,
    ur_calibration_text,
    urdf_text,
    urscript_joint_targets,
    urscript_replace_targets,
)
from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.robot import chain, ur5


def _model(order, seed=0, scale=2e-4):
    robot = ur5()
    spec = ErrorModelSpec.uniform(6, order, np.full(6, -np.pi), np.full(6, np.pi))
    c = np.random.default_rng(seed).normal(scale=scale, size=spec.n_params)
    return robot, spec, c


def test_corrected_robot_equals_model_for_constant_errors():
    robot, spec, c = _model(0)
    q = np.random.default_rng(1).uniform(-3, 3, size=(20, 6))
    rc = corrected_robot(robot, spec, c)
    np.testing.assert_allclose(chain(rc, q), model_tcp(robot, spec, c, q, np.eye(4)), atol=1e-12)
    np.testing.assert_allclose(geometric_part(spec, c), c.reshape(8, 6)[1:-1], atol=1e-15)


def test_urdf_loads_in_pinocchio_with_the_corrected_kinematics():
    robot, spec, c = _model(2, seed=4)
    rc = corrected_robot(robot, spec, c)
    model = pin.buildModelFromXML(urdf_text(rc))
    data = model.createData()
    fid = model.getFrameId("flange")
    q = np.random.default_rng(2).uniform(-3, 3, size=(10, 6))
    T_ref = chain(rc, q)
    for k in range(10):
        pin.framesForwardKinematics(model, data, q[k])
        np.testing.assert_allclose(data.oMf[fid].homogeneous, T_ref[k], atol=1e-8)
    assert model.nq == 6 and list(model.names)[1:] == list(robot.joint_names)


def test_dh_deltas_recover_dh_parameter_errors():
    """Errors that *are* DH deltas come back as those deltas, with no residual."""
    robot = ur5()
    dh = robot.dh
    true = np.zeros(24)
    true[[1, 8, 13, 20]] = [1e-3, 2e-4, -3e-4, 5e-4]  # θ2, a3, d2, α3
    from quickhealth.identify.compensate import _dh_robot

    bent = _dh_robot(robot, true)
    # express the bent robot as joint error motions: E_i = Rz(Δθ) C_i' C_i^-1 per joint
    spec = ErrorModelSpec.uniform(
        6, 0, np.full(6, -np.pi), np.full(6, np.pi), base=False, tool=False
    )
    from quickhealth.identify.transforms import inv_T, log_so3

    E = bent.links[1:] @ inv_T(robot.links[1:])
    c = np.zeros(spec.n_params).reshape(6, 6)
    for i in range(6):
        th = bent.q_offset[i] - robot.q_offset[i]
        Rz = np.array(
            [
                [np.cos(th), -np.sin(th), 0, 0],
                [np.sin(th), np.cos(th), 0, 0],
                [0, 0, 1, 0],
                [0, 0, 0, 1],
            ]
        )
        Ei = Rz @ E[i]
        c[i, :3] = Ei[:3, 3]
        c[i, 3:] = log_so3(Ei[:3, :3])  # small angles: Rx Ry Rz ≈ exp of the vector
    cal = dh_deltas(robot, spec, c.ravel(), n_samples=150)
    assert cal.nominal_residual_pos_rms > 5e-4
    assert cal.residual_pos_rms < 2e-5  # small-angle approximations only
    assert dh is not None
    T_fit = chain(cal.robot(robot), np.random.default_rng(0).uniform(-3, 3, (30, 6)))
    T_true = chain(bent, np.random.default_rng(0).uniform(-3, 3, (30, 6)))
    assert np.abs(T_fit[:, :3, 3] - T_true[:, :3, 3]).max() < 5e-5
    text = ur_calibration_text(cal)
    assert "[mounting]" in text and text.count("delta_") == 4


def test_compensation_lands_modelled_tcp_on_nominal_target():
    robot, spec, c = _model(3, seed=7, scale=1e-4)
    q = np.random.default_rng(5).uniform(-2.5, 2.5, size=(25, 6))
    rng = np.random.default_rng(6)
    q[:, 4] = rng.uniform(0.4, 2.5, size=25)  # away from the wrist singularity
    q[:, 2] = rng.choice([-1, 1], 25) * rng.uniform(0.5, 2.5, size=25)  # and the elbow one
    tcp = np.eye(4)
    tcp[2, 3] = 0.15
    comp = compensate_joints(robot, spec, c, q, tcp)
    assert comp.error_before_pos.mean() > 2e-4
    assert comp.converged.all() and comp.residual_pos.max() < 1e-8
    T_goal = chain(robot, q) @ tcp
    T_new = model_tcp(robot, spec, c, comp.q, tcp)
    np.testing.assert_allclose(T_new, T_goal, atol=1e-8)
    assert np.abs(comp.q - q).max() < 5e-3  # small corrections


def test_urscript_rewrite_keeps_everything_but_the_targets():
    text = (
        "def loop():\n"
        "  movej([0.1, -1.2, 1.3, -1.0, 1.57, 0.0], a=1.2, v=0.25)\n"
        "  movel(p[0.1, 0.2, 0.3, 0, 0, 0], a=1)\n"
        "  movel([0.2, -1.1, 1.2, -1.1, 1.5, 0.1], a=1.2, v=0.1)\n"
        "  movej(home_q)\n"
        "end\n"
    )
    spans, q = urscript_joint_targets(text, 6)
    assert q.shape == (2, 6) and q[1, 0] == pytest.approx(0.2)
    out = urscript_replace_targets(text, spans, q + 0.001)
    spans2, q2 = urscript_joint_targets(out, 6)
    np.testing.assert_allclose(q2, q + 0.001, atol=1e-9)
    assert "p[0.1, 0.2, 0.3, 0, 0, 0]" in out and "movej(home_q)" in out and "v=0.25)" in out


@pytest.fixture(scope="module")
def model_json(tmp_path_factory):
    """A model fitted to the digital twin, as ``identify fit`` writes it."""
    from quickhealth.identify.fit import InstrumentNoise, fit_model
    from quickhealth.identify.twin import make_twin, random_joints
    from quickhealth.station import formats

    twin = make_twin(seed=2)
    q = random_joints(twin.robot, 60, seed=3, T_instr_base=twin.truth.T_instr_base)
    spec = ErrorModelSpec.uniform(6, 1, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, twin.measure(q, seed=4), spec, noise=InstrumentNoise(3e-5, 1e-4))
    p = tmp_path_factory.mktemp("model") / "model.json"
    formats.write_model(p, fm)
    return p, fm


def test_export_command_writes_urdf_and_ur_calibration(model_json, tmp_path, capsys):
    from quickhealth.station.cli import main

    path, fm = model_json
    urdf, conf, js = tmp_path / "c.urdf", tmp_path / "calibration.conf", tmp_path / "dh.json"
    rc = main(
        ["export", str(path), "--urdf", str(urdf), "--ur-calibration", str(conf), "--json", str(js)]
    )
    assert rc == 0
    model = pin.buildModelFromXML(urdf.read_text())
    data = model.createData()
    q = np.array([0.3, -1.2, 1.1, -0.5, 1.2, 0.4])
    pin.framesForwardKinematics(model, data, q)
    T = data.oMf[model.getFrameId("flange")].homogeneous
    np.testing.assert_allclose(
        T, chain(corrected_robot(fm.robot, fm.spec, fm.coeffs), q[None])[0], atol=1e-8
    )
    assert "[mounting]" in conf.read_text()
    import json

    doc = json.loads(js.read_text())
    assert len(doc["delta_theta"]) == 6 and doc["residual_pos_rms_mm"] >= 0
    assert main(["export", str(path)]) == 2  # nothing asked for
    assert "nothing to export" in capsys.readouterr().err


def test_compensate_command_rewrites_urscript(model_json, tmp_path, capsys):
    from quickhealth.station.cli import main

    path, fm = model_json
    prog = tmp_path / "loop.script"
    prog.write_text(
        "def loop():\n"
        "  movej([0.3, -1.2, 1.1, -0.5, 1.2, 0.4], a=1.0, v=0.2)\n"
        "  movej([-0.4, -1.6, 1.7, -1.0, 0.9, -0.2], a=1.0, v=0.2)\n"
        "end\n"
    )
    out, err = tmp_path / "comp.script", tmp_path / "err.csv"
    rc = main(
        [
            "compensate",
            str(path),
            str(prog),
            "--out",
            str(out),
            "--errors",
            str(err),
            "--tcp-mm",
            "0,0,100",
        ]
    )
    assert rc == 0
    _, q_new = urscript_joint_targets(out.read_text(), 6)
    _, q_old = urscript_joint_targets(prog.read_text(), 6)
    tcp = np.eye(4)
    tcp[2, 3] = 0.1
    ref = compensate_program(fm, q_old, tcp)  # what the command runs: the fitted model's
    np.testing.assert_allclose(q_new, ref.q, atol=1e-8)
    rows = err.read_text().splitlines()
    assert rows[0].startswith("target,err_before_mm,err_after_mm") and len(rows) == 3
    before, after = (np.array([float(r.split(",")[k]) for r in rows[1:]]) for k in (1, 2))
    assert np.all(before > 0.05) and np.all(after < 1e-5)
    assert main(["compensate", str(path), str(prog), "--out", str(out), "--tcp-mm", "1,2"]) == 2
