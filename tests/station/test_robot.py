"""Robot interface: validated moves, the fake's timing and faults, the read-only view."""

from __future__ import annotations

import numpy as np
import pytest

from quickhealth.identify.errors import HardwareError, InputError
from quickhealth.identify.robot import ur5
from quickhealth.station.hardware.robot import (
    ConnectionLost,
    Leg,
    ProgramStopped,
    ProtectiveStop,
    Robot,
    RobotReader,
    SafetyMode,
    StreamFrozen,
    check_move,
)
from quickhealth.station.sim.arm import trapezoid_duration, trapezoid_fraction
from quickhealth.station.sim.fake_robot import FakeRobot

Q1 = np.radians([10.0, -80.0, 80.0, -90.0, -90.0, 10.0])


def test_protocols_are_met():
    r = FakeRobot(time_scale=50)
    assert isinstance(r, Robot)
    view = r.reader()
    assert isinstance(view, RobotReader)
    assert not hasattr(view, "move") and not hasattr(view, "stop")


@pytest.mark.parametrize(
    "q, speed, accel, match",
    [
        (np.zeros(5), 1.0, 1.0, "6 finite"),
        (np.array([0, 0, np.nan, 0, 0, 0]), 1.0, 1.0, "6 finite"),
        (np.full(6, 7.0), 1.0, 1.0, "outside the joint limits"),
        (np.zeros(6), 0.0, 1.0, "speed"),
        (np.zeros(6), 1.0, float("inf"), "acceleration"),
        (np.zeros(6), 99.0, 1.0, "speed"),
    ],
)
def test_only_validated_numbers_reach_the_controller(q, speed, accel, match):
    with pytest.raises(InputError, match=match):
        check_move(ur5(), q, Leg.JOINT, speed, accel)


def test_fake_moves_in_time_and_ends_at_target():
    r = FakeRobot(time_scale=40)
    t0 = r.now()
    r.move(Q1, Leg.JOINT, speed=1.0, accel=2.0)
    dt = r.now() - t0
    D = np.max(np.abs(Q1 - np.radians([0, -90, 90, -90, -90, 0])))
    assert dt >= trapezoid_duration(D, 1.0, 2.0) * 0.95
    assert np.allclose(r.joints(), Q1, atol=2e-4)  # ringing + noise only
    assert r.status().ready


def test_the_fake_reports_its_joints_temperatures_and_torques():
    """The in-process cell's robot says what a controller says about each joint: the torque
    its drive holds the arm with, and a temperature that rises as the arm works."""
    from quickhealth.identify.robot import gravity_torques

    r = FakeRobot(time_scale=100)
    before = r.reader().joint_sensors()
    for q in (Q1, np.radians([0, -90, 90, -90, -90, 0]), Q1):
        r.move(q, Leg.JOINT, speed=1.0, accel=2.0)
    after = r.reader().joint_sensors()
    assert after.temperature[1] > before.temperature[1] > 25.0  # the shoulder warmed
    # at the reading it was taken at (the readings carry encoder noise and ringing)
    np.testing.assert_allclose(after.torque, -gravity_torques(r.model, r.joints())[0], atol=0.01)


def test_trapezoid_profile_is_monotonic_and_complete():
    D, v, a = 0.8, 1.0, 2.0
    T = trapezoid_duration(D, v, a)
    s = [trapezoid_fraction(t, T, D, a) for t in np.linspace(0, T, 50)]
    assert s[0] == 0.0 and s[-1] == 1.0 and np.all(np.diff(s) >= 0)
    assert trapezoid_duration(0.01, 1.0, 2.0) == pytest.approx(2 * np.sqrt(0.01 / 2.0))


@pytest.mark.parametrize(
    "fault, exc",
    [
        ("protective_stop", ProtectiveStop),
        ("connection_drop", ConnectionLost),
        ("frozen_stream", StreamFrozen),
        ("program_stop", ProgramStopped),
    ],
)
def test_fake_faults_raise_hardware_errors_that_say_what_to_do(fault, exc):
    r = FakeRobot(time_scale=50)
    r.inject(fault, after_moves=2)
    r.move(Q1)
    with pytest.raises(exc) as err:
        r.move(np.zeros(6))
    assert isinstance(err.value, HardwareError)
    assert "--resume" in str(err.value)
    r.release()
    r.move(np.zeros(6))
    assert r.status().safety_mode is SafetyMode.NORMAL
