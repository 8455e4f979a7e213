"""Measurement CSV v1, model.json, report.json, robot descriptions, URScript, WAM files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import qh_synth as S

from quickhealth.identify.errors import InputError
from quickhealth.identify.fit import fit_model
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.robot import chain
from quickhealth.station import formats
from quickhealth.station.provenance import provenance

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"


GOOD = """# robot serial: 2018301234
# instrument: stereo
q1,q2,q3,q4,q5,q6,x,y,z,pitch,yaw,roll,time,temp
10,-80,90,-100,90,0,100.5,-200.25,1800.125,10,20,30,0.0,21.5
-20,-60,70,-90,80,45,110.5,-210.25,1810.125,-10,25,35,1.5,21.6
35,-100,110,-120,100,-30,90.0,-190.0,1790.0,15,-20,40,3.0,21.7
"""


def _write(tmp_path, text, name="m.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------- CSV v1


def test_read_good_file_converts_units_and_metadata(tmp_path):
    m = formats.read_measurements(_write(tmp_path, GOOD), 6)
    assert m.n_poses == 3 and m.has_orientation
    assert m.q[0, 0] == pytest.approx(np.radians(10))
    assert m.pos[0] == pytest.approx([0.1005, -0.20025, 1.800125])
    assert m.rpy[1] == pytest.approx(np.radians([-10, 25, 35]))
    assert m.temp[2] == 21.7 and m.time[1] == 1.5
    assert m.meta == {"robot serial": "2018301234", "instrument": "stereo"}


def test_roundtrip_full_pose_with_uncertainties(tmp_path):
    truth = S.paper_truth(0)
    m = S.measure(truth, S.random_q(10, 1), 2)
    from dataclasses import replace

    m = replace(
        m,
        sigma_pos=np.full((10, 3), 3e-5),
        sigma_rpy=np.full((10, 3), 1e-4),
        pose_id=tuple(f"p{i}" for i in range(10)),
        time=np.arange(10.0),
        meta={"run": "x"},
    )
    p = tmp_path / "rt.csv"
    formats.write_measurements(p, m)
    back = formats.read_measurements(p, 6)
    for f in ("q", "pos", "rpy", "sigma_pos", "sigma_rpy", "time"):
        np.testing.assert_allclose(getattr(back, f), getattr(m, f), rtol=1e-12, atol=1e-15)
    assert back.pose_id == m.pose_id and back.meta == {"run": "x"}


def test_position_only_file_and_free_column_order(tmp_path):
    text = "z,x,q6,q5,q4,q3,q2,q1,y\n1,2,10,20,30,40,50,60,3\n4,5,11,21,31,41,51,61,6\n"
    m = formats.read_measurements(_write(tmp_path, text), 6)
    assert not m.has_orientation
    assert m.pos[0] == pytest.approx([0.002, 0.003, 0.001])
    assert m.q[0] == pytest.approx(np.radians([60, 50, 40, 30, 20, 10]))


@pytest.mark.parametrize(
    ("text", "where", "what"),
    [
        (GOOD.replace(",x,", ",xx,"), ":3:15:", "missing column 'x'"),
        (GOOD.replace("q1,q2,q3,q4,q5,q6,", "q2,q3,q4,q5,q6,"), ":3:14:", "missing column 'q1'"),
        (GOOD.replace("100.5", "1OO.5"), ":4:7:", "'1OO.5' is not a number"),
        (GOOD.replace("100.5", "nan"), ":4:7:", "not finite"),
        (GOOD.replace("100.5", "inf"), ":4:7:", "not finite"),
        (GOOD.replace("100.5", ""), ":4:7:", "empty cell"),
        (GOOD.replace(",time,", ",temp,"), ":3:14:", "duplicate column 'temp'"),
        (GOOD.replace("1800.125,10,20,30", "1800.125,10,20"), ":4:14:", "row has 13 cells"),
        (GOOD.replace(",pitch,yaw,", ",pitch,yawn,"), ":3:10:", "needs 'yaw'"),
        ("# only a comment\n", ":1:1:", "no header"),
        ("q1,q2,q3,q4,q5,q6,x,y,z\n", ":2:1:", "no data rows"),
        (
            GOOD.replace("q6,x", "q6,q7,x")
            .replace(",0,100.5", ",0,1,100.5")
            .replace(",45,110.5", ",45,1,110.5")
            .replace(",-30,90.0", ",-30,1,90.0"),
            ":3:7:",
            "robot has 6 joints",
        ),
        (GOOD.replace("2.5,10,20,30", "2.5,10,20,30").replace("0.0,21.5", "0.0,21.5"), None, None),
    ],
)
def test_bad_input_gives_one_line_file_line_column(tmp_path, text, where, what):
    p = _write(tmp_path, text)
    if where is None:
        formats.read_measurements(p, 6)  # control: the unchanged file reads
        return
    with pytest.raises(InputError) as exc:
        formats.read_measurements(p, 6)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(f"{p}{where}"), msg
    assert what in msg


QUAT = """q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz,srot
10,-80,90,-100,90,0,100.5,-200.25,1800.125,0.5,-0.5,0.5,0.5,0.01
-20,-60,70,-90,80,45,110.5,-210.25,1810.125,1,0,0,0,0.02
35,-100,110,-120,100,-30,90.0,-190.0,1790.0,0.7071068,0,-0.7071068,0,0.03
"""


def test_quaternion_orientation_near_yaw_minus_90_roundtrips_without_singularity(tmp_path):
    """The T-Mac of the shared UR10 set sits 0.3-0.7 deg from yaw = -90 deg, where the
    pitch/yaw/roll angles are singular: the quaternion form keeps the rotation exactly, and
    srot is one isotropic angle on the rotation vector."""
    from quickhealth.identify.linearize import rotation_noise_cov
    from quickhealth.identify.transforms import rpy_to_R

    rng = np.random.default_rng(3)
    n = 40
    rpy = np.c_[
        rng.uniform(-3, 3, n), np.radians(-90 + rng.uniform(0.3, 0.7, n)), rng.uniform(-3, 3, n)
    ]
    R = rpy_to_R(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    m = Measurements(
        q=np.radians(rng.uniform(-90, 90, (n, 6))),
        pos=rng.normal(0, 1, (n, 3)),
        rot=R,
        sigma_rot=np.full(n, np.radians(0.002)),
    )
    p = tmp_path / "q.csv"
    formats.write_measurements(p, m)
    header = p.read_text().splitlines()[0].split(",")
    assert {"qw", "qx", "qy", "qz", "srot"} <= set(header) and "pitch" not in header
    back = formats.read_measurements(p, 6)
    assert np.abs(back.R - R).max() < 1e-12
    assert back.rpy is None and back.sigma_rot == pytest.approx(m.sigma_rot)
    cov = rotation_noise_cov(back, 1e-4)
    assert cov == pytest.approx(np.radians(0.002) ** 2 * np.broadcast_to(np.eye(3), (n, 3, 3)))


def test_quaternion_columns_read(tmp_path):
    m = formats.read_measurements(_write(tmp_path, QUAT), 6)
    assert m.has_orientation and m.rpy is None
    assert m.R[1] == pytest.approx(np.eye(3))
    assert m.R[2] @ [1, 0, 0] == pytest.approx([0, 0, 1], abs=1e-6)  # -90 deg about y
    assert m.sigma_rot == pytest.approx(np.radians([0.01, 0.02, 0.03]))


@pytest.mark.parametrize(
    ("text", "where", "what"),
    [
        (QUAT.replace("1,0,0,0,0.02", "1,0,0.5,0,0.02"), ":3:10:", "norm 1.11803, not 1"),
        (QUAT.replace("1,0,0,0,0.02", "0,0,0,0,0.02"), ":3:10:", "norm 0, not 1"),
        (QUAT.replace(",qz,srot", ",qzz,srot"), ":1:10:", "needs 'qz'"),
        (QUAT.replace("0.02\n", "-0.02\n"), ":3:14:", "uncertainty -0.02 must be > 0"),
        (
            "q1,q2,q3,q4,q5,q6,x,y,z,srot\n1,2,3,4,5,6,7,8,9,0.1\n",
            ":1:10:",
            "uncertainty 'srot' without an orientation",
        ),
        (
            QUAT.replace(",srot", ",srot,pitch,yaw,roll")
            .replace("\n1", ",1,2,3\n1")
            .replace("0.01\n", "0.01,1,2,3\n")
            .replace("0.02\n", "0.02,1,2,3\n")
            .replace("0.03\n", "0.03,1,2,3\n"),
            ":1:10:",
            "orientation given twice",
        ),
    ],
)
def test_quaternion_bad_input_one_line(tmp_path, text, where, what):
    p = _write(tmp_path, text)
    with pytest.raises(InputError) as exc:
        formats.read_measurements(p, 6)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{p}{where}"), msg
    assert what in msg, msg


def test_joint_angles_in_radians_are_refused(tmp_path):
    rows = ["q1,q2,q3,q4,q5,q6,x,y,z"]
    rng = np.random.default_rng(0)
    for q in rng.uniform(-3, 3, (5, 6)):
        rows.append(",".join(f"{v:.4f}" for v in q) + ",1,2,3")
    p = _write(tmp_path, "\n".join(rows) + "\n")
    with pytest.raises(InputError, match=r"m\.csv:\d+:\d+: joint angles look like radians"):
        formats.read_measurements(p, 6)


def test_orientation_in_radians_is_refused(tmp_path):
    text = GOOD.replace(",10,20,30,", ",0.1,0.2,3.0,").replace(",-10,25,35,", ",-0.1,-1.2,0.3,")
    text = text.replace(",15,-20,40,", ",0.5,0.2,-2.0,")
    with pytest.raises(InputError, match="orientation angles look like radians"):
        formats.read_measurements(_write(tmp_path, text), 6)


def test_uncertainty_columns_must_be_positive(tmp_path):
    text = "q1,q2,q3,q4,q5,q6,x,y,z,sx,sy,sz\n10,20,30,40,50,60,1,2,3,0.03,0.03,0\n"
    with pytest.raises(InputError, match=r":2:12: column 'sz': uncertainty 0 must be > 0"):
        formats.read_measurements(_write(tmp_path, text), 6)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        formats.read_measurements(tmp_path / "nope.csv", 6)


def test_joints_only_file_for_prediction(tmp_path):
    text = "q1,q2,q3,q4,q5,q6\n10,20,30,40,50,60\n-10,-20,-30,-40,-50,-60\n"
    m = formats.read_measurements(_write(tmp_path, text), 6, joints_only=True)
    assert np.all(np.isnan(m.pos)) and m.n_poses == 2


# ---------------------------------------------------------------- robots


def test_builtin_and_toml_ur5_agree():
    a = formats.load_robot("ur5")
    b = formats.load_robot(str(FIXTURES / "robots" / "ur5.toml"))
    q = S.random_q(20, 3)
    np.testing.assert_allclose(a.fk(q), b.fk(q), atol=1e-12)
    np.testing.assert_allclose(a.masses, b.masses)
    np.testing.assert_allclose(a.coms, b.coms, atol=1e-12)


def test_wam_toml_reproduces_the_data_sets_desired_positions():
    wam = formats.load_robot(str(FIXTURES / "robots" / "wam.toml"))
    a = np.loadtxt(FIXTURES / "wam" / "grid.csv", delimiter=",", skiprows=1)
    T = wam.fk(np.radians(a[:, 7:14]))
    x_t = (T[:, :3, 3] + 0.044 * T[:, :3, 2]) * 1e3
    assert np.abs(x_t - a[:, 1:4]).max() < 0.01  # mm


@pytest.mark.parametrize("name", ["../ur5", "..", "ur5/../../etc/passwd", "UR6", "ur5;rm"])
def test_robot_names_cannot_escape(name):
    with pytest.raises(InputError):
        formats.load_robot(name)


def test_bad_toml_robot(tmp_path):
    p = tmp_path / "r.toml"
    p.write_text('[robot]\nconvention = "dh"\n[[joint]]\na = 0\nd = "x"\nalpha = 0\n')
    with pytest.raises(InputError, match="d = 'x' is not a number"):
        formats.load_robot(str(p))
    p.write_text("[robot\n")
    with pytest.raises(InputError, match="not valid TOML"):
        formats.load_robot(str(p))


URDF = """<?xml version="1.0"?>
<robot name="three">
  <link name="base"/>
  <link name="l1"><inertial><mass value="2.0"/><origin xyz="0.1 0 0.05"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="1.0"/><origin xyz="0.2 0.01 0"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l3"><inertial><mass value="0.5"/><origin xyz="0 0 0.03"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.1 0 0.2" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.4 0 0" rpy="0 0.2 0.1"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-2.5" upper="2.5" effort="1" velocity="1"/></joint>
</robot>
"""


def test_urdf_through_pinocchio_matches_pinocchio_kinematics(tmp_path):
    import pinocchio as pin

    p = tmp_path / "three.urdf"
    p.write_text(URDF)
    robot = formats.load_robot(str(p))
    model = pin.buildModelFromUrdf(str(p))
    model.gravity.linear = np.array([0.0, 0.0, -9.80665])
    data = model.createData()
    rng = np.random.default_rng(0)
    for q in rng.uniform(-2, 2, (5, 3)):
        pin.forwardKinematics(model, data, q)
        T_ref = data.oMi[3].homogeneous
        T = robot.fk(q)
        # the flange is the last joint's frame, exactly as pinocchio places it
        np.testing.assert_allclose(T, T_ref, atol=1e-12)
        # and every joint turns about z of its error frame: joint 3 turns about (0.6, 0, 0.8)
        _, frames = chain(robot, q[None], return_frames=True)
        axis = T_ref[:3, :3] @ np.array([0.6, 0, 0.8])
        np.testing.assert_allclose(frames[0, 2, :3, 2], axis, atol=1e-12)
        # gravity torques agree with pinocchio's generalized gravity
        from quickhealth.identify.robot import gravity_torques

        tau = gravity_torques(robot, q)[0]
        g = pin.computeGeneralizedGravity(model, data, q)
        np.testing.assert_allclose(tau, -g, atol=1e-9)
    assert robot.q_min == pytest.approx([-3, -2, -2.5])


# ---------------------------------------------------------------- model.json / report.json


def test_model_json_roundtrip_predicts_the_same(tmp_path):
    truth = S.paper_truth(0)
    m = S.measure(truth, S.random_q(60, 1), 2)
    fm = fit_model(truth.robot, m, truth.spec)
    p = tmp_path / "model.json"
    formats.write_model(p, fm)
    text = p.read_text()
    assert json.loads(text)["schema"] == formats.MODEL_SCHEMA
    assert json.loads(text)["provenance"] == provenance()  # the writer's software and libraries
    back = formats.read_model(p)
    q = S.random_q(10, 5)
    np.testing.assert_allclose(back.predict(q), fm.predict(q), atol=1e-15)
    np.testing.assert_allclose(back.cov, fm.cov)
    assert back.unidentifiable == fm.unidentifiable and back.labels == fm.labels


def test_model_json_bad_inputs(tmp_path):
    p = tmp_path / "model.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"model\.json:1:2: not valid JSON"):
        formats.read_model(p)
    p.write_text('{"schema": "other/1"}')
    with pytest.raises(InputError, match="not a quickhealth model"):
        formats.read_model(p)
    p.write_text(json.dumps({"schema": formats.MODEL_SCHEMA, "robot": {}}))
    with pytest.raises(InputError, match="incomplete or damaged"):
        formats.read_model(p)


def test_report_json_roundtrip(tmp_path):
    p = tmp_path / "report.json"
    formats.write_report(p, {"bic": np.float64(1.5), "x": np.arange(3), "bad": float("nan")})
    doc = formats.read_report(p)
    assert doc["bic"] == 1.5 and doc["x"] == [0, 1, 2] and doc["bad"] is None
    assert doc["provenance"] == provenance()
    formats.write_report(p, {**doc, "provenance": {"software": "quickhealth 0.0.1"}})
    assert formats.read_report(p)["provenance"] == provenance()  # always the last writer's


# ---------------------------------------------------------------- URScript, WAM


def test_urscript_joint_targets(tmp_path):
    p = tmp_path / "loop.script"
    p.write_text(
        "def loop():\n"
        "  movej([0.1, -1.2, 1.0, -1.4, 1.57, 0.0], a=1.2, v=0.25)\n"
        "  # movej([9, 9, 9, 9, 9, 9])\n"
        "  movel([0.2,-1.1,1.1,-1.5,1.5,0.1], a=0.5, v=0.1)\n"
        "end\n"
    )
    q, lines = formats.read_urscript_joints(p, 6)
    assert q.shape == (2, 6) and lines == [2, 4]
    assert q[1, 0] == pytest.approx(0.2)
    p.write_text("movel(p[0.1, 0.2, 0.3, 0, 0, 0])\n")
    with pytest.raises(InputError, match=r"loop\.script:1:1: movel to a Cartesian pose"):
        formats.read_urscript_joints(p, 6)
    p.write_text("movej([0.1, 0.2])\n")
    with pytest.raises(InputError, match="has 2 joint values"):
        formats.read_urscript_joints(p, 6)


def test_wam_reader_sign_and_units():
    a = np.loadtxt(FIXTURES / "wam" / "random.csv", delimiter=",", skiprows=1)
    m = formats.read_wam_csv(FIXTURES / "wam" / "random.csv", 1.0)
    assert m.n_joints == 7 and m.n_poses == len(a)
    np.testing.assert_allclose(m.pos * 1e3, a[:, 1:4] + a[:, 4:7])
    np.testing.assert_allclose(np.degrees(m.q), a[:, 7:14])


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("", r"wam\.csv:1:1: empty file"),
        (
            "step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,"
            + ",".join(f"joint_{i}" for i in range(1, 8))
            + "\n",
            "no data rows",
        ),  # fmt: skip
        (
            "step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,"
            + ",".join(f"joint_{i}" for i in range(1, 8))
            + "\n1,"
            + ",".join(["1"] * 5 + ["nan"] + ["2"] * 7)
            + "\n",
            r"wam\.csv:2:7: column 'z_dif' .*'nan' is not a finite number",
        ),  # fmt: skip
        ("\x00\x01\xff", "not UTF-8 text"),
    ],
)
def test_wam_reader_refuses_with_one_line(tmp_path, text, what):
    p = tmp_path / "wam.csv"
    p.write_bytes(text.encode("latin-1"))
    with pytest.raises(InputError, match=what):
        formats.read_wam_csv(p, 1.0)


def test_pose_ids_that_look_like_comments_or_lose_spaces(tmp_path):
    q = np.radians(np.array([[10.0, 20, 30], [40, 50, 60]]))
    pos = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    m = Measurements(q=q, pos=pos, pose_id=("#1", '#"2"'))
    back = formats.parse_measurements(formats.format_measurements(m), "f.csv", 3)
    assert back.pose_id == ("#1", '#"2"') and back.n_poses == 2  # quoted, not comments
    with pytest.raises(InputError, match="begins or ends with a space"):
        formats.format_measurements(Measurements(q=q, pos=pos, pose_id=(" P1", "P2")))


def test_joint_temperature_and_torque_columns_roundtrip_and_refusals(tmp_path):
    """CSV v1 temp_j1 … temp_jN (°C) and tau_j1 … tau_jN (N·m): written, read, and refused in
    one line when a joint is missing, a column names a joint the robot lacks or a value is
    no controller's."""
    from dataclasses import replace

    m = S.measure(S.paper_truth(0), S.random_q(8, 1), 2)
    rng = np.random.default_rng(3)
    m = replace(
        m, joint_temp=25.0 + 10.0 * rng.random((8, 6)), joint_torque=rng.normal(0, 20, (8, 6))
    )
    p = tmp_path / "j.csv"
    formats.write_measurements(p, m)
    head = p.read_text().splitlines()[0].split(",")
    assert [h for h in head if h.startswith(("temp_j", "tau_j"))] == [
        f"{k}{i}" for k in ("temp_j", "tau_j") for i in range(1, 7)
    ]
    back = formats.read_measurements(p, 6)
    np.testing.assert_allclose(back.joint_temp, m.joint_temp, rtol=1e-15)
    np.testing.assert_allclose(back.joint_torque, m.joint_torque, rtol=1e-15)
    assert back.conditions()["joint_temp"] is back.joint_temp

    rows = p.read_text().splitlines()
    cols = rows[0].split(",")

    def without(name: str) -> str:
        k = cols.index(name)
        return "\n".join(",".join(c for j, c in enumerate(r.split(",")) if j != k) for r in rows)

    with pytest.raises(InputError, match=r"j\.csv:1:\d+: column 'temp_j1' needs 'temp_j4' too"):
        formats.parse_measurements(without("temp_j4"), "j.csv", 6)
    with pytest.raises(InputError, match=r"column 'tau_j6', but the robot has 5 joints"):
        formats.parse_measurements(without("q6").replace("temp_j6", "tj6"), "j.csv", 5)
    hot = "\n".join(
        [rows[0], rows[1]]
        + [",".join("300" if cols[j] == "temp_j2" else c for j, c in enumerate(r.split(",")))
           for r in rows[2:3]]
    )  # fmt: skip
    with pytest.raises(InputError, match=r"j\.csv:3:\d+: column 'temp_j2': 300 °C is outside"):
        formats.parse_measurements(hot, "j.csv", 6)


def test_a_robot_file_states_its_torque_constants(tmp_path):
    from quickhealth.identify.jointload import TORQUE_CONSTANT, torque_constant
    from quickhealth.station.formats.robot import robot_from_json, robot_to_json

    text = (FIXTURES / "robots" / "ur5.toml").read_text()
    builtin = formats.load_robot(str(FIXTURES / "robots" / "ur5.toml"))
    assert builtin.torque_constant is None  # unstated: the estimate, for every built-in arm
    np.testing.assert_array_equal(torque_constant(builtin), TORQUE_CONSTANT)
    kt = [12.6, 12.6, 12.6, 9.1, 9.1, 9.1]
    stated = text.replace("q_max = 360.0\n", "q_max = 360.0\ntorque_constant = {}\n")
    p = tmp_path / "ur5kt.toml"
    p.write_text(stated.format(*kt))
    robot = formats.load_robot(str(p))
    np.testing.assert_array_equal(torque_constant(robot), kt)
    # model.json carries them, so a fit's robot converts currents as the file said
    again = robot_from_json(json.loads(json.dumps(robot_to_json(robot))))
    np.testing.assert_array_equal(again.torque_constant, kt)
    p.write_text(stated.replace("{}", "12.6", 5).replace("{}", "-3"))
    with pytest.raises(InputError, match="joint 6: torque_constant = -3 N·m/A is not a motor's"):
        formats.load_robot(str(p))
    p.write_text(stated.replace("torque_constant = {}\n", "", 1).replace("{}", "9"))
    with pytest.raises(InputError, match="torque_constant .N·m/A. for every joint or for none"):
        formats.load_robot(str(p))
