"""A degraded simulated robot: the 'a month later' run of the demo and of tests."""

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.sim.world import build_world, degrade_truth, parse_degradation


def test_degradation_changes_exactly_the_named_coefficient() -> None:
    w0 = build_world("reference", twin_seed=1)
    w1 = build_world("reference", twin_seed=1, degrade={"j2.ex.c0": 5e-4})
    labels = w0.twin.truth.spec.labels()
    diff = w1.twin.truth.coeffs - w0.twin.truth.coeffs
    assert diff[labels.index("j2.ex.c0")] == pytest.approx(5e-4)
    assert np.count_nonzero(diff) == 1
    q = np.radians([10, -80, 70, -60, -90, 20])
    moved = np.linalg.norm(w0.T_instr_target0(q)[:3, 3] - w1.T_instr_target0(q)[:3, 3])
    # a 0.5 mrad tilt of joint 2 moves a target some 0.2-0.6 m out by a few tenths of a mm
    assert 5e-5 < moved < 5e-4


def test_parse_degradation_and_its_errors() -> None:
    assert parse_degradation("j2.ex.c0=5e-4, j3.dz.c0=-1e-5") == {
        "j2.ex.c0": 5e-4,
        "j3.dz.c0": -1e-5,
    }
    assert parse_degradation(None) == {}
    with pytest.raises(InputError, match="LABEL=VALUE"):
        parse_degradation("j2.ex.c0")
    with pytest.raises(InputError, match="not a coefficient"):
        degrade_truth(build_world("reference", twin_seed=1).twin.truth, {"j9.ex.c0": 1e-4})


def test_the_demo_names_the_wear_by_the_fault_it_is() -> None:
    from quickhealth.station.demo import DEFAULT_DEGRADATION, worn_faults

    # a constant twist of the link from joint 2 to joint 3 about x is joint 3's axis tilt
    assert worn_faults("reference", DEFAULT_DEGRADATION) == ["joint 3 tilt about x"]
    assert worn_faults("reference", {"j2.ez.c0": -3e-4, "compliance:j2": 2e-5}) == [
        "joint 2 zero offset",
        "joint 2 compliance",
    ]
    assert worn_faults("ur10e", {"j3.ez.c0": 3e-4}) == ["joint 3 zero offset"]
    # a radial motion of joint 1 along x is no single fault: the story could not check it
    with pytest.raises(InputError, match="no single physical fault"):
        worn_faults("reference", {"j1.dx.c0": 1e-4})
