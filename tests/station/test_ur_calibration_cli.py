"""The controller's calibration as the nominal model, through the command line (issue 24).

A digital twin of a UR10e whose arm really has a controller calibration (known DH deltas,
the ``calibration.yaml`` a ROS user would pass) plus small joint errors of its own:

- fitted against the published nominal kinematics, the errors found include the deltas;
- fitted with ``--calibration`` they are smaller by exactly those deltas: the same as the
  errors found on a twin without the deltas (same joint errors, poses and noise);
- ``export --ur-calibration OUT.yaml`` of the nominal fit, read back with ``--calibration``
  and fitted again: what is left is what a constant kinematic correction cannot hold
  (the ``.conf`` layout of the DH deltas still works beside it);
- report.json says which nominal kinematics the figures are against (file name, SHA-256).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from quickhealth.identify.assess import assess
from quickhealth.identify.compensate import corrected_robot
from quickhealth.identify.robot import from_dh, ur10e
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.identify.ur_calibration import kinematics_of, kinematics_yaml
from quickhealth.station import formats
from quickhealth.station.cli import main

pytestmark = pytest.mark.slow  # four fits of 200 poses, ~12 s here

N_POSES = 200
MAX_ORDER = "2"
TWIN = {"seed": 11, "geometric_pos": 3e-5, "geometric_rot": 5e-5}


def _calibrated(nominal):
    """The arm's real kinematics: the nominal DH table plus the controller's deltas."""
    dh = nominal.dh
    return from_dh(
        nominal.name,
        a=np.add(dh["a"], [0.0, 3e-4, -2e-4, 0.0, 0.0, 0.0]),
        d=np.add(dh["d"], [0.0, 0.0, 0.0, 4e-4, -2e-4, 0.0]),
        alpha=np.add(dh["alpha"], [0.0, 2e-4, -3e-4, 2e-4, 0.0, 0.0]),
        theta_offset=[0.0, 4e-4, -3e-4, 5e-4, -2e-4, 0.0],
        q_min=nominal.q_min,
        q_max=nominal.q_max,
        masses=nominal.masses,
        coms=nominal.coms,
        joint_names=nominal.joint_names,
    )


def _fit(meas, out, *robot_args):
    args = ["identify", "fit", str(meas), *map(str, robot_args), "--out", str(out), "--quiet"]
    assert main([*args, "--max-order", MAX_ORDER]) == 0
    return json.loads((out / "report.json").read_text()), formats.read_model(out / "model.json")


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    d = tmp_path_factory.mktemp("urcal")
    nominal = ur10e()
    arm = _calibrated(nominal)
    q = random_joints(nominal, N_POSES, seed=12)
    meas = make_twin(arm, **TWIN).measure(q)
    formats.write_measurements(d / "meas.csv", meas)
    (d / "calibration.yaml").write_text(
        kinematics_yaml(kinematics_of(arm, reference=nominal).kinematics)
    )
    rep_a, fm_a = _fit(d / "meas.csv", d / "nominal", "--robot", "UR10e")
    rep_b, fm_b = _fit(
        d / "meas.csv",
        d / "calibrated",
        "--robot",
        "ur10e",
        "--calibration",
        d / "calibration.yaml",
    )
    # the control: the same joint errors, poses and noise on an arm without the deltas
    control = assess(make_twin(nominal, **TWIN).measure(q), nominal, max_order=int(MAX_ORDER))
    return d, q, (rep_a, fm_a), (rep_b, fm_b), control.fitted


def _rms(v):
    return float(np.sqrt(np.mean(np.sum(np.asarray(v) ** 2, axis=-1))))


def test_a_fit_against_the_controller_calibration_finds_errors_smaller_by_its_deltas(fits):
    d, q, (rep_a, fm_a), (rep_b, fm_b), fm_c = fits
    e_a, e_b, e_c = (f.tcp_error_vector(q) for f in (fm_a, fm_b, fm_c))
    # against the nominal kinematics the deltas are most of the error (0.54 mm vs 0.15 mm)
    assert _rms(e_a) > 3 * _rms(e_c), (_rms(e_a), _rms(e_c))
    # against the calibration, what is left is the arm's own joint errors: the errors found
    # on the twin without deltas, to 1 µm rms (0.07 µm measured; the deltas' part: 0.54 mm)
    assert _rms(e_b - e_c) < 1e-6, _rms(e_b - e_c)
    # workspace figure 0.500 mm against nominal, 0.146 mm against the calibration
    assert rep_b["workspace"]["mean_mm"] < 0.4 * rep_a["workspace"]["mean_mm"]
    # both fits model the same arm: the same predicted poses (6 nm measured)
    assert _rms(fm_a.robot_pose(q)[:, :3, 3] - fm_b.robot_pose(q)[:, :3, 3]) < 1e-6
    # the report says which nominal kinematics
    cal = d / "calibration.yaml"
    assert rep_a["nominal"] == {
        "robot": "ur10e",
        "calibration": None,
        "calibration_sha256": None,
        "description": "ur10e (published nominal kinematics)",
    }
    assert rep_b["nominal"]["robot"] == "ur10e"
    assert rep_b["nominal"]["calibration"] == "calibration.yaml"
    assert rep_b["nominal"]["calibration_sha256"] == hashlib.sha256(cal.read_bytes()).hexdigest()
    assert "calibration.yaml" in rep_b["summary"][-1]
    # predict reads the model's own robot: the calibrated nominal travels in model.json
    assert fm_b.robot.nominal.calibration == "calibration.yaml"
    assert np.abs(fm_b.robot.fk(q) - formats.load_robot("ur10e", cal).fk(q)).max() < 1e-15


def test_export_writes_the_corrected_kinematics_that_a_refit_reads_back(fits, capsys):
    d, q, (rep_a, fm_a), _, fm_c = fits
    out = d / "exported.yaml"
    conf = d / "exported.conf"
    assert main(["export", str(d / "nominal" / "model.json"), "--ur-calibration", str(out)]) == 0
    assert main(["export", str(d / "nominal" / "model.json"), "--ur-calibration", str(conf)]) == 0
    assert (
        conf.read_text().startswith("# quickhealth: kinematics deltas")
        and "[mounting]" in conf.read_text()
    )
    text = out.read_text()
    assert text.splitlines()[0].startswith("# quickhealth: corrected kinematics")
    assert "kinematics:" in text and "hash: quickhealth_" in text
    # the file holds the corrected kinematics exactly
    exported = formats.load_robot("ur10e", out)
    rc = corrected_robot(fm_a.robot, fm_a.spec, fm_a.coeffs)
    assert np.abs(exported.fk(q) - rc.fk(q)).max() < 1e-12
    rep_d, fm_d = _fit(d / "meas.csv", d / "refit", "--robot", "ur10e", "--calibration", out)
    # what is left after the export is what a constant correction cannot hold (the joint
    # errors' position dependence): 0.010 mm, from 0.500 mm; the export holds the deltas and
    # the arm's constant joint errors (0.146 mm on the twin without deltas), 0.011 mm rms left
    assert rep_d["workspace"]["mean_mm"] < 0.05 * rep_a["workspace"]["mean_mm"]
    assert _rms(fm_d.tcp_error_vector(q)) < 0.2 * _rms(fm_c.tcp_error_vector(q))
    assert rep_d["nominal"]["calibration"] == "exported.yaml"
    # a model fitted against a calibration has no DH table: the .conf export says what to do
    rc_ = main(["export", str(d / "refit" / "model.json"), "--ur-calibration", str(d / "x.conf")])
    assert rc_ == 2 and "export --ur-calibration OUT.yaml instead" in capsys.readouterr().err
