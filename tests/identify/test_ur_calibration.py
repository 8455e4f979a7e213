"""The UR ROS driver's calibration YAML: read, written, and what its numbers mean (issue 24).

The files the driver's ``ur_calibration`` tool writes come from the controller's DH table
plus its calibration deltas: the tool moves the large ``d`` offsets of the parallel axes
(2, 3, 4) back onto the arm and writes each joint origin as x, y, z and three angles.  That
construction is re-implemented here (``_ur_calibration_file``) and run on the deltas of the
tool's own unit test (a UR10 calibration), so the reader is checked against what the
controller computes, not against this project's writer.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.robot import from_dh, ur10, ur10e, ur30
from quickhealth.identify.transforms import rot_x, rot_z
from quickhealth.identify.ur_calibration import (
    SEGMENTS,
    UrKinematics,
    convention_difference,
    intrinsic_xyz,
    kinematics_of,
    kinematics_yaml,
)
from quickhealth.station import formats

Q = np.random.default_rng(7).uniform(-np.pi, np.pi, (300, 6))

# ur_description's config/ur10/default_kinematics.yaml and config/ur30/default_kinematics.yaml
# (the nominal files, as published, numbers and rounding included)
UR10_DEFAULT = """kinematics:
  shoulder:
    x: 0
    y: 0
    z: 0.1273
    roll: 0
    pitch: 0
    yaw: 0
  upper_arm:
    x: 0
    y: 0
    z: 0
    roll: 1.570796327
    pitch: 0
    yaw: 0
  forearm:
    x: -0.612
    y: 0
    z: 0
    roll: 0
    pitch: 0
    yaw: 0
  wrist_1:
    x: -0.5723
    y: 0
    z: 0.163941
    roll: 0
    pitch: 0
    yaw: 0
  wrist_2:
    x: 0
    y: -0.1157
    z: -2.373046667922381e-11
    roll: 1.570796327
    pitch: 0
    yaw: 0
  wrist_3:
    x: 0
    y: 0.0922
    z: -1.891053610911353e-11
    roll: 1.570796326589793
    pitch: 3.141592653589793
    yaw: 3.141592653589793
  hash: calib_17227329492635474227
"""
UR30_DEFAULT = (
    "kinematics:\n"
    "  shoulder: {x: 0, y: 0, z: 0.23630000000000001, roll: -0, pitch: 0, yaw: -0}\n"
    "  upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: -0}\n"
    "  forearm: {x: -0.637, y: 0, z: 0, roll: -0, pitch: 0, yaw: -0}\n"
    "  wrist_1: {x: -0.5037, y: 0, z: 0.20100000000000001, roll: -0, pitch: 0, yaw: -0}\n"
    "  wrist_2: {x: 0, y: -0.1593, z: 0, roll: 1.570796327, pitch: 0, yaw: -0}\n"
    "  wrist_3: {x: 0, y: 0.15429999999999999, z: -3.1647459019915597e-11,"
    " roll: 1.5707963265897931, pitch: 3.1415926535897931, yaw: 3.1415926535897931}\n"
    "  hash: calib_4890363623803256388\n"
)

# ur_calibration's unit test: a UR10's calibration deltas (d, a, theta, alpha per joint)
UR10_TEST_DELTAS = np.array(
    [
        [0.00065609212979853, 4.6311376834935676e-05, -7.290070070824746e-05, 0.000211987863869334],
        [1.4442162376284788, -0.00012568315331862312, -0.01713897289704999, -0.0072553625957652995],
        [0.854147723854608, 0.00186216581161458, -0.03707159413492756, -0.013483226769541364],
        [-2.2989425877563705, 9.918593870679266e-05, 0.054279462160583214, 0.0013495820227329425],
        [-1.573498686836816e-05, 4.215462720453189e-06, 1.488984257025741e-07, -0.001263136163679901],
        [1.9072435590711256e-05, 0.0, 1.551499479707493e-05, 0.0],
    ]
)  # fmt: skip


def _with_deltas(nominal, deltas):
    """The controller's kinematics: the nominal DH table plus calibration deltas."""
    dh = nominal.dh
    d, a, th, al = (np.asarray(deltas)[:, k] for k in range(4))
    return from_dh(
        nominal.name,
        a=np.add(dh["a"], a),
        d=np.add(dh["d"], d),
        alpha=np.add(dh["alpha"], al),
        theta_offset=th,
        q_min=nominal.q_min,
        q_max=nominal.q_max,
        masses=nominal.masses,
        coms=nominal.coms,
        joint_names=nominal.joint_names,
    )


def _ur_calibration_file(robot) -> str:
    """The YAML ``ur_calibration`` would write for a DH robot (``robot.dh`` with offsets).

    The DH chain is split into ``Rz(θ_i)·Tz(d_i)`` and ``Tx(a_i)·Rx(α_i)``.  For the upper arm
    and the forearm (joints 2, 3), the joint's ``d`` is set to zero: the next joint axis is
    intersected with the joint's xy plane, the link becomes that intersection (length and
    heading), the old heading goes into the link's rotation, and the distance moved along the
    next axis is taken off the next joint's ``d``.  Each origin is then the link part of the
    previous joint times the joint part of this one, its angles Eigen's ``eulerAngles(0, 1, 2)``
    (``R = Rx(a) Ry(b) Rz(c)``); the last link part (``a6``, ``α6``) is not written.
    """
    dh = robot.dh
    a, d, al, th = (np.array(dh[k], float) for k in ("a", "d", "alpha", "theta_offset"))
    joint = [np.eye(4) for _ in range(6)]
    link = [np.eye(4) for _ in range(6)]
    for i in range(6):
        joint[i][:3, :3], joint[i][2, 3] = rot_z(th[i]), d[i]
        link[i][:3, :3], link[i][0, 3] = rot_x(al[i]), a[i]
    for i in (1, 2):
        if joint[i][2, 3] == 0.0:
            continue
        start = joint[i] @ link[i]
        p0, p1 = start[:3, 3], (start @ joint[i + 1])[:3, 3]
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        t = -p0[2] / u[2]  # where the next axis meets this joint's xy plane
        hit = p0 + t * u
        heading = np.arctan(hit[1] / hit[0])
        joint[i][2, 3] = 0.0
        joint[i][:3, :3] = rot_z(heading)
        link[i][0, 3] = -np.linalg.norm(hit)
        link[i][:3, :3] = rot_z(th[i] - heading) @ rot_x(al[i])
        joint[i + 1][2, 3] -= t * (1.0 if u[2] > 0 else -1.0)
    origins = [joint[0]] + [link[i - 1] @ joint[i] for i in range(1, 6)]
    lines = ["kinematics:"]
    for name, O in zip(SEGMENTS, origins, strict=True):
        r, p, y = intrinsic_xyz(O[:3, :3])
        vals = dict(zip(("x", "y", "z"), O[:3, 3], strict=True)) | {"roll": r, "pitch": p, "yaw": y}
        lines.append(f"  {name}:")
        # yaml-cpp's shortest form: 1e-05 has no dot (a string to YAML 1.1), zeros may be -0
        lines += [f"    {k}: {float(v):.17g}" for k, v in vals.items()]
    lines.append("  hash: calib_12345")
    return "\n".join(lines) + "\n"


def test_published_nominal_files_read_as_the_built_in_dh_tables(tmp_path):
    """default_kinematics.yaml of the UR10 and UR30 give the DH tables' forward kinematics to
    the files' rounding (1.570796327 for π/2: 3e-10 rad), 1e-9 m; and this project's writer,
    on the DH table, gives the published numbers."""
    for nominal, text in ((ur10(), UR10_DEFAULT), (ur30(), UR30_DEFAULT)):
        f = tmp_path / f"{nominal.name}.yaml"
        f.write_text(text)
        kin, sha = formats.read_ur_calibration(f)
        assert sha == hashlib.sha256(text.encode()).hexdigest()
        assert kin.hash.startswith("calib_")
        cal = formats.load_robot(nominal.name.upper(), f)
        d = np.abs(cal.fk(Q) - nominal.fk(Q)).max()
        assert d < 1e-9, d
        assert cal.nominal.calibration == f.name and cal.nominal.calibration_sha256 == sha
        # same bodies: gravity torques agree
        from quickhealth.identify.robot import gravity_torques

        np.testing.assert_allclose(gravity_torques(cal, Q), gravity_torques(nominal, Q), atol=1e-7)
        mine = kinematics_of(nominal).kinematics
        np.testing.assert_allclose(mine.xyz, kin.xyz, atol=1e-9)
        np.testing.assert_allclose(mine.origins()[:, :3, :3], kin.origins()[:, :3, :3], atol=1e-9)


def test_a_file_as_ur_calibration_writes_it_reproduces_the_controller(tmp_path):
    """The unit-test calibration of ur_calibration, written the way the tool writes it, read
    back: the controller's DH-plus-deltas chain to 1e-9 m (1e-12 measured).  Read the URDF's
    way (fixed-axis rpy) the same numbers put the flange 0.043 mm off."""
    truth = _with_deltas(ur10(), UR10_TEST_DELTAS)
    text = _ur_calibration_file(truth)
    assert "e-05" in text  # numbers YAML 1.1 reads as strings: the reader takes them
    f = tmp_path / "robot_calibration.yaml"
    f.write_text(text)
    cal = formats.load_robot("ur10", f)
    assert np.abs(cal.fk(Q) - truth.fk(Q)).max() < 1e-9
    kin, _ = formats.read_ur_calibration(f)
    pos, _rot = convention_difference(kin)
    assert 2e-5 < pos < 1e-4, pos


def test_known_deltas_round_trip_through_the_file(tmp_path):
    """A UR10e with known calibration deltas → YAML → read → the same kinematics (1e-12 m)
    → written again: the same numbers (to 1e-15).  Its joint frames stay where the
    nominal file puts them (shoulder at z = d1 …)."""
    deltas = np.zeros((6, 4))
    deltas[:, 0] = [2e-4, 0, 0, 4e-4, -2e-4, 1e-4]  # d
    deltas[:, 1] = [1e-4, 3e-4, -2e-4, 0, 5e-5, 0]  # a
    deltas[:, 2] = [1e-4, 4e-4, -3e-4, 5e-4, -2e-4, 3e-4]  # theta
    deltas[:, 3] = [2e-4, 2e-4, -3e-4, 2e-4, -1e-4, 0]  # alpha
    nominal = ur10e()
    truth = _with_deltas(nominal, deltas)
    ex = kinematics_of(truth, reference=nominal)
    assert ex.flange_pos < 1e-12 and ex.flange_rot < 1e-12
    # a real last-joint zero offset (θ6) keeps the two readings ~0.03 mm, 0.4 mrad apart:
    # the layout ends on joint 6's frame, so nothing can absorb it (ur_calibration's files too)
    assert ex.urdf_pos < 1e-4 and ex.urdf_rot < 1e-3
    text = kinematics_yaml(ex.kinematics, ["known deltas"])
    f = tmp_path / "cal.yaml"
    f.write_text(text)
    cal = formats.load_robot("ur10e", f)
    assert np.abs(cal.fk(Q) - truth.fk(Q)).max() < 1e-12
    kin, _ = formats.read_ur_calibration(f)
    np.testing.assert_array_equal(kin.xyz, ex.kinematics.xyz)
    np.testing.assert_array_equal(kin.rpy, ex.kinematics.rpy)
    np.testing.assert_allclose(convention_difference(kin), (ex.urdf_pos, ex.urdf_rot), rtol=0.2)
    again = kinematics_of(cal).kinematics  # written again: the same numbers (to 1 ulp)
    np.testing.assert_allclose(again.xyz, kin.xyz, rtol=0, atol=1e-15)
    np.testing.assert_allclose(again.rpy, kin.rpy, rtol=0, atol=1e-15)
    # frames where the nominal file has them (the meshes stay put): the shoulder at d1, the
    # calibration's 0.2 mm of d1 on the upper arm's origin, along the same axis
    assert abs(kin.xyz[0, 2] - nominal.dh["d"][0]) < 1e-12
    assert abs(kin.xyz[1, 2] - deltas[0, 0]) < 1e-6


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("kinematics: [1, 2]\n", "no 'kinematics:' block"),
        ("robot: {}\n", "no 'kinematics:' block"),
        ("kinematics:\n  shoulder: {x: 0\n", "not valid YAML"),
        (UR10_DEFAULT.replace("wrist_1:", "wrist1:"), "no wrist_1; unknown 'wrist1'"),
        (UR10_DEFAULT.replace("z: 0.1273", "z: .nan"), "kinematics.shoulder.z = nan"),
        (UR10_DEFAULT.replace("x: -0.612", "x: -612.0"), "more than 20 m"),
        (UR10_DEFAULT.replace("x: -0.612", "x: [1]"), "kinematics.forearm.x = [1]"),
    ],
)
def test_bad_files_are_refused_in_one_line(tmp_path, text, message):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(InputError) as exc:
        formats.load_robot("ur10", f)
    assert message in str(exc.value) and "\n" not in str(exc.value)
    assert str(f) in str(exc.value)


def test_another_arms_calibration_and_a_robot_without_six_joints_are_refused(tmp_path):
    f = tmp_path / "ur10.yaml"
    f.write_text(UR10_DEFAULT)
    with pytest.raises(InputError, match=r"another arm model\? Give the arm"):
        formats.load_robot("ur10e", f)
    wam = str(formats.load_robot.__globals__["Path"](__file__).resolve().parents[2])
    with pytest.raises(InputError, match="has 7"):
        formats.load_robot(f"{wam}/fixtures/robots/wam.toml", f)


def test_urkinematics_origins_follow_the_stated_conventions():
    k = UrKinematics(xyz=np.zeros((6, 3)), rpy=np.tile([0.3, -0.2, 0.5], (6, 1)))
    Ro = k.origins()[0, :3, :3]
    Ru = k.origins("urdf")[0, :3, :3]
    np.testing.assert_allclose(Ro, rot_x(0.3) @ _rot_y(-0.2) @ rot_z(0.5), atol=1e-15)
    np.testing.assert_allclose(Ru, rot_z(0.5) @ _rot_y(-0.2) @ rot_x(0.3), atol=1e-15)
    np.testing.assert_allclose(intrinsic_xyz(Ro), [0.3, -0.2, 0.5], atol=1e-15)


def _rot_y(a):
    from quickhealth.identify.transforms import rot_y

    return rot_y(a)
