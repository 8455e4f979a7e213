"""``quickhealth diagnose``, ``twin`` and ``compare`` through the real command line."""

import json

import numpy as np
import pytest

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import fit_model
from quickhealth.identify.robot import ur5
from quickhealth.station.cli import main
from quickhealth.station.formats import read_measurements, write_model


@pytest.fixture(scope="module")
def backlash_run(tmp_path_factory):
    """A twin data set with hidden backlash on joint 2, and a model fitted without it."""
    d = tmp_path_factory.mktemp("twin")
    meas_csv = d / "meas.csv"
    rc = main(
        [
            "twin",
            "--out",
            str(meas_csv),
            "--effects",
            "backlash:j2=0.025",
            "--n",
            "120",
            "--heldout",
            "150",
            "--seed",
            "7",
        ]
    )
    assert rc == 0
    truth = json.loads((d / "meas.truth.json").read_text())
    meas = read_measurements(meas_csv, 6)
    orders = np.asarray(truth["chebyshev"]["orders"])
    orders[[0, -1]] = 0
    spec = ErrorModelSpec(orders, meas.q.min(0) - 0.05, meas.q.max(0) + 0.05)
    write_model(d / "model.json", fit_model(ur5(), meas, spec))
    return d


def test_twin_writes_csv_v1_and_truth(backlash_run) -> None:
    d = backlash_run
    text = (d / "meas.csv").read_text().splitlines()
    header = next(line for line in text if not line.startswith("#"))
    for col in ("q1", "q6", "x", "y", "z", "pitch", "yaw", "roll", "time", "temp"):
        assert col in header.split(",")
    assert len(read_measurements(d / "meas.heldout.csv", 6).q) == 150
    truth = json.loads((d / "meas.truth.json").read_text())
    assert truth["effects"]["backlash:j2"][0] == pytest.approx(np.radians(0.025))
    assert truth["sigma_pos"] == pytest.approx(3e-5)


def test_diagnose_names_the_hidden_effect_per_contract(backlash_run, tmp_path, capsys) -> None:
    d = backlash_run
    out = tmp_path / "diag.json"
    plots = tmp_path / "plots"
    rc = main(
        [
            "diagnose",
            str(d / "model.json"),
            str(d / "meas.csv"),
            "--json",
            str(out),
            "--plots",
            str(plots),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["verdict"] == "missing-effect"
    c0 = doc["candidates"][0]
    assert c0["effect"] == "backlash:j2"
    assert isinstance(c0["score"], float) and isinstance(c0["predicted_rms_drop_mm"], float)
    assert "approach direction of joint 2" in c0["evidence"]
    assert (plots / "candidate_1_backlash_j2.png").stat().st_size > 5000
    assert (plots / "spectrum.png").exists()
    stdout = capsys.readouterr().out
    # the words first (what is missing, what to do), the statistics after their heading
    assert stdout.startswith("a physical effect is missing from the model: backlash:j2")
    assert "statistics:\n  verdict: missing-effect" in stdout
    rc = main(
        [
            "diagnose",
            str(d / "model.json"),
            str(d / "meas.csv"),
            "--json",
            str(out),
            "--fail-on-missing",
        ]
    )
    assert rc == 1


def test_diagnose_on_data_the_model_explains_is_adequate(backlash_run, tmp_path) -> None:
    """Asked only about effects that are not there, the verdict is adequate (exit 0 even
    with --fail-on-missing), and a uniform scale is explained, not tested."""
    d = backlash_run
    out = tmp_path / "diag.json"
    rc = main(
        [
            "diagnose",
            str(d / "model.json"),
            str(d / "meas.csv"),
            "--json",
            str(out),
            "--candidates",
            "uniformscale,thermal",
            "--fail-on-missing",
        ]
    )
    doc = json.loads(out.read_text())
    assert rc == 0 and doc["verdict"] == "adequate"
    assert [c["effect"] for c in doc["candidates"]] == ["thermal"]
    assert "indistinguishable" in doc["not_identifiable"][0]


def test_compare_shows_the_error_fall(backlash_run, tmp_path, capsys) -> None:
    d = backlash_run
    out = tmp_path / "cmp.json"
    rc = main(
        [
            "compare",
            str(d / "model.json"),
            str(d / "meas.csv"),
            "--effects",
            "backlash:j2",
            "--heldout",
            str(d / "meas.heldout.csv"),
            "--json",
            str(out),
            "--plots",
            str(tmp_path),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == "held-out" and doc["n_eval"] == 150
    assert doc["after"]["pos_mm"] < 0.6 * doc["before"]["pos_mm"]
    assert doc["after"]["pos_mm"] < 1.3 * doc["noise_floor_pos_mm"]
    assert (tmp_path / "compare.png").exists()
    assert "without" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["twin", "--out", "{tmp}/x.csv", "--effects", "backlash:j9=0.1"], "j9 does not exist"),
        (["twin", "--out", "{tmp}/x.csv", "--effects", "backlash:j2"], "needs a size"),
        (["twin", "--out", "{tmp}/x.csv", "--effects", "wobble=1"], "unknown effect"),
        (["diagnose", "{tmp}/none.json", "{tmp}/none.csv", "--json", "{tmp}/o.json"], "not found"),
        (
            [
                "diagnose",
                "{d}/model.json",
                "{d}/meas.csv",
                "--json",
                "{tmp}/o.json",
                "--candidates",
                "bogus",
            ],
            "unknown effect",
        ),
        (
            ["compare", "{d}/model.json", "{d}/meas.csv", "--effects", "uniformscale"],
            "indistinguishable",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line(backlash_run, tmp_path, capsys, argv, message) -> None:
    args = [a.format(tmp=tmp_path, d=backlash_run) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "o.json").exists() and not (tmp_path / "x.csv").exists()


def test_twin_measures_a_plan_in_its_order(tmp_path) -> None:
    q_deg = [[10.0 * i, -60.0, 80.0, -100.0, -90.0, 5.0 * i] for i in range(6)]
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses": [{"q_deg": q, "leg": "linear"} for q in q_deg]}))
    out = tmp_path / "m.csv"
    assert main(["twin", "--plan", str(plan), "--out", str(out), "--effects", "thermal=5e-5"]) == 0
    meas = read_measurements(out, 6)
    np.testing.assert_allclose(np.degrees(meas.q), q_deg, atol=1e-9)
    assert meas.temp is not None and meas.temp[-1] > meas.temp[0]
    assert meas.joint_temp is None and meas.joint_torque is None  # no effect needs them
    argv = ["twin", "--plan", str(plan), "--out", str(tmp_path / "j.csv"), "--joint-sensors"]
    assert main([*argv, "--payload-kg", "1.5"]) == 0
    joints = read_measurements(tmp_path / "j.csv", 6)
    assert joints.joint_temp[-1, 1] > joints.joint_temp[0, 1]  # the shoulder warms
    from quickhealth.identify.robot import gravity_torques, ur5

    lift = joints.joint_torque + gravity_torques(ur5(), joints.q)  # the payload's share
    assert np.abs(lift).max() > 1.0 and np.abs(lift).min() < 1e-9  # some poses carry, some not
    plan.write_text(json.dumps({"poses": [{"q": [1, 2]}]}))
    assert main(["twin", "--plan", str(plan), "--out", str(tmp_path / "n.csv")]) == 2
