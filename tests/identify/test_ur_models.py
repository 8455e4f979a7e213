"""The built-in Universal Robots arms against independent sources (issue 24, part A).

Frames: every built-in model's base is the controller's base frame (DH frame 0) and its
flange the controller's tool flange (DH frame 6).  In example-robot-data's URDFs (the old
ur_description) these are the frames ``base`` (``base_link`` turned 180° about z) and
``tool0``; the URDFs' joint zeros are the controller's.  ur-analytic-ik's forward kinematics
are the same DH frames.  No other convention needs accounting for.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from quickhealth.identify.effects import effect_context, parse_effect
from quickhealth.identify.robot import (
    BUILTIN_ROBOTS,
    UR_ARMS,
    builtin_robot,
    gravity_torques,
    ur5,
    with_payload,
)
from quickhealth.identify.transforms import log_so3
from quickhealth.station import formats

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
E_SERIES = ("ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30")
Q = np.random.default_rng(24).uniform(-2 * np.pi, 2 * np.pi, (200, 6))


def _erd_urdf(name: str) -> Path:
    for f in importlib.metadata.files("example-robot-data") or []:
        if str(f).endswith(f"ur_description/urdf/{name}_robot.urdf"):
            return Path(str(f.locate()))
    raise AssertionError(f"example-robot-data has no {name}_robot.urdf")


def test_every_builtin_carries_the_published_table():
    assert BUILTIN_ROBOTS == (
        "ur3",
        "ur5",
        "ur10",
        "ur3e",
        "ur5e",
        "ur10e",
        "ur16e",
        "ur20",
        "ur30",
    )
    for name in BUILTIN_ROBOTS:
        r = builtin_robot(name)
        arm = UR_ARMS[name]
        assert r.name == name and r.n_joints == 6 and r.convention == "dh"
        assert r.masses is not None and r.coms is not None
        assert r.masses.shape == (6,) and np.all(r.masses > 0) and r.coms.shape == (6, 3)
        np.testing.assert_allclose(r.masses, arm.masses)
        np.testing.assert_allclose(r.q_min, -2 * np.pi)
        np.testing.assert_allclose(r.q_max, 2 * np.pi)
        assert r.qd_max is not None and r.qdd_max is not None
        assert np.all(np.degrees(r.qd_max) >= 120 - 1e-9) and np.all(r.qdd_max == 40.0)
        assert (r.controller, r.control_hz) == (
            ("CB3", 125.0) if name in ("ur3", "ur5", "ur10") else ("e-Series", 500.0)
        )
        assert r.nominal is not None and r.nominal.robot == name
    # the manuals' speed groups
    assert np.allclose(np.degrees(builtin_robot("ur10e").qd_max), [120, 120, 180, 180, 180, 180])
    assert np.allclose(np.degrees(builtin_robot("ur20").qd_max), [120, 120, 150, 210, 210, 210])
    assert np.allclose(np.degrees(builtin_robot("ur3").qd_max), [180, 180, 180, 360, 360, 360])


def test_ur5_keeps_its_exact_numbers_and_ur10_equals_its_description_file():
    r = ur5()
    assert r.dh == {
        "a": [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0],
        "d": [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823],
        "alpha": [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0],
        "theta_offset": [0.0] * 6,
    }
    assert r.masses.tolist() == [3.7, 8.393, 2.33, 1.219, 1.219, 0.1879]
    assert r.coms[1].tolist() == [0.2125, 0.0, 0.11336]
    for name in ("ur5", "ur10"):
        a = formats.load_robot(name)
        b = formats.load_robot(str(FIXTURES / "robots" / f"{name}.toml"))
        np.testing.assert_allclose(a.links, b.links, atol=1e-15)
        np.testing.assert_array_equal(a.q_offset, b.q_offset)
        np.testing.assert_allclose([a.q_min, a.q_max], [b.q_min, b.q_max], atol=1e-15)
        np.testing.assert_allclose(a.masses, b.masses)
        np.testing.assert_allclose(a.coms, b.coms, atol=1e-15)
        assert a.joint_names == b.joint_names


@pytest.mark.parametrize("name", ["ur3", "ur5", "ur10"])
def test_fk_matches_example_robot_data_urdf_through_pinocchio(name):
    """base → tool0 of the URDF equals the DH flange: 1e-9 m asked, ~7e-12 m measured (the
    URDF writes π/2 as 1.57079632679)."""
    model = pin.buildModelFromUrdf(str(_erd_urdf(name)))
    data = model.createData()
    base, tool0 = model.getFrameId("base"), model.getFrameId("tool0")
    r = builtin_robot(name)
    T_dh = r.fk(Q[:100])
    for k, q in enumerate(Q[:100]):
        pin.framesForwardKinematics(model, data, q)
        T = (data.oMf[base].inverse() * data.oMf[tool0]).homogeneous
        assert np.abs(T[:3, 3] - T_dh[k, :3, 3]).max() < 1e-9
        assert np.linalg.norm(log_so3(T[:3, :3].T @ T_dh[k, :3, :3])) < 1e-9


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_fk_matches_ur_analytic_ik(name):
    """ur-analytic-ik (C++ analytic FK from the same published table): 1e-12 m and rad asked,
    1e-15 measured; every e-Series arm and the CB3 ones it knows (all three)."""
    import ur_analytic_ik as uik

    fk = getattr(uik, name).forward_kinematics
    T_dh = builtin_robot(name).fk(Q)
    for k, q in enumerate(Q):
        T = np.asarray(fk(*q))
        assert np.abs(T[:3, 3] - T_dh[k, :3, 3]).max() < 1e-12
        assert np.abs(T[:3, :3] - T_dh[k, :3, :3]).max() < 1e-12
    assert set(E_SERIES) <= set(BUILTIN_ROBOTS)


def _pinocchio_model(robot, payload=None):
    model = pin.Model()
    parent = 0
    jid = 0
    for i in range(6):
        placement = pin.SE3(robot.links[i][:3, :3], robot.links[i][:3, 3])
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{i}")
        com_body = robot.links[i + 1][:3, :3] @ robot.coms[i] + robot.links[i + 1][:3, 3]
        model.appendBodyToJoint(
            jid, pin.Inertia(robot.masses[i], com_body, np.eye(3) * 1e-3), pin.SE3.Identity()
        )
        parent = jid
    if payload is not None:  # the target as its own body on the flange
        m, c = payload
        flange = pin.SE3(robot.links[6][:3, :3], robot.links[6][:3, 3])
        model.appendBodyToJoint(jid, pin.Inertia(m, c, np.eye(3) * 1e-4), flange)
    model.gravity = pin.Motion(np.array([0, 0, -9.80665]), np.zeros(3))
    return model


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_compliance_uses_the_arms_masses_plus_the_targets(name):
    """Gravity torques of every arm, alone and carrying a 1.2 kg target 80 mm out on the
    flange, equal pinocchio's RNEA on bodies built from the same table (1e-9 N·m), and the
    compliance effect takes the mass form on every built-in arm."""
    r = builtin_robot(name)
    target = (1.2, np.array([0.0, 0.02, 0.08]))
    q = Q[:12]
    for robot, payload in ((r, None), (with_payload(r, *target), target)):
        model = _pinocchio_model(r, payload)
        data = model.createData()
        ours = gravity_torques(robot, q)
        for k in range(q.shape[0]):
            g = -pin.computeGeneralizedGravity(model, data, q[k])
            np.testing.assert_allclose(ours[k], g, atol=1e-9)
    heavy = with_payload(r, *target)
    assert heavy.masses[-1] == pytest.approx(r.masses[-1] + 1.2)
    e = parse_effect("compliance:j2", heavy)
    assert e.form == "masses"
    tau = e.regressor(effect_context(heavy, q))
    np.testing.assert_allclose(tau, gravity_torques(heavy, q)[:, 1])
    assert not np.allclose(tau, gravity_torques(r, q)[:, 1])


def test_every_name_works_with_robot_case_insensitive_and_unknown_names_list_them():
    for name in BUILTIN_ROBOTS:
        for spelled in (name, name.upper(), f" {name.capitalize()} "):
            assert formats.load_robot(spelled).name == name
    from quickhealth.identify.errors import InputError

    with pytest.raises(InputError) as exc:
        formats.load_robot("ur7e")
    msg = str(exc.value)
    assert "\n" not in msg and "ur7e" in msg
    assert all(n in msg for n in BUILTIN_ROBOTS)
